// Tests for core/simd.hpp's estimate-based helpers (inverse_sqrt, reciprocal, log_positive): every
// lane of the SIMD build against the double-precision value over many decades, in ulp of float.
#include <doctest/doctest.h>

#include <cmath>
#include <vector>

#include "anisocap/core/simd.hpp"

using namespace anisocap;

namespace {

using V = simd::batch<float>;
constexpr std::size_t L = simd::lanes_v<V>;

/// Inputs spread log-uniformly over [lo, hi], padded to whole registers.
std::vector<float> log_spread(double lo, double hi, std::size_t n) {
  std::vector<float> x(n);
  for (std::size_t i = 0; i < n; ++i) x[i] = float(lo * std::pow(hi / lo, double(i) / double(n - 1)));
  return x;
}

/// Largest error of f's SIMD build against `exact`, in units of the float spacing at the exact value.
template <class F, class E>
double max_ulp(const std::vector<float>& x, F f, E exact) {
  double worst = 0;
  alignas(simd::alignment) float in[L], out[L];
  for (std::size_t i = 0; i + L <= x.size(); i += L) {
    for (std::size_t l = 0; l < L; ++l) in[l] = x[i + l];
    simd::store<V>(out, f(simd::load<V>(in)));
    for (std::size_t l = 0; l < L; ++l) {
      const double e = exact(double(in[l]));
      const double ulp = std::nextafter(float(std::abs(e)), INFINITY) - float(std::abs(e));
      worst = std::max(worst, std::abs(double(out[l]) - e) / ulp);
    }
  }
  return worst;
}

}  // namespace

TEST_CASE("inverse_sqrt and reciprocal are within 3 ulp over 1e-6 .. 1e12") {
  const auto x = log_spread(1e-6, 1e12, 4096 * L);
  CHECK(max_ulp(x, [](V v) { return simd::inverse_sqrt(v); }, [](double d) { return 1.0 / std::sqrt(d); }) <= 3.0);
  CHECK(max_ulp(x, [](V v) { return simd::reciprocal(v); }, [](double d) { return 1.0 / d; }) <= 3.0);
}

TEST_CASE("log_positive is within 2 ulp (or 1e-7 absolute near 1) over 1e-30 .. 1e30") {
  auto x = log_spread(1e-30, 1e30, 8192 * L);
  for (float v : log_spread(0.5, 2.0, 4096 * L)) x.push_back(v);  // dense around log = 0
  alignas(simd::alignment) float in[L], out[L];
  double worst = 0;
  for (std::size_t i = 0; i + L <= x.size(); i += L) {
    for (std::size_t l = 0; l < L; ++l) in[l] = x[i + l];
    simd::store<V>(out, simd::log_positive(simd::load<V>(in)));
    for (std::size_t l = 0; l < L; ++l) {
      const double e = std::log(double(in[l]));
      const double ulp = std::nextafter(float(std::abs(e)), INFINITY) - float(std::abs(e));
      const double err = std::abs(double(out[l]) - e);
      if (err > 1e-7) worst = std::max(worst, err / ulp);
    }
  }
  CHECK(worst <= 2.0);
  // The scalar build is the standard library's.
  CHECK(simd::log_positive(2.5f) == std::log(2.5f));
}
