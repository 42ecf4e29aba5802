#pragma once
/// @file
/// Explicit instantiations of the per-texel kernels, for programs of several translation units.
///
/// The fused loss and gradient (loss_and_gradient, in float and in double SIMD batches), the
/// per-texel refine and the renderer (render, in float SIMD batches) are the largest functions a
/// capture compiles, once per BRDF feature set (eight sets). Every translation unit that runs a
/// capture, a refine or a fine-tune compiles its own copy of them, and the linker keeps one. A
/// program of several units compiles them once with
///
///     // in a header every unit includes, after the anisocap headers:
///     ANISOCAP_TEXEL_KERNELS(extern)
///     // in exactly one .cpp file:
///     ANISOCAP_TEXEL_KERNELS()
///
/// The first line declares the instantiations (no unit compiles them implicitly), the second
/// defines them. The maps the kernels produce are the same either way.
#include "anisocap/brdf/ward.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/render/renderer.hpp"

/// The four kernels of one feature set F (see the file comment); `prefix` is `extern` or empty.
#define ANISOCAP_TEXEL_KERNELS_OF(prefix, F)                                                                                      \
  prefix template double anisocap::loss_and_gradient<F, anisocap::simd::batch<float>>(                                         \
      const anisocap::material_maps&, const anisocap::capture&, const anisocap::loss_targets&, anisocap::material_maps*,        \
      const anisocap::tile_placement&, const anisocap::render_options&, const anisocap::texel_groups*);                         \
  prefix template double anisocap::loss_and_gradient<F, anisocap::simd::batch<double>>(                                        \
      const anisocap::material_maps&, const anisocap::capture&, const anisocap::loss_targets&, anisocap::material_maps*,        \
      const anisocap::tile_placement&, const anisocap::render_options&, const anisocap::texel_groups*);                         \
  prefix template anisocap::refine_result anisocap::refine<F>(anisocap::material_maps&, const anisocap::capture&,              \
                                                               const anisocap::loss_targets&, const anisocap::refine_options&); \
  prefix template std::vector<anisocap::image> anisocap::render<F, anisocap::simd::batch<float>>(                              \
      const anisocap::material_maps&, const anisocap::capture&, const anisocap::tile_placement&, const anisocap::render_options&);

/// The kernels of every feature set with_features dispatches to (all eight combinations of three
/// terms, which brdf/ward.hpp asserts are all there are): `extern` declares them, empty defines
/// them (in one translation unit).
#define ANISOCAP_TEXEL_KERNELS(prefix)                                                   \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{false, false, false}))      \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{false, false, true}))       \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{false, true, false}))       \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{false, true, true}))        \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{true, false, false}))       \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{true, false, true}))        \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{true, true, false}))        \
  ANISOCAP_TEXEL_KERNELS_OF(prefix, (anisocap::brdf_features{true, true, true}))
