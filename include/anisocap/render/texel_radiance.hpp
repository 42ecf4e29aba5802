#pragma once
/// @file
/// One texel's radiance under one configuration, in any number type (double for references,
/// ad::dual for exact per-texel derivatives): the arithmetic of render/renderer.hpp for one pixel,
/// without its SIMD, culling or tiling.
#include <array>
#include <cmath>

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// The radiance of texel (x, y) of a width x height material under one configuration (point
/// light, no occlusion), with the parameters in any number type: what the renderer computes for one
/// pixel, written for one texel and differentiable with ad::dual.
template <class T, brdf_features F = all_features>
std::array<T, 3> texel_radiance(const ward_parameters<T>& p, const capture_image& im, int x, int y, int width, int height) {
  using std::sqrt;
  using ad::sqrt;
  const auto pos = texel_position(x, y, width, height);
  std::array<double, 3> l{im.light[0] - pos[0], im.light[1] - pos[1], double(im.light[2])};
  std::array<double, 3> v{im.camera[0] - pos[0], im.camera[1] - pos[1], double(im.camera[2])};
  const double r2 = l[0] * l[0] + l[1] * l[1] + l[2] * l[2];
  const double lr = std::sqrt(r2), vr = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  for (auto& c : l) c /= lr;
  for (auto& c : v) c /= vr;
  const auto f = ward_evaluate<F>(p, l, v);
  T nx = p.nx * 0.0, ny = p.ny * 0.0, nz = nx + 1.0;
  if constexpr (F.normal_map) {
    nx = p.nx;
    ny = p.ny;
    nz = sqrt(1.0 - nx * nx - ny * ny);
  }
  const T cos_l = nx * l[0] + ny * l[1] + nz * l[2];
  std::array<T, 3> out;
  for (int c = 0; c < 3; ++c) out[c] = f[c] * cos_l * (double(im.intensity[c]) / r2);
  return out;
}

/// The parameters of texel (x, y) of `m`, each in type T.
template <class T>
ward_parameters<T> texel_ward_parameters(const material_maps& m, int x, int y) {
  ward_parameters<T> p;
  for (int c = 0; c < 3; ++c) {
    p.diffuse[c] = T(m.at(diffuse_r + c, x, y));
    p.specular[c] = T(m.at(specular_r + c, x, y));
  }
  p.sx = T(m.at(lobe_x, x, y));
  p.sy = T(m.at(lobe_y, x, y));
  p.f0 = T(m.at(fresnel_f0, x, y));
  p.nx = T(m.at(normal_x, x, y));
  p.ny = T(m.at(normal_y, x, y));
  p.alpha = T(m.at(rotation, x, y));
  return p;
}

}  // namespace anisocap
