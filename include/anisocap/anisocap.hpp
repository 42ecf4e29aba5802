#pragma once
/// @file
/// The umbrella header: every public header of anisocap (scripts/umbrella.sh writes it). Including
/// single headers (for instance `anisocap/render/renderer.hpp`) compiles faster when only a part is
/// needed. Folders, each including only those before it: core, ad, nn, brdf, render, data,
/// networks, training, pipeline, calibration, export (README.md "Architecture").

#include "anisocap/core/image.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/core/memory.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/core/tensor.hpp"

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/ad/reverse/tape.hpp"

#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/conv.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/layers.hpp"
#include "anisocap/nn/linear.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/nn/normalization.hpp"
#include "anisocap/nn/parameter.hpp"
#include "anisocap/nn/pooling.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/nn/schedule.hpp"
#include "anisocap/nn/upsample.hpp"

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"

#include "anisocap/render/analysis.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/contact_sheet.hpp"
#include "anisocap/data/data.hpp"
#include "anisocap/data/family_errors.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"

#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/network_layers.hpp"
#include "anisocap/networks/network_space.hpp"

#include "anisocap/training/prefetch.hpp"
#include "anisocap/training/training.hpp"

#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/encode.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/finetune.hpp"
#include "anisocap/pipeline/fingerprint.hpp"
#include "anisocap/pipeline/refine.hpp"

#include "anisocap/calibration/camera.hpp"
#include "anisocap/calibration/markers.hpp"
#include "anisocap/calibration/photo_synthesis.hpp"
#include "anisocap/calibration/photos_description.hpp"
#include "anisocap/calibration/rectify.hpp"

#include "anisocap/export/blender.hpp"
#include "anisocap/export/canonical_maps.hpp"
#include "anisocap/export/conversion.hpp"
#include "anisocap/export/export.hpp"
#include "anisocap/export/fidelity.hpp"
#include "anisocap/export/gltf.hpp"
#include "anisocap/export/materialx.hpp"
#include "anisocap/export/mitsuba.hpp"
#include "anisocap/export/target_models.hpp"
#include "anisocap/export/textures.hpp"
#include "anisocap/export/viewer.hpp"
