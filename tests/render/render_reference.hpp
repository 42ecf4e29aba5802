#pragma once
// A slow, literal implementation of docs/method.md section 4-5 on top of ward_evaluate, in double, with exact
// gradients from dual numbers: the reference the fast renderer is tested against.
#include <array>
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/texel_radiance.hpp"

namespace anisocap::testing {

/// Random valid maps; parameters a feature set disables get their neutral values.
inline material_maps random_maps(int w, int h, std::uint64_t seed, brdf_features f = all_features) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  material_maps m(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        m.at(diffuse_r + c, x, y) = 0.05f + 0.9f * u(gen);
        m.at(specular_r + c, x, y) = 0.05f + 0.9f * u(gen);
      }
      m.at(lobe_x, x, y) = 0.05f + 0.5f * u(gen);
      m.at(lobe_y, x, y) = f.anisotropic ? 0.05f + 0.5f * u(gen) : m.at(lobe_x, x, y);
      m.at(fresnel_f0, x, y) = f.fresnel ? 0.05f + 0.9f * u(gen) : 1.0f;
      const float r = f.normal_map ? 0.4f * u(gen) : 0.0f, phi = 6.2831853f * u(gen);
      m.at(normal_x, x, y) = r * std::cos(phi);
      m.at(normal_y, x, y) = r * std::sin(phi);
      m.at(rotation, x, y) = f.anisotropic ? 3.0f * (u(gen) - 0.5f) : 0.0f;
    }
  return m;
}

/// Random configurations above the material at moderate distances.
inline capture random_capture(int n, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  capture c;
  for (int i = 0; i < n; ++i) {
    capture_image im;
    im.file = "input_" + std::to_string(i) + ".exr";
    im.camera = {u(gen), u(gen), 0.6f + 0.5f * (u(gen) + 1.0f)};
    im.light = {u(gen), u(gen), 0.6f + 0.5f * (u(gen) + 1.0f)};
    im.intensity = {2.0f + u(gen), 2.0f + u(gen), 2.0f + u(gen)};
    c.images.push_back(im);
  }
  return c;
}

/// Radiance of texel (x, y) under one configuration with parameters in T (double or dual): the
/// library's scalar texel_radiance, which follows docs/method.md literally, without the renderer's SIMD.
template <class T, brdf_features F = all_features>
std::array<T, 3> reference_radiance(const ward_parameters<T>& p, const capture_image& im, int x, int y, int w, int h) {
  return texel_radiance<T, F>(p, im, x, y, w, h);
}

template <class T>
ward_parameters<T> texel_parameters(const material_maps& m, int x, int y) {
  return texel_ward_parameters<T>(m, x, y);
}

template <class T>
std::array<T, 3> reference_radiance(const material_maps& m, const capture_image& im, int x, int y, brdf_features) {
  return reference_radiance<T>(texel_parameters<T>(m, x, y), im, x, y, m.width(), m.height());
}

/// Loss of docs/method.md section 5 and its exact gradient (plane-major: grad[k * w * h + y * w + x]).
template <brdf_features F>
double reference_loss(const material_maps& m, const capture& cap, const loss_targets& targets, std::vector<double>& grad) {
  using D = ad::dual<double, 12>;
  const int w = m.width(), h = m.height();
  grad.assign(std::size_t(12) * w * h, 0.0);
  double loss = 0;
  const double scale = 1.0 / (3.0 * w * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      ward_parameters<D> p;
      for (int c = 0; c < 3; ++c) {
        p.diffuse[c] = D::variable(m.at(diffuse_r + c, x, y), diffuse_r + c);
        p.specular[c] = D::variable(m.at(specular_r + c, x, y), specular_r + c);
      }
      p.sx = D::variable(m.at(lobe_x, x, y), lobe_x);
      p.sy = D::variable(m.at(lobe_y, x, y), lobe_y);
      p.f0 = D::variable(m.at(fresnel_f0, x, y), fresnel_f0);
      p.nx = D::variable(m.at(normal_x, x, y), normal_x);
      p.ny = D::variable(m.at(normal_y, x, y), normal_y);
      p.alpha = D::variable(m.at(rotation, x, y), rotation);
      for (std::size_t k = 0; k < cap.images.size(); ++k) {
        const auto r = reference_radiance<D, F>(p, cap.images[k], x, y, w, h);
        for (int c = 0; c < 3; ++c) {
          const double d = std::log(r[c].value + loss_epsilon) - std::log(double(targets.images[k].at(c, x, y)));
          loss += std::abs(d) * scale;
          const double dl = (d >= 0 ? scale : -scale) / (r[c].value + loss_epsilon);
          for (int q = 0; q < 12; ++q) grad[std::size_t(q) * w * h + std::size_t(y) * w + x] += dl * r[c].grad[q];
        }
      }
    }
  return loss;
}

/// Whether two maps of one size hold the same bits in every parameter plane (padding aside).
inline bool same_bits(const material_maps& a, const material_maps& b) {
  for (int k = 0; k < parameter_count; ++k)
    if (std::memcmp(a.plane(k), b.plane(k), a.texel_count() * sizeof(float)) != 0) return false;
  return true;
}

}  // namespace anisocap::testing
