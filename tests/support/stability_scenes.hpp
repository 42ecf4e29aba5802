#pragma once
// Scenes and measurements shared by the stability tests (tests/pipeline/stability_test.cpp) and
// the stability report (studies/stability.cpp), so that the report measures what the tests assert.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <utility>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/render/configurations.hpp"

namespace anisocap::testing {

/// Largest |a - b| over the planes [first, last] (alpha: difference modulo pi).
inline double max_difference(const material_maps& a, const material_maps& b, int first, int last) {
  double d = 0;
  for (int k = first; k <= last; ++k)
    for (std::size_t i = 0; i < a.texel_count(); ++i) {
      const double x = a.plane(k)[i], y = b.plane(k)[i];
      d = std::max(d, k == rotation ? std::abs(rotation_difference(x, y)) : std::abs(x - y));
    }
  return d;
}

/// Every photograph with each value clipped at `level` (a sensor's saturation).
inline std::vector<image> clipped(std::vector<image> photos, float level) {
  for (image& p : photos)
    for (int c = 0; c < p.channels(); ++c)
      for (std::size_t i = 0; i < p.pixel_count(); ++i) p.plane(c)[i] = std::min(p.plane(c)[i], level);
  return photos;
}

/// The q-quantile of every pixel value of every photograph.
inline float quantile(const std::vector<image>& photos, double q) {
  std::vector<float> values;
  for (const image& p : photos)
    for (int c = 0; c < p.channels(); ++c) values.insert(values.end(), p.plane(c), p.plane(c) + p.pixel_count());
  const auto k = std::size_t(q * double(values.size() - 1));
  std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(k), values.end());
  return values[k];
}

/// The capture and photographs with every intensity and every pixel multiplied by `factor`: the
/// same physical capture in other units (apply_exposure, the pipeline's own rescaling).
inline std::pair<capture, std::vector<image>> scaled(capture cap, std::vector<image> photos, float factor) {
  apply_exposure(cap, photos, factor);
  return {std::move(cap), std::move(photos)};
}

/// `count` configurations whose cameras and lights lie 75 to 88 degrees from the normal at the
/// point they aim at, 4 to 8 material sizes away (so that the angle changes little across the
/// material); every other one is a mirror configuration (highlight at grazing angles), the rest are
/// independent. Intensity pi d^2 as in configurations.hpp.
inline capture grazing_capture(int count, std::uint64_t seed) {
  random_generator rng(seed);
  auto direction = [&](double azimuth) {
    const double zenith = rng.uniform(75.0, 88.0) * std::numbers::pi / 180.0;
    return std::array<double, 3>{std::sin(zenith) * std::cos(azimuth), std::sin(zenith) * std::sin(azimuth), std::cos(zenith)};
  };
  capture c;
  for (int i = 0; i < count; ++i) {
    const std::array<double, 3> point{rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 0.0};
    const double azimuth = rng.uniform(0.0, 2 * std::numbers::pi);
    const auto view = direction(azimuth);
    const auto light = direction(i % 2 == 0 ? azimuth + std::numbers::pi : rng.uniform(0.0, 2 * std::numbers::pi));
    const double dv = rng.uniform(4.0, 8.0), dl = rng.uniform(4.0, 8.0);
    capture_image im;
    im.file = input_file_name(i);
    for (int a = 0; a < 3; ++a) {
      im.camera[std::size_t(a)] = float(point[std::size_t(a)] + dv * view[std::size_t(a)]);
      im.light[std::size_t(a)] = float(point[std::size_t(a)] + dl * light[std::size_t(a)]);
    }
    const auto intensity = float(configuration_irradiance * dl * dl);
    im.intensity = {intensity, intensity, intensity};
    c.images.push_back(im);
  }
  return c;
}

}  // namespace anisocap::testing
