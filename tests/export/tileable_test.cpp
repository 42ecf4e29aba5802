// Seamless tiles (export/tileable.hpp): the wrap edges of a tile are as smooth as its interior
// where the captured maps' are not, each map keeps its mean and variance, and the lobe and normal
// blend as tensors and vectors (a rotation near +pi/2 meets one near -pi/2 without passing 0).
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/export/tileable.hpp"

using namespace anisocap;

namespace {

/// A map set that does not tile: every plane smooth stationary noise (a sum of waves whose periods
/// do not divide the material), so its wrap edges join unrelated values while interior neighbours
/// are close, and any crop has the whole's statistics.
material_maps smooth_noise_material(int w, int h, std::uint64_t seed) {
  material_maps m(w, h);
  random_generator rng(seed);
  struct wave {
    double kx, ky, phase;
  };
  std::array<std::array<wave, 6>, parameter_count> waves;
  for (auto& plane : waves)
    for (wave& v : plane) {
      const double angle = rng.uniform(0, 2 * std::numbers::pi), period = rng.uniform(7.3, 23.1);
      v = {std::cos(angle) * 2 * std::numbers::pi / period, std::sin(angle) * 2 * std::numbers::pi / period, rng.uniform(0, 6.3)};
    }
  const std::array<std::array<double, 2>, parameter_count> range = {{{0.2, 0.6}, {0.2, 0.6}, {0.2, 0.6}, {0.05, 0.3}, {0.05, 0.3}, {0.05, 0.3},
                                                                     {0.15, 0.4}, {0.03, 0.1}, {0.04, 0.6}, {-0.3, 0.3}, {-0.3, 0.3}, {-1.2, 1.2}}};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int k = 0; k < parameter_count; ++k) {
        double s = 0;
        for (const wave& v : waves[k]) s += std::sin(v.kx * x + v.ky * y + v.phase);
        const double t = 0.5 + s / 6;  // in [0, 1] (mostly near the middle)
        m.at(k, x, y) = float(range[k][0] + (range[k][1] - range[k][0]) * t);
      }
  return m;
}

/// A map set that does not tile: every plane a ramp across the material plus texel noise, so its
/// wrap edges jump by the ramp's whole range.
material_maps ramp_material(int w, int h) {
  material_maps m(w, h);
  random_generator rng(7);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double u = (x + 0.5) / w, v = (y + 0.5) / h;
      auto noise = [&](double s) { return s * (rng.uniform() - 0.5); };
      for (int c = 0; c < 3; ++c) m.at(diffuse_r + c, x, y) = float(0.2 + 0.5 * u + noise(0.1));
      for (int c = 0; c < 3; ++c) m.at(specular_r + c, x, y) = float(0.05 + 0.3 * v + noise(0.05));
      m.at(lobe_x, x, y) = float(0.1 + 0.3 * u + noise(0.02));
      m.at(lobe_y, x, y) = float(0.05 + 0.03 * v + noise(0.01));
      m.at(fresnel_f0, x, y) = float(0.04 + 0.5 * v + noise(0.02));
      m.at(normal_x, x, y) = float(-0.3 + 0.6 * u + noise(0.05));
      m.at(normal_y, x, y) = float(0.3 - 0.6 * v + noise(0.05));
      m.at(rotation, x, y) = float(-1.2 + 2.4 * v + noise(0.1));
    }
  return m;
}

}  // namespace

TEST_CASE("a ramp's tile has wrap edges as smooth as its interior") {
  const material_maps maps = ramp_material(64, 48);
  const seam_statistics before = measure_seam(maps);
  const material_maps tile = make_tileable(maps, {0.25, false});
  CHECK(tile.width() == 48);
  CHECK(tile.height() == 36);
  const seam_statistics after = measure_seam(tile);
  CHECK(before.mean_seam_ratio() > 4);  // the ramp material has a visible seam
  for (int k = 0; k < parameter_count; ++k) {
    CAPTURE(k);
    CHECK(before.seam_ratio[k] > 2);
    CHECK(after.seam_ratio[k] < 1.6);  // a wrap step like an interior step
  }
}

TEST_CASE("a tile of stationary maps has smooth wrap edges and keeps each map's mean and variance") {
  for (std::uint64_t seed : {1, 2, 3}) {
    material_maps maps = smooth_noise_material(96, 80, seed);
    canonicalise(maps);  // the tile's lobes come out canonical: compare like with like
    const seam_statistics before = measure_seam(maps);
    const seam_statistics after = measure_seam(make_tileable(maps));
    CAPTURE(seed);
    CHECK(before.mean_seam_ratio() > 3);
    for (int k = 0; k < parameter_count; ++k) {
      CAPTURE(k);
      CHECK(after.seam_ratio[k] < 1.6);
      if (k == rotation) continue;  // an angle: its mean and variance depend on where it wraps
      CHECK(std::abs(after.mean[k] - before.mean[k]) < 0.25 * std::sqrt(before.variance[k]));
      CHECK(after.variance[k] > 0.7 * before.variance[k]);
      CHECK(after.variance[k] < 1.3 * before.variance[k]);
    }
  }
}

TEST_CASE("a procedural weave's tile keeps every map's mean and variance") {
  procedural_options options;
  options.kind = material_kind::twill;
  material_maps maps = generate_material(5, 96, 96, options);
  canonicalise(maps);
  const seam_statistics before = measure_seam(maps);
  const seam_statistics after = measure_seam(make_tileable(maps));
  for (int k = 0; k < parameter_count; ++k) {
    CAPTURE(k);
    CHECK(after.seam_ratio[k] < 1.6);
    if (k == rotation || before.variance[k] < 1e-10) continue;
    CHECK(std::abs(after.mean[k] - before.mean[k]) < 0.2 * std::sqrt(before.variance[k]));
    CHECK(after.variance[k] > 0.7 * before.variance[k]);
    CHECK(after.variance[k] < 1.3 * before.variance[k]);
  }
}

TEST_CASE("lobes blend as tensors: rotations near +pi/2 and -pi/2 meet as one direction") {
  material_maps maps(16, 16);
  const float flat[parameter_count] = {0.5f, 0.5f, 0.5f, 0.1f, 0.1f, 0.1f, 0.3f, 0.05f, 0.5f, 0.0f, 0.0f, 0.0f};
  maps.fill(flat);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) maps.at(rotation, x, y) = x < 8 ? float(std::numbers::pi / 2 - 0.05) : float(-std::numbers::pi / 2 + 0.05);
  const material_maps tile = make_tileable(maps, {0.25});
  for (std::size_t i = 0; i < tile.texel_count(); ++i) {
    // Every blended lobe points within 0.1 rad of the y axis (mod pi; a per-value blend of the two
    // angles would pass through 0, the x axis) and keeps its widths.
    const double a = tile.plane(rotation)[i];
    CHECK(std::abs(std::abs(a) - std::numbers::pi / 2) < 0.1);
    CHECK(tile.plane(lobe_x)[i] == doctest::Approx(0.3).epsilon(0.02));
    CHECK(tile.plane(lobe_y)[i] == doctest::Approx(0.05).epsilon(0.02));
  }
}

TEST_CASE("normals blend as slopes and stay unit vectors") {
  material_maps maps(16, 16);
  const float flat[parameter_count] = {0.5f, 0.5f, 0.5f, 0.1f, 0.1f, 0.1f, 0.3f, 0.1f, 0.5f, 0.0f, 0.0f, 0.0f};
  maps.fill(flat);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) maps.at(normal_x, x, y) = x < 8 ? 0.6f : -0.6f;
  const material_maps tile = make_tileable(maps, {0.25});
  for (std::size_t i = 0; i < tile.texel_count(); ++i) {
    const double nx = tile.plane(normal_x)[i], ny = tile.plane(normal_y)[i];
    CHECK(nx * nx + ny * ny < 1);
    CHECK(std::abs(ny) < 1e-6);
    CHECK(std::abs(nx) <= 0.6 + 1e-6 + 0.3);  // the variance-preserving blend may overshoot a little
  }
}

TEST_CASE("a tile needs an overlap in (0, 0.5] and enough texels to blend") {
  const material_maps maps = ramp_material(16, 16);
  CHECK_THROWS_AS(make_tileable(maps, {0.0}), std::invalid_argument);
  CHECK_THROWS_AS(make_tileable(maps, {0.6}), std::invalid_argument);
  CHECK_THROWS_AS(make_tileable(ramp_material(4, 4), {0.25}), std::invalid_argument);
}

TEST_CASE("compare_tile: the seam before and after, the statistics' change; validate_tileable refuses what make_tileable refuses") {
  const material_maps maps = ramp_material(64, 48);
  const material_maps tile = make_tileable(maps, {0.25, false});
  const tileable_change c = compare_tile(maps, tile);
  CHECK(c.width_before == 64);
  CHECK(c.height_after == 36);
  CHECK(c.seam_before == doctest::Approx(measure_seam(maps).mean_seam_ratio()));
  CHECK(c.seam_after == doctest::Approx(measure_seam(tile).mean_seam_ratio()));
  CHECK(c.seam_after < c.seam_before);
  CHECK(c.largest_mean_shift > 0);
  CHECK(c.variance_ratio_low <= c.variance_ratio_high);
  const tileable_change same = compare_tile(maps, maps);
  CHECK(same.largest_mean_shift == 0);
  CHECK(same.variance_ratio_low == doctest::Approx(1));
  CHECK(same.variance_ratio_high == doctest::Approx(1));
  CHECK_NOTHROW(validate_tileable(64, 48, {0.25, false}));
  CHECK_THROWS_AS(validate_tileable(64, 48, {0.6, false}), std::invalid_argument);
  CHECK_THROWS_AS(validate_tileable(64, 4, {0.25, false}), std::invalid_argument);
  CHECK_THROWS_AS(make_tileable(ramp_material(64, 4), {0.25, false}), std::invalid_argument);
}
