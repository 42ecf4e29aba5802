#pragma once
/// @file
/// Seeded randomness that is the same on every machine and compiler: SplitMix64 (seeding and
/// stateless hashing) and xoshiro256** (the stream), both as published by Blackman and Vigna
/// (https://prng.di.unimi.it), with our own uniform, integer and normal draws.
///
/// Why not <random>: the engines are portable but the distributions (std::uniform_real_distribution,
/// std::normal_distribution, ...) are implementation-defined and differ between libstdc++, libc++
/// and MSVC, so a seed would describe a different capture or material on each (docs/method.md section 6 asks for
/// "the same configuration on every machine").
///
/// What is bit-identical everywhere: next_u64(), uniform() (an exact conversion of 53 bits),
/// uniform_int() and the hashes (integer arithmetic only). Draws that go through libm (normal())
/// or through a multiply-add (uniform(a, b)) are exact IEEE operations except for the last-bit
/// differences a platform's libm or FMA contraction may introduce; callers that store float
/// results (configurations, material maps) compute in double and round, which hides those.
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>

namespace anisocap {

/// One step of SplitMix64 (Steele, Lea and Flood 2014; Vigna's splitmix64.c): advances `state`
/// by the golden-ratio increment and returns the mixed value. Seed 1234567 gives
/// 6457827717110365317, 3203168211198807973, ... (the published reference outputs).
constexpr std::uint64_t splitmix64(std::uint64_t& state) noexcept {
  std::uint64_t z = (state += 0x9e3779b97f4a7c15ULL);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

/// Stateless 64-bit hash of one word (the SplitMix64 output for state `x`): every input bit
/// affects every output bit, so consecutive integers give unrelated values.
constexpr std::uint64_t hash64(std::uint64_t x) noexcept { return splitmix64(x); }

/// Hash of a seed and two signed lattice coordinates, for per-thread and per-cell variation in
/// procedural textures: the coordinates are spread by two different odd constants (so (a, b) and
/// (b, a) differ) and mixed twice, which is enough to decorrelate neighbouring lattice points and
/// costs half of chaining three full hashes (value noise evaluates four per sample).
constexpr std::uint64_t hash64(std::uint64_t seed, std::int64_t a, std::int64_t b) noexcept {
  const std::uint64_t spread = static_cast<std::uint64_t>(a) * 0xd1b54a32d192ed03ULL ^
                               static_cast<std::uint64_t>(b) * 0xaef17502108ef2d9ULL;
  return hash64(hash64(seed) ^ spread);
}

/// Maps 64 random bits to a double in [0, 1) exactly (the top 53 bits times 2^-53).
constexpr double bits_to_unit(std::uint64_t bits) noexcept {
  return static_cast<double>(bits >> 11) * 0x1.0p-53;
}

/// A uniform value in [0, 1) attached to (seed, a, b): the same everywhere, no state.
constexpr double hash_uniform(std::uint64_t seed, std::int64_t a, std::int64_t b = 0) noexcept {
  return bits_to_unit(hash64(seed, a, b));
}

/// Smooth 2-D value noise in [0, 1): random values on the integer lattice, blended with the
/// quintic fade 6t^5 - 15t^4 + 10t^3 (continuous value and slope), so a texture can vary slowly
/// across texels (slubs in a thread, crushed velvet) without a stored table.
inline double value_noise(std::uint64_t seed, double x, double y) noexcept {
  const double fx = std::floor(x), fy = std::floor(y);
  const auto ix = static_cast<std::int64_t>(fx), iy = static_cast<std::int64_t>(fy);
  const double tx = x - fx, ty = y - fy;
  const double sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0);
  const double sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0);
  const double v00 = hash_uniform(seed, ix, iy), v10 = hash_uniform(seed, ix + 1, iy);
  const double v01 = hash_uniform(seed, ix, iy + 1), v11 = hash_uniform(seed, ix + 1, iy + 1);
  const double top = v00 + (v10 - v00) * sx, bottom = v01 + (v11 - v01) * sx;
  const double v = top + (bottom - top) * sy;
  return v < 1.0 ? v : std::nextafter(1.0, 0.0);  // rounding of the blend must not reach 1
}

/// Sum of `octaves` value-noise layers, each at twice the frequency and half the amplitude of the
/// previous one, normalised back to [0, 1): fractal detail for scratches and fibres.
inline double fractal_noise(std::uint64_t seed, double x, double y, int octaves) noexcept {
  double sum = 0.0, amplitude = 1.0, total = 0.0, frequency = 1.0;
  for (int o = 0; o < octaves; ++o) {
    sum += amplitude * value_noise(hash64(seed + static_cast<std::uint64_t>(o)), x * frequency, y * frequency);
    total += amplitude;
    amplitude *= 0.5;
    frequency *= 2.0;
  }
  const double v = total > 0.0 ? sum / total : 0.0;
  return v < 1.0 ? v : std::nextafter(1.0, 0.0);
}

/// xoshiro256** 1.0 (Blackman and Vigna 2018), seeded by four SplitMix64 outputs as its authors
/// recommend. State {1, 2, 3, 4} gives 11520, 0, 1509978240, 1215971899390074240, ...
/// Small (32 bytes), fast, and passes BigCrush; not for cryptography.
class random_generator {
 public:
  /// The four state words of xoshiro256**.
  using state_type = std::array<std::uint64_t, 4>;

  /// Seeds the state with SplitMix64(seed) outputs (never all zero, whatever the seed).
  explicit constexpr random_generator(std::uint64_t seed = 0) noexcept {
    std::uint64_t s = seed;
    for (auto& word : state_) word = splitmix64(s);
  }

  /// A generator with an explicit state (for reference vectors); an all-zero state is replaced by
  /// the seed-0 state, since xoshiro would output zeros forever.
  static constexpr random_generator from_state(const state_type& state) noexcept {
    random_generator r;
    if (state[0] | state[1] | state[2] | state[3]) r.state_ = state;
    return r;
  }

  /// The current state (to save and restore a stream).
  constexpr const state_type& state() const noexcept { return state_; }

  /// The next 64 random bits.
  constexpr std::uint64_t next_u64() noexcept {
    const std::uint64_t result = rotl(state_[1] * 5, 7) * 9;
    const std::uint64_t t = state_[1] << 17;
    state_[2] ^= state_[0];
    state_[3] ^= state_[1];
    state_[1] ^= state_[2];
    state_[0] ^= state_[3];
    state_[2] ^= t;
    state_[3] = rotl(state_[3], 45);
    return result;
  }

  /// A double in [0, 1), bit-identical on every platform.
  constexpr double uniform() noexcept { return bits_to_unit(next_u64()); }

  /// A double in [a, b) (up to rounding of a + (b - a) u).
  constexpr double uniform(double a, double b) noexcept { return a + (b - a) * uniform(); }

  /// An integer in [0, n), unbiased (Lemire's multiply-and-reject); 0 when n is 0.
  constexpr std::uint64_t uniform_int(std::uint64_t n) noexcept {
    if (n == 0) return 0;
    std::uint64_t high = 0, low = multiply_wide(next_u64(), n, high);
    if (low < n) {
      const std::uint64_t threshold = (0 - n) % n;  // 2^64 mod n
      while (low < threshold) low = multiply_wide(next_u64(), n, high);
    }
    return high;
  }

  /// True with probability p.
  constexpr bool bernoulli(double p) noexcept { return uniform() < p; }

  /// A standard normal value by the Box-Muller transform, written out (std::normal_distribution
  /// differs between standard libraries). Uses 1 - u so the logarithm never sees 0; the second
  /// value of each pair is kept for the next call.
  double normal() noexcept {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double u1 = 1.0 - uniform();  // (0, 1]
    const double u2 = uniform();
    const double radius = std::sqrt(-2.0 * std::log(u1));
    const double angle = 2.0 * std::numbers::pi * u2;
    spare_ = radius * std::sin(angle);
    has_spare_ = true;
    return radius * std::cos(angle);
  }

  /// A normal value with the given mean and standard deviation.
  double normal(double mean, double deviation) noexcept { return mean + deviation * normal(); }

  /// A new generator whose stream is unrelated to this one's continuation (seeded by a draw):
  /// lets a sampler hand independent streams to sub-tasks while staying reproducible.
  constexpr random_generator split() noexcept { return random_generator(next_u64()); }

 private:
  static constexpr std::uint64_t rotl(std::uint64_t x, int k) noexcept { return (x << k) | (x >> (64 - k)); }

  /// Full 128-bit product a * b as (high, returned low), in portable 32-bit pieces (no __int128).
  static constexpr std::uint64_t multiply_wide(std::uint64_t a, std::uint64_t b, std::uint64_t& high) noexcept {
    const std::uint64_t a0 = a & 0xffffffffULL, a1 = a >> 32, b0 = b & 0xffffffffULL, b1 = b >> 32;
    const std::uint64_t p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    const std::uint64_t middle = (p00 >> 32) + (p01 & 0xffffffffULL) + (p10 & 0xffffffffULL);
    high = p11 + (p01 >> 32) + (p10 >> 32) + (middle >> 32);
    return (middle << 32) | (p00 & 0xffffffffULL);
  }

  state_type state_{};
  double spare_ = 0.0;
  bool has_spare_ = false;
};

}  // namespace anisocap
