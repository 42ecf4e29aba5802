#pragma once
/// @file
/// How faithful each export is: the Ward + Schlick BRDF (brdf/ward.hpp) against each target's model
/// (export/target_models.hpp) after the conversion of export/conversion.hpp, texel by texel, over a
/// grid of light and view directions. The error of a target is the relative L1 distance of the
/// cosine-weighted reflectance, each with its renderer's cosine (the shading normal's for Ward),
///   sum |f_target(l, v) cos_target(l) - f_ward(l, v) cos_n(l)| / sum f_ward(l, v) cos_n(l),
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

/// The relative L1 error (file comment) of the glTF conversion on `maps` with or without
/// KHR_materials_anisotropy, on every `texel_stride`-th texel along x and y, over the direction
/// grid of `zenith_steps` x `azimuth_steps`.
inline double gltf_error(const material_maps& maps, bool anisotropic, const conversion_options& c, int texel_stride,
                         int zenith_steps = 6, int azimuth_steps = 12) {
  fidelity_options grid;
  grid.zenith_steps = zenith_steps, grid.azimuth_steps = azimuth_steps;
  const std::vector<vec3> dirs = fidelity_directions(grid);
  double diff = 0, total = 0;
  for (int y = 0; y < maps.height(); y += texel_stride)
    for (int x = 0; x < maps.width(); x += texel_stride) {
      const ward_parameters<float> p = texel_parameters(maps, std::size_t(y) * maps.width() + x);
      const gltf_texel g = to_gltf(p, c, anisotropic);
      const ward_parameters<double> pd{{p.diffuse[0], p.diffuse[1], p.diffuse[2]}, {p.specular[0], p.specular[1], p.specular[2]},
                                       p.sx, p.sy, p.f0, p.nx, p.ny, p.alpha};
      const double nz = std::sqrt(std::max(1.0 - double(p.nx) * p.nx - double(p.ny) * p.ny, 1e-6));
      for (const vec3& l : dirs) {
        const double cos_n = std::max(0.0, p.nx * l[0] + p.ny * l[1] + nz * l[2]), cos_g = shading_cosine(g, l);
        for (const vec3& v : dirs) {
          const auto w = ward_evaluate(pd, l, v);
          const rgb t = evaluate(g, l, v);
          for (int ch = 0; ch < 3; ++ch) total += w[ch] * cos_n, diff += std::abs(t[ch] * cos_g - w[ch] * cos_n);
        }
      }
    }
  return total > 0 ? diff / total : 0;
}

/// Whether the glTF export of `maps` uses KHR_materials_anisotropy: as `c` says, or, when
/// automatic, where the anisotropic conversion's error (gltf_error on about 16 x 16 texels) is the
/// lower. The extension builds its direction in the mesh's tangent plane, so a normal map cannot
/// move a narrow highlight (target_models.hpp): materials whose tilted normals matter more than
/// their anisotropy (woven fabrics, velvet) follow isotropic GGX about the mapped normal better.
inline bool gltf_uses_anisotropy(const material_maps& maps, const conversion_options& c) {
  if (c.gltf_anisotropy_use != gltf_anisotropy::automatic) return c.gltf_anisotropy_use == gltf_anisotropy::on;
  const int stride = std::max(1, std::max(maps.width(), maps.height()) / 16);
  return gltf_error(maps, true, c, stride) <= gltf_error(maps, false, c, stride);
}

/// Measures every target on `maps` (canonical form expected: brdf/canonical_maps.hpp).
inline fidelity_result measure_fidelity(const material_maps& maps, const fidelity_options& o = {}) {
  const bool gltf_anisotropic = gltf_uses_anisotropy(maps, o.conversion);
  const std::vector<vec3> dirs = fidelity_directions(o);
  std::array<double, target_count> diff{};
  std::array<std::size_t, target_count> clamped{};
  double total = 0;
  fidelity_result r;
  for (int y = 0; y < maps.height(); y += o.texel_stride)
    for (int x = 0; x < maps.width(); x += o.texel_stride) {
      const std::size_t i = std::size_t(y) * maps.width() + x;
      const ward_parameters<float> p = texel_parameters(maps, i);
      const gltf_texel g = to_gltf(p, o.conversion, gltf_anisotropic);
      const blender_texel b = to_blender(p, o.conversion);
      const standard_surface_texel s = to_standard_surface(p, o.conversion);
      const mitsuba_texel m = to_mitsuba(p);
      ward_parameters<double> pd{{p.diffuse[0], p.diffuse[1], p.diffuse[2]}, {p.specular[0], p.specular[1], p.specular[2]},
                                 p.sx, p.sy, p.f0, p.nx, p.ny, p.alpha};
      clamped[0] += gltf_anisotropic ? o.conversion.gltf_scale * p.sx > 1 : p.sx > 1.5 * p.sy;
      clamped[1] += p.sx > 10 * p.sy || o.conversion.blender_scale * std::sqrt(p.sx * p.sy) > 1;
      clamped[2] += p.sx > 50 * p.sy || o.conversion.standard_surface_scale * p.sx > 1;
      clamped[3] += std::abs(std::sin(2 * p.alpha)) * (p.sx - p.sy) > 0.01 * p.sx || p.nx * p.nx + p.ny * p.ny > 1e-4;
      ++r.texels;
      const double nz = std::sqrt(std::max(1.0 - double(p.nx) * p.nx - double(p.ny) * p.ny, 1e-6));
      for (const vec3& l : dirs) {
        // Each renderer's cosine: the shading normal's for Ward, Blender and Standard Surface (their
        // frames are built about it), N.l for glTF, the geometric one for Mitsuba (no shading normal).
        const double cos_n = std::max(0.0, p.nx * l[0] + p.ny * l[1] + nz * l[2]);
        const double cosine[target_count] = {shading_cosine(g, l), cos_n, cos_n, l[2]};
        for (const vec3& v : dirs) {
          const auto w = ward_evaluate(pd, l, v);
          const rgb t[target_count] = {evaluate(g, l, v), evaluate(b, l, v), evaluate(s, l, v), evaluate(m, l, v)};
          for (int c = 0; c < 3; ++c) {
            total += w[c] * cos_n;
            for (int k = 0; k < target_count; ++k) diff[k] += std::abs(t[k][c] * cosine[k] - w[c] * cos_n);
          }
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
