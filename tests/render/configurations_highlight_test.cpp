// The configurations seen through the renderer: an anisotropic pair really puts the specular
// highlight of a flat glossy material on its chosen point, and a Fresnel configuration really
// lights the material at grazing angles (paper 3.6).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <numbers>

#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"

using namespace anisocap;

namespace {

/// A flat, black, glossy, isotropic material: its rendering is the specular lobe alone.
material_maps glossy_mirror(int width, int height) {
  material_maps maps(width, height);
  //                             a_d      a'_s     sx    sy    F0  n_x n_y alpha
  const float values[parameter_count] = {0, 0, 0, 1, 1, 1, 0.05f, 0.05f, 1, 0, 0, 0};
  maps.fill(values);
  return maps;
}

}  // namespace

TEST_CASE("anisotropic pairs put the highlight of a flat glossy material on their point") {
  const int width = 160, height = 96;
  const material_maps maps = glossy_mirror(width, height);
  random_generator rng(21);
  capture cap;
  for (int k = 0; k < 6; ++k) {
    auto [a, b] = anisotropic_configuration_pair(rng, width, height);
    cap.images.push_back(a);
    cap.images.push_back(b);
  }
  const std::vector<image> images = render(maps, cap);
  for (std::size_t i = 0; i < cap.images.size(); ++i) {
    const capture_image& c = cap.images[i];
    // The mirror point (where the half vector is vertical) and the brightest texel.
    const double zc = c.camera[2], zl = c.light[2];
    const double px = (c.camera[0] * zl + c.light[0] * zc) / (zc + zl);
    const double py = (c.camera[1] * zl + c.light[1] * zc) / (zc + zl);
    float peak = 0;
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) peak = std::max(peak, images[i].at(1, x, y));
    // The texel containing the point.
    const double n = width > height ? width : height;
    const int x = std::clamp(int(std::floor(px * n + 0.5 * width)), 0, width - 1);
    const int y = std::clamp(int(std::floor(0.5 * height - py * n)), 0, height - 1);
    INFO("image ", i, ": point (", px, ", ", py, ") in texel (", x, ", ", y, ")");
    // The highlight covers the point: the brightest value is there up to the 1/d^2, cosine and
    // foreshortening factors, which move the radiance peak off the half-vector peak at grazing views.
    CHECK(images[i].at(1, x, y) > 0.5f * peak);
    CHECK(peak > 0.0f);
    // And it is a highlight: the texel half the material's width away is far darker.
    const int far_x = (x + width / 2) % width;
    CHECK(images[i].at(1, far_x, y) < 0.1f * images[i].at(1, x, y));
  }
}

TEST_CASE("Fresnel configurations light the material at grazing angles from the far side") {
  const int width = 128, height = 128;
  random_generator rng(22);
  for (int k = 0; k < 8; ++k) {
    const capture_image c = fresnel_configuration(rng, width, height);
    // At the material's centre both directions are low (grazing) and on opposite sides.
    const double lx = c.light[0], ly = c.light[1], lz = c.light[2];
    const double vx = c.camera[0], vy = c.camera[1], vz = c.camera[2];
    const double light_elevation = std::atan2(lz, std::hypot(lx, ly));
    const double view_elevation = std::atan2(vz, std::hypot(vx, vy));
    CHECK(light_elevation < 50.0 * std::numbers::pi / 180.0);
    CHECK(view_elevation < 50.0 * std::numbers::pi / 180.0);
    CHECK(lx * vx + ly * vy < 0.0);
  }
}
