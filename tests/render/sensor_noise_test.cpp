// Simulated sensor noise: its statistics are the stated ones, it is seeded, and it never makes a
// pixel negative.
#include <doctest/doctest.h>

#include <cmath>

#include "anisocap/render/sensor_noise.hpp"

using namespace anisocap;

namespace {
image constant_image(int w, int h, float value) {
  image im(w, h, 3);
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < im.pixel_count(); ++i) im.plane(c)[i] = value;
  return im;
}
}  // namespace

TEST_CASE("sensor noise has the stated mean and standard deviation") {
  const float value = 0.5f;
  const sensor_noise noise{0.05, 0.01};
  image im = constant_image(200, 150, value);
  add_sensor_noise(im, noise, 7);
  double sum = 0, sum2 = 0;
  const double n = 3.0 * im.pixel_count();
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < im.pixel_count(); ++i) {
      sum += im.plane(c)[i];
      sum2 += double(im.plane(c)[i]) * im.plane(c)[i];
    }
  const double mean = sum / n, sd = std::sqrt(sum2 / n - mean * mean);
  const double expected_sd = std::sqrt(0.05 * 0.05 * value + 0.01 * 0.01);
  CHECK(std::abs(mean - value) < 4 * expected_sd / std::sqrt(n));
  CHECK(sd == doctest::Approx(expected_sd).epsilon(0.02));
}

TEST_CASE("sensor noise is seeded: same seed same pixels, other seed or channel other pixels") {
  const sensor_noise noise{0.1, 0.0};
  image a = constant_image(32, 16, 0.3f), b = constant_image(32, 16, 0.3f), c = constant_image(32, 16, 0.3f);
  add_sensor_noise(a, noise, 11);
  add_sensor_noise(b, noise, 11);
  add_sensor_noise(c, noise, 12);
  int same_ab = 0, same_ac = 0, same_channels = 0;
  for (std::size_t i = 0; i < a.pixel_count(); ++i) {
    same_ab += a.plane(0)[i] == b.plane(0)[i];
    same_ac += a.plane(0)[i] == c.plane(0)[i];
    same_channels += a.plane(0)[i] == a.plane(1)[i];
  }
  CHECK(same_ab == int(a.pixel_count()));
  CHECK(same_ac == 0);
  CHECK(same_channels == 0);
  // A capture's photographs get independent noise.
  std::vector<image> photos{constant_image(8, 8, 0.3f), constant_image(8, 8, 0.3f)};
  add_sensor_noise(photos, noise, 5);
  int same_photos = 0;
  for (std::size_t i = 0; i < photos[0].pixel_count(); ++i) same_photos += photos[0].plane(0)[i] == photos[1].plane(0)[i];
  CHECK(same_photos == 0);
}

TEST_CASE("sensor noise keeps pixels non-negative, leaves a noiseless sensor's image alone and rejects bad levels") {
  image dark = constant_image(64, 64, 0.001f);
  add_sensor_noise(dark, sensor_noise{0.0, 0.05}, 3);
  int zeros = 0;
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < dark.pixel_count(); ++i) {
      CHECK_FALSE(dark.plane(c)[i] < 0.0f);
      zeros += dark.plane(c)[i] == 0.0f;
    }
  CHECK(zeros > 0);  // read noise 50x the signal clips about half the pixels
  image clean = constant_image(16, 16, 0.25f);
  add_sensor_noise(clean, sensor_noise{}, 3);
  for (std::size_t i = 0; i < clean.pixel_count(); ++i) CHECK(clean.plane(2)[i] == 0.25f);
  CHECK_THROWS_AS(add_sensor_noise(clean, sensor_noise{-0.1, 0.0}, 3), std::invalid_argument);
  CHECK_THROWS_AS(add_sensor_noise(clean, sensor_noise{0.0, std::nan("")}, 3), std::invalid_argument);
}
