#pragma once
/// @file
/// Umbrella header of the neural-network engine: parameters, the layers, convolutions
/// and transposed convolutions, seeded initialisation, Adam and safetensors weight files.
#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/conv.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/layers.hpp"
#include "anisocap/nn/parameter.hpp"
#include "anisocap/nn/safetensors.hpp"
