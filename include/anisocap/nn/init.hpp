#pragma once
/// @file
/// Seeded weight initialisation that gives the same bits on every machine and standard library.
///
/// std:: distributions are implementation-defined (libstdc++ and libc++ draw different numbers),
/// and even a hand-written Box-Muller would depend on the libm's log/cos and on whether the
/// compiler fuses a multiply-add. So: splitmix64 integers; a symmetric uniform value is an exact
/// dyadic number in [-1, 1) times the bound (one rounding); a normal value is the Irwin-Hall sum of
/// twelve 32-bit uniforms (computed exactly in integers, variance 1, tails cut at +-6) times the
/// standard deviation (one rounding). Each parameter draws from a stream seeded by the network's
/// seed and the parameter's name, so adding a layer does not change the others' weights.
#include <cmath>
#include <cstdint>
#include <string_view>

#include "anisocap/core/random.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

/// Weight-initialisation stream: core/random.hpp's splitmix64 (Steele, Lea, Flood 2014), with the
/// exact uniform and Irwin-Hall normal transforms described above (bits identical everywhere).
class random_generator {
 public:
  explicit random_generator(std::uint64_t seed) noexcept : state_(seed) {}

  /// Next 64 random bits.
  std::uint64_t next() noexcept { return splitmix64(state_); }

  /// Uniform in [-1, 1), an exact multiple of 2^-51.
  double symmetric_uniform() noexcept {
    const double u = double(next() >> 12) * 0x1p-52;  // [0, 1) exactly
    return 2 * u - 1;                                 // exact: 2u - 1 is a multiple of 2^-51 in [-1, 1)
  }

  /// Approximately standard normal: Irwin-Hall sum of twelve uniforms minus 6, exact in integers.
  double normal() noexcept {
    std::int64_t sum = 0;
    for (int i = 0; i < 12; ++i) sum += std::int64_t(next() >> 32);
    return double(sum - (std::int64_t(6) << 32)) * 0x1p-32;  // |sum - 6 * 2^32| < 2^35: exact
  }

 private:
  std::uint64_t state_;
};

/// FNV-1a hash of a name, to give each parameter its own stream.
inline std::uint64_t name_hash(std::string_view name) noexcept {
  std::uint64_t h = 0xcbf29ce484222325ULL;
  for (unsigned char c : name) h = (h ^ c) * 0x100000001b3ULL;
  return h;
}

/// The generator for parameter `name` of a network seeded with `seed`.
inline random_generator generator_for(std::uint64_t seed, std::string_view name) noexcept {
  random_generator mix(seed ^ name_hash(name));
  return random_generator(mix.next());
}

/// Fills p with uniform values in [-bound, bound).
template <class T>
void uniform_init(basic_parameter<T>& p, double bound, std::uint64_t seed) {
  auto g = generator_for(seed, p.name);
  for (auto& v : p.value) v = T(g.symmetric_uniform() * bound);
}

/// Fills p with (approximately) normal values of standard deviation `stddev`, mean 0.
template <class T>
void normal_init(basic_parameter<T>& p, double stddev, std::uint64_t seed) {
  auto g = generator_for(seed, p.name);
  for (auto& v : p.value) v = T(g.normal() * stddev);
}

/// He (Kaiming) uniform for (leaky) ReLU layers: bound sqrt(6 / ((1 + slope^2) fan_in)), which keeps
/// activations' variance constant through the layer (He et al. 2015).
template <class T>
void he_uniform(basic_parameter<T>& p, int fan_in, std::uint64_t seed, double slope = 0) {
  uniform_init(p, std::sqrt(6.0 / ((1 + slope * slope) * fan_in)), seed);
}

/// He (Kaiming) normal: standard deviation sqrt(2 / ((1 + slope^2) fan_in)).
template <class T>
void he_normal(basic_parameter<T>& p, int fan_in, std::uint64_t seed, double slope = 0) {
  normal_init(p, std::sqrt(2.0 / ((1 + slope * slope) * fan_in)), seed);
}

/// Xavier (Glorot) uniform for tanh/linear layers: bound sqrt(6 / (fan_in + fan_out)).
template <class T>
void xavier_uniform(basic_parameter<T>& p, int fan_in, int fan_out, std::uint64_t seed) {
  uniform_init(p, std::sqrt(6.0 / (fan_in + fan_out)), seed);
}

/// Xavier (Glorot) normal: standard deviation sqrt(2 / (fan_in + fan_out)).
template <class T>
void xavier_normal(basic_parameter<T>& p, int fan_in, int fan_out, std::uint64_t seed) {
  normal_init(p, std::sqrt(2.0 / (fan_in + fan_out)), seed);
}

/// Sets every value of p to v (biases: 0; norm scales: 1).
template <class T>
void constant_init(basic_parameter<T>& p, T v) {
  for (auto& x : p.value) x = v;
}

}  // namespace anisocap::nn
