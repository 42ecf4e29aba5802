#pragma once
/// @file
/// Error metrics between an estimated and a true map set, as in the paper's Table 1 (MODEL.md 9):
/// mean squared error per parameter in the original ranges.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/procedural.hpp"

namespace anisocap {

/// Per-parameter mean squared errors. The BRDF has two symmetries that leave every rendering
/// unchanged: alpha -> alpha + pi, and (sx, sy, alpha) -> (sy, sx, alpha + pi/2). Errors are taken
/// modulo both, like the paper's alpha modulo pi: per texel, the estimate is compared in whichever
/// of its two equivalent forms has the smaller lobe + rotation error.
struct parameter_errors {
  double diffuse = 0;    ///< a_d, mean over texels and RGB
  double specular = 0;   ///< a'_s, mean over texels and RGB
  double normal = 0;     ///< n_s, mean over texels and the 3 components of the unit normal
  double lobes = 0;      ///< sigma, mean over texels and (sx, sy)
  double rotation = 0;   ///< alpha, difference taken modulo pi (alpha is pi-periodic), all texels
  /// alpha modulo pi over texels whose true lobes differ (max/min >= 1.25) only: where sx ~ sy,
  /// alpha has no visible effect and any value is right. NaN when no texel qualifies.
  double rotation_anisotropic = 0;
  double fresnel = 0;    ///< F0
};

/// alpha1 - alpha2 wrapped into [-pi/2, pi/2].
inline double rotation_difference(double a, double b) {
  const double d = a - b;
  return d - std::numbers::pi * std::nearbyint(d / std::numbers::pi);
}

/// MSE per parameter between `estimate` and `truth` (same size).
inline parameter_errors compare_maps(const material_maps& estimate, const material_maps& truth) {
  if (estimate.width() != truth.width() || estimate.height() != truth.height())
    throw std::invalid_argument("compare_maps: the map sets differ in size (" + std::to_string(estimate.width()) + "x" +
                                std::to_string(estimate.height()) + " against " + std::to_string(truth.width()) + "x" +
                                std::to_string(truth.height()) + ")");
  parameter_errors e;
  const std::size_t n = truth.texel_count();
  auto sq = [](double x) { return x * x; };
  std::size_t aniso = 0;
  for (std::size_t i = 0; i < n; ++i) {
    double r = 0;
    for (int c = 0; c < 3; ++c) {
      e.diffuse += sq(estimate.plane(diffuse_r + c)[i] - truth.plane(diffuse_r + c)[i]);
      e.specular += sq(estimate.plane(specular_r + c)[i] - truth.plane(specular_r + c)[i]);
    }
    auto nz = [&](const material_maps& m) {
      return std::sqrt(std::max(0.0, 1.0 - sq(m.plane(normal_x)[i]) - sq(m.plane(normal_y)[i])));
    };
    e.normal += sq(estimate.plane(normal_x)[i] - truth.plane(normal_x)[i]) +
                sq(estimate.plane(normal_y)[i] - truth.plane(normal_y)[i]) + sq(nz(estimate) - nz(truth));
    {
      const double ex = estimate.plane(lobe_x)[i], ey = estimate.plane(lobe_y)[i], ea = estimate.plane(rotation)[i];
      const double tx = truth.plane(lobe_x)[i], ty = truth.plane(lobe_y)[i], ta = truth.plane(rotation)[i];
      const double lobes_as_is = sq(ex - tx) + sq(ey - ty), rot_as_is = sq(rotation_difference(ea, ta));
      const double lobes_swapped = sq(ey - tx) + sq(ex - ty);
      const double rot_swapped = sq(rotation_difference(ea + std::numbers::pi / 2, ta));
      const bool swap = lobes_swapped + rot_swapped < lobes_as_is + rot_as_is;
      e.lobes += swap ? lobes_swapped : lobes_as_is;
      r = swap ? rot_swapped : rot_as_is;
    }
    e.rotation += r;
    const double sx = truth.plane(lobe_x)[i], sy = truth.plane(lobe_y)[i];
    if (std::max(sx, sy) >= 1.25 * std::min(sx, sy)) { e.rotation_anisotropic += r; ++aniso; }
    e.fresnel += sq(estimate.plane(fresnel_f0)[i] - truth.plane(fresnel_f0)[i]);
  }
  const double dn = double(n);
  e.diffuse /= 3 * dn; e.specular /= 3 * dn; e.normal /= 3 * dn; e.lobes /= 2 * dn;
  e.rotation /= dn; e.fresnel /= dn;
  e.rotation_anisotropic = aniso ? e.rotation_anisotropic / double(aniso) : std::nan("");
  return e;
}

/// The errors of one evaluated material, labelled with its family.
struct material_errors {
  material_kind kind = material_kind::plain_weave;  ///< the material's family
  parameter_errors errors;                          ///< compare_maps against the truth
  double novel_view_loss = std::nan("");            ///< novel_view_error, NaN when not measured
};

/// Mean errors over the materials of one family.
struct family_errors {
  material_kind kind = material_kind::plain_weave;  ///< the family
  int count = 0;                                    ///< materials averaged
  parameter_errors mean;     ///< per-parameter means (rotation_anisotropic over the materials that have it; NaN if none)
  double novel_view_loss = std::nan("");  ///< mean over the materials that measured it; NaN if none
};

/// Groups per-material errors by family and averages each group: one row per family present, in
/// material_kind order.
inline std::vector<family_errors> errors_by_family(const std::vector<material_errors>& materials) {
  std::vector<family_errors> rows;
  for (int k = 0; k < material_kind_count; ++k) {
    family_errors row;
    row.kind = static_cast<material_kind>(k);
    int anisotropic = 0, novel = 0;
    double rotation_anisotropic = 0, novel_sum = 0;
    for (const material_errors& m : materials) {
      if (m.kind != row.kind) continue;
      ++row.count;
      row.mean.diffuse += m.errors.diffuse;
      row.mean.specular += m.errors.specular;
      row.mean.normal += m.errors.normal;
      row.mean.lobes += m.errors.lobes;
      row.mean.rotation += m.errors.rotation;
      row.mean.fresnel += m.errors.fresnel;
      if (!std::isnan(m.errors.rotation_anisotropic)) { rotation_anisotropic += m.errors.rotation_anisotropic; ++anisotropic; }
      if (!std::isnan(m.novel_view_loss)) { novel_sum += m.novel_view_loss; ++novel; }
    }
    if (row.count == 0) continue;
    const double n = row.count;
    row.mean.diffuse /= n; row.mean.specular /= n; row.mean.normal /= n; row.mean.lobes /= n;
    row.mean.rotation /= n; row.mean.fresnel /= n;
    row.mean.rotation_anisotropic = anisotropic ? rotation_anisotropic / anisotropic : std::nan("");
    row.novel_view_loss = novel ? novel_sum / novel : std::nan("");
    rows.push_back(row);
  }
  return rows;
}

/// The kind of evaluation material m: families[m mod size] when a list is given (each listed
/// family in turn), otherwise kind_for_seed(seed, mix).
inline material_kind evaluation_kind(int m, std::uint64_t seed, const std::vector<material_kind>& families, material_mix mix) {
  return families.empty() ? kind_for_seed(seed, mix) : families[std::size_t(m) % families.size()];
}

}  // namespace anisocap

#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap {

/// Three views the capture did not use, for judging an estimate by its renderings (paper 5.1's
/// "novel views"): a Fresnel, an independent and a mirror configuration drawn from `seed` (salted
/// apart from every capture set). Files are named novel_00.exr, novel_01.exr, novel_02.exr.
inline capture novel_view_set(std::uint64_t seed, int width, int height) {
  random_generator rng(hash64(seed ^ 0x6e6f76656cULL));
  capture c;
  c.images.push_back(fresnel_configuration(rng, width, height));
  c.images.push_back(independent_configuration(rng, width, height));
  c.images.push_back(mirror_configuration(rng, width, height));
  for (std::size_t i = 0; i < c.images.size(); ++i) c.images[i].file = "novel_0" + std::to_string(i) + ".exr";
  return c;
}

/// Novel-view image error: the image loss of MODEL.md 5 between renderings of `estimate` and of
/// `truth` under `views`, averaged over the views (mean over pixels and channels of
/// |log(A + 0.01) - log(B + 0.01)|).
inline double novel_view_error(const material_maps& estimate, const material_maps& truth, const capture& views) {
  if (views.images.empty()) throw std::invalid_argument("novel_view_error: no views");
  const loss_targets targets = make_loss_targets(render(truth, views));
  return loss_and_gradient(estimate, views, targets, nullptr) / double(views.images.size());
}

}  // namespace anisocap
