#pragma once
/// @file
/// How faithful each export is: the Ward + Schlick BRDF (brdf/ward.hpp) against each target's model
/// (export/target_models.hpp) after the conversion of export/conversion.hpp, texel by texel, over a
/// grid of light and view directions. The error of a target is the relative L1 distance of the
/// cosine-weighted reflectance,
///   sum |f_target(l, v) - f_ward(l, v)| cos(theta_l) / sum f_ward(l, v) cos(theta_l),
/// summed over texels, directions and colour channels: what a renderer shows under point lights.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <numbers>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/export/conversion.hpp"

namespace anisocap::exports {

/// The export targets that convert the BRDF.
enum class target : int { gltf = 0, blender = 1, standard_surface = 2, mitsuba = 3 };
/// Number of targets.
inline constexpr int target_count = 4;
/// Display names of the targets.
inline constexpr const char* target_names[target_count] = {"gltf", "blender", "mtlx (Standard Surface)", "mitsuba"};

/// The direction grid and texel sampling of a measurement.
struct fidelity_options {
  int zenith_steps = 6;       ///< zenith angles 0, 75/(n-1), ..., 75 degrees, for l and for v
  int azimuth_steps = 12;     ///< azimuths per non-zero zenith
  int texel_stride = 4;       ///< every n-th texel along x and y
  conversion_options conversion;
};

/// Errors of one measurement.
struct fidelity_result {
  std::array<double, target_count> error{};           ///< relative L1 error per target
  std::array<double, target_count> clamped_fraction{};///< texels whose lobe the target could not express
  std::size_t texels = 0;
};

/// Unit directions of the grid (z up).
inline std::vector<vec3> fidelity_directions(const fidelity_options& o) {
  std::vector<vec3> out{{0, 0, 1}};
  for (int i = 1; i < o.zenith_steps; ++i) {
    const double theta = 75.0 * std::numbers::pi / 180 * i / (o.zenith_steps - 1);
    for (int j = 0; j < o.azimuth_steps; ++j) {
      const double phi = 2 * std::numbers::pi * (j + 0.5 * (i % 2)) / o.azimuth_steps;
      out.push_back({std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)});
    }
  }
  return out;
}

/// The parameters of texel i of `maps`.
inline ward_parameters<float> texel_parameters(const material_maps& maps, std::size_t i) {
  ward_parameters<float> p;
  for (int c = 0; c < 3; ++c) p.diffuse[c] = maps.plane(diffuse_r + c)[i], p.specular[c] = maps.plane(specular_r + c)[i];
  p.sx = maps.plane(lobe_x)[i], p.sy = maps.plane(lobe_y)[i], p.f0 = maps.plane(fresnel_f0)[i];
  p.nx = maps.plane(normal_x)[i], p.ny = maps.plane(normal_y)[i], p.alpha = maps.plane(rotation)[i];
  return p;
}

/// Measures every target on `maps` (canonical form expected: brdf/canonical_maps.hpp).
inline fidelity_result measure_fidelity(const material_maps& maps, const fidelity_options& o = {}) {
  const std::vector<vec3> dirs = fidelity_directions(o);
  std::array<double, target_count> diff{};
  std::array<std::size_t, target_count> clamped{};
  double total = 0;
  fidelity_result r;
  for (int y = 0; y < maps.height(); y += o.texel_stride)
    for (int x = 0; x < maps.width(); x += o.texel_stride) {
      const std::size_t i = std::size_t(y) * maps.width() + x;
      const ward_parameters<float> p = texel_parameters(maps, i);
      const gltf_texel g = to_gltf(p, o.conversion);
      const blender_texel b = to_blender(p, o.conversion);
      const standard_surface_texel s = to_standard_surface(p, o.conversion);
      const mitsuba_texel m = to_mitsuba(p);
      ward_parameters<double> pd{{p.diffuse[0], p.diffuse[1], p.diffuse[2]}, {p.specular[0], p.specular[1], p.specular[2]},
                                 p.sx, p.sy, p.f0, p.nx, p.ny, p.alpha};
      clamped[0] += o.conversion.gltf_scale * p.sx > 1;
      clamped[1] += p.sx > 10 * p.sy || o.conversion.blender_scale * std::sqrt(p.sx * p.sy) > 1;
      clamped[2] += p.sx > 50 * p.sy || o.conversion.standard_surface_scale * p.sx > 1;
      clamped[3] += std::abs(std::sin(2 * p.alpha)) * (p.sx - p.sy) > 0.01 * p.sx || p.nx * p.nx + p.ny * p.ny > 1e-4;
      ++r.texels;
      for (const vec3& l : dirs)
        for (const vec3& v : dirs) {
          const auto w = ward_evaluate(pd, l, v);
          const rgb t[target_count] = {evaluate(g, l, v), evaluate(b, l, v), evaluate(s, l, v), evaluate(m, l, v)};
          for (int c = 0; c < 3; ++c) {
            total += w[c] * l[2];
            for (int k = 0; k < target_count; ++k) diff[k] += std::abs(t[k][c] - w[c]) * l[2];
          }
        }
    }
  for (int k = 0; k < target_count; ++k) {
    r.error[k] = total > 0 ? diff[k] / total : 0;
    r.clamped_fraction[k] = r.texels ? double(clamped[k]) / double(r.texels) : 0;
  }
  return r;
}

}  // namespace anisocap::exports
