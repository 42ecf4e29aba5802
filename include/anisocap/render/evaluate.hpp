#pragma once
/// @file
/// Error metrics between an estimated and a true map set, as in the paper's Table 1 (docs/method.md section 9):
/// mean squared error per parameter in the original ranges.
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"

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

/// Novel-view image error: the image loss of docs/method.md section 5 between renderings of `estimate` and of
/// `truth` under `views`, averaged over the views (mean over pixels and channels of
/// |log(A + 0.01) - log(B + 0.01)|).
inline double novel_view_error(const material_maps& estimate, const material_maps& truth, const capture& views) {
  if (views.images.empty()) throw std::invalid_argument("novel_view_error: no views");
  const loss_targets targets = make_loss_targets(render(truth, views));
  return loss_and_gradient(estimate, views, targets, nullptr) / double(views.images.size());
}

}  // namespace anisocap
