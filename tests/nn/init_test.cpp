// Seeded initialisation (nn/init.hpp): identical for equal seeds, different otherwise, per-name
// streams, and the statistics each scheme promises.
#include <doctest/doctest.h>

#include <cmath>
#include <cstring>

#include "anisocap/nn/init.hpp"
#include "anisocap/nn/linear.hpp"

using namespace anisocap;

namespace {
bool same_bits(const nn::parameter& a, const nn::parameter& b) {
  return a.size() == b.size() && std::memcmp(a.value.data(), b.value.data(), a.size() * sizeof(float)) == 0;
}
}  // namespace

TEST_CASE("init: equal seeds give identical weights, different seeds or names different ones") {
  nn::parameter a("layer.weight", {64, 32}), b("layer.weight", {64, 32}), c("layer.weight", {64, 32}),
      d("other.weight", {64, 32});
  nn::he_normal(a, 32, 7);
  nn::he_normal(b, 32, 7);
  nn::he_normal(c, 32, 8);
  nn::he_normal(d, 32, 7);
  CHECK(same_bits(a, b));
  CHECK_FALSE(same_bits(a, c));
  CHECK_FALSE(same_bits(a, d));
  nn::linear<8, 4> l1("fc", 3), l2("fc", 3), l3("fc", 4);
  CHECK(same_bits(l1.weight, l2.weight));
  CHECK_FALSE(same_bits(l1.weight, l3.weight));
}

TEST_CASE("init: the generator's first values are fixed (same on every machine)") {
  // splitmix64 from seed 0: published reference outputs.
  nn::random_generator g(0);
  CHECK(g.next() == 0xe220a8397b1dcdafULL);
  CHECK(g.next() == 0x6e789e6aa1b965f4ULL);
  // Uniform and normal values are exact functions of those integers.
  nn::random_generator u(0);
  CHECK(u.symmetric_uniform() == double(0xe220a8397b1dcdafULL >> 12) * 0x1p-51 - 1);
}

TEST_CASE("init: statistics of the schemes") {
  nn::parameter p("p", {256, 256});
  const double n = double(p.size());
  auto moments = [&](double& mean, double& var, double& maxabs) {
    mean = var = maxabs = 0;
    for (float v : p.value) { mean += v; maxabs = std::max(maxabs, double(std::abs(v))); }
    mean /= n;
    for (float v : p.value) var += (v - mean) * (v - mean);
    var /= n;
  };
  double mean, var, maxabs;
  nn::he_uniform(p, 128, 1);
  moments(mean, var, maxabs);
  const double bound = std::sqrt(6.0 / 128);
  CHECK(maxabs <= bound);
  CHECK(maxabs > 0.99 * bound);
  CHECK(var == doctest::Approx(2.0 / 128).epsilon(0.02));  // He: variance 2 / fan_in
  CHECK(std::abs(mean) < 0.02 * std::sqrt(var));  // 5 standard errors of the mean
  nn::he_normal(p, 128, 2);
  moments(mean, var, maxabs);
  CHECK(var == doctest::Approx(2.0 / 128).epsilon(0.02));
  CHECK(maxabs <= 6 * std::sqrt(2.0 / 128));  // Irwin-Hall tails end at 6 sigma
  CHECK(maxabs > 3.5 * std::sqrt(2.0 / 128));  // but reach well beyond 3 sigma on 65536 draws
  nn::xavier_uniform(p, 100, 300, 3);
  moments(mean, var, maxabs);
  CHECK(var == doctest::Approx(2.0 / 400).epsilon(0.02));
}
