#pragma once
/// @file
/// Camera-sensor noise for synthetic captures, so that the evaluation can ask how the pipeline
/// and the configuration sets behave on photographs that are not exact renders: a pixel of value
/// I becomes I + sqrt(shot^2 I + read^2) g, g a standard normal draw, clipped at 0 (a sensor
/// reports no negative light). Shot (photon) noise grows with the signal, read noise does not;
/// `shot` is the relative standard deviation of a pixel of value 1. Seeded and deterministic:
/// the same seed gives the same noise on every machine up to the last bit of libm's log/sin/cos.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/image.hpp"
#include "anisocap/core/random.hpp"

namespace anisocap {

/// Noise levels of a simulated sensor (both 0: no noise).
struct sensor_noise {
  double shot = 0;  ///< shot-noise standard deviation at pixel value 1 (scales with sqrt(I))
  double read = 0;  ///< signal-independent read-noise standard deviation

  /// True when either level is non-zero.
  bool enabled() const noexcept { return shot > 0 || read > 0; }

  /// Throws std::invalid_argument unless both levels are finite and non-negative.
  void validate() const {
    if (!(shot >= 0 && std::isfinite(shot)) || !(read >= 0 && std::isfinite(read)))
      throw std::invalid_argument("sensor noise: shot and read levels must be finite and >= 0 (got " + std::to_string(shot) +
                                  ", " + std::to_string(read) + ")");
  }
};

/// Adds `noise` to every pixel of `photo` in place, drawing from a stream seeded by `seed`.
inline void add_sensor_noise(image& photo, const sensor_noise& noise, std::uint64_t seed) {
  noise.validate();
  if (!noise.enabled()) return;
  const double shot2 = noise.shot * noise.shot, read2 = noise.read * noise.read;
  for (int c = 0; c < photo.channels(); ++c) {
    random_generator rng(hash64(seed ^ hash64(std::uint64_t(c) + 0x6e6f697365ULL)));
    float* p = photo.plane(c);
    for (std::size_t i = 0; i < photo.pixel_count(); ++i) {
      const double v = p[i];
      const double sigma = std::sqrt(shot2 * std::max(v, 0.0) + read2);
      p[i] = float(std::max(0.0, v + sigma * rng.normal()));
    }
  }
}

/// Adds independent noise to each photograph of a capture (photo k draws from seed and k).
inline void add_sensor_noise(std::vector<image>& photos, const sensor_noise& noise, std::uint64_t seed) {
  for (std::size_t k = 0; k < photos.size(); ++k) add_sensor_noise(photos[k], noise, hash64(seed + 0x9e3779b97f4a7c15ULL * (k + 1)));
}

}  // namespace anisocap
