#pragma once
/// @file
/// Every layer of the engine except the convolutions (nn/conv.hpp, nn/conv_transpose.hpp).
///
/// Convention: layers are class templates on compile-time channel counts and `class T = float`
/// (double for gradient checks), hold `basic_parameter<T>` members, and apply as
/// `ad::variable<Cout, T> operator()(ad::tape&, const ad::variable<Cin, T>&)`; stateless operations
/// are free functions. An output requires a gradient iff an input does or a parameter is not
/// frozen; the backward pass computes an input's gradient only if that input requires it and a
/// weight gradient only for parameters that are not frozen; nothing is recorded in no-grad mode.
/// Outputs and gradients live in the tape's arena and gradients accumulate (but between two
/// transposed convolutions linked by a chain_link, whose later layer writes the gradient).
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/linear.hpp"
#include "anisocap/nn/normalization.hpp"
#include "anisocap/nn/pooling.hpp"
#include "anisocap/nn/upsample.hpp"
