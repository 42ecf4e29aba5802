#pragma once
/// @file
/// Capture-time analysis: the cheapest BRDF kernel that renders a map set under a capture exactly,
/// up to a stated tolerance, so that an isotropic sample gets no anisotropy kernel, a capture with
/// no grazing configuration no Fresnel term, and flat normals no normal-map frame.
#include <algorithm>
#include <cmath>
#include <string>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// The kernel chosen and why.
struct kernel_analysis {
  brdf_features features;       ///< the cheapest exact feature set
  double max_lobe_asymmetry;    ///< max |sx - sy| / max(sx, sy) over texels
  double max_normal_tilt;       ///< max sqrt(nx^2 + ny^2) over texels
  double max_fresnel_excess;    ///< max (F / F0 - 1) = (1/F0 - 1)(1 - v.h')^5 over texels and images
  std::string describe() const {
    return std::string(features.anisotropic ? "anisotropic" : "isotropic") + (features.fresnel ? ", Fresnel" : ", no Fresnel") +
           (features.normal_map ? ", normal map" : ", flat normals");
  }
};

/// Picks the features whose omission changes no rendering by more than a relative `tolerance`:
/// - anisotropy is dropped when every texel has |sx - sy| <= tolerance * max(sx, sy) (the isotropic
///   kernel then uses sx for both, and alpha has no effect);
/// - Fresnel is dropped when F / F0 <= 1 + tolerance for every texel and image (the specular term
///   then changes by at most that factor);
/// - the normal map is dropped when every normal has sqrt(nx^2 + ny^2) <= tolerance.
inline kernel_analysis analyse_kernel(const material_maps& maps, const capture& cap, double tolerance = 1e-3) {
  kernel_analysis a{all_features, 0, 0, 0};
  const std::size_t n = maps.texel_count();
  double max_inv_f0 = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double sx = std::max(maps.plane(lobe_x)[i], ward_limits::min_lobe), sy = std::max(maps.plane(lobe_y)[i], ward_limits::min_lobe);
    a.max_lobe_asymmetry = std::max(a.max_lobe_asymmetry, std::abs(sx - sy) / std::max(sx, sy));
    const double nx = maps.plane(normal_x)[i], ny = maps.plane(normal_y)[i];
    a.max_normal_tilt = std::max(a.max_normal_tilt, std::sqrt(nx * nx + ny * ny));
    max_inv_f0 = std::max(max_inv_f0, 1.0 / std::max(double(maps.plane(fresnel_f0)[i]), double(ward_limits::min_f0)) - 1.0);
  }
  // Largest (1 - v.h')^5 over texels and images: v.h' is smallest where view and light graze, so
  // check every texel (cheap: one pass per image).
  double max_m5 = 0;
  for (const auto& im : cap.images)
    for (int y = 0; y < maps.height(); ++y)
      for (int x = 0; x < maps.width(); ++x) {
        const auto p = texel_position(x, y, maps.width(), maps.height());
        double l[3] = {im.light[0] - p[0], im.light[1] - p[1], im.light[2]};
        double v[3] = {im.camera[0] - p[0], im.camera[1] - p[1], im.camera[2]};
        const double ll = std::sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]), vl = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double h[3];
        for (int c = 0; c < 3; ++c) h[c] = l[c] / ll + v[c] / vl;
        const double hl = std::sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2]);
        if (hl < 1e-9) continue;
        const double c = (v[0] * h[0] + v[1] * h[1] + v[2] * h[2]) / (vl * hl);
        max_m5 = std::max(max_m5, std::pow(std::max(0.0, 1.0 - c), 5));
      }
  a.max_fresnel_excess = max_inv_f0 * max_m5;
  a.features.anisotropic = a.max_lobe_asymmetry > tolerance;
  a.features.fresnel = a.max_fresnel_excess > tolerance;
  a.features.normal_map = a.max_normal_tilt > tolerance;
  return a;
}

}  // namespace anisocap
