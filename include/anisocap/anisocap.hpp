#pragma once
/// @file
/// The umbrella header: everything anisocap offers. Including single headers (for instance
/// `anisocap/render/renderer.hpp`) compiles faster when only a part is needed.
///
/// Layers, each including only those before it: core (tensors, SIMD, memory, randomness, JSON),
/// ad (forward duals, reverse tape), nn (layers, optimiser, weight files), brdf (Ward model, map
/// sets), render (captures, configurations, renderer and loss), data (image, capture and map I/O,
/// procedural materials), pipeline (refine, evaluation).
#include "anisocap/core/image.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/core/json.hpp"
#include "anisocap/core/memory.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/tensor.hpp"

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/ad/reverse/tape.hpp"

#include "anisocap/nn/parameter.hpp"

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"

#include "anisocap/render/analysis.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/contact_sheet.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"

#include "anisocap/pipeline/evaluate.hpp"
#include "anisocap/pipeline/refine.hpp"
