// Tests for core/simd.hpp: the estimate-based helpers (inverse_sqrt, reciprocal, log_positive), every
// lane of the SIMD build against the double-precision value over many decades, in ulp of float; min,
// max and the double square root against their scalar definitions, bit for bit.
#include <doctest/doctest.h>

#include <cmath>
#include <cstring>
#include <limits>
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

TEST_CASE_TEMPLATE("simd::min and simd::max are a < b ? a : b and a > b ? a : b in every lane, NaN and signed zeros included", T, float, double) {
  using B = simd::batch<T>;
  constexpr std::size_t W = simd::lanes_v<B>;
  const T nan = std::numeric_limits<T>::quiet_NaN(), inf = std::numeric_limits<T>::infinity();
  const std::vector<T> values = {T(0), -T(0), T(1), T(-1), T(2.5), T(1e-30), -inf, inf, nan, T(3)};
  std::vector<T> a, b;
  for (T x : values)
    for (T y : values) { a.push_back(x); b.push_back(y); }
  while (a.size() % W) { a.push_back(T(0)); b.push_back(T(0)); }
  alignas(simd::alignment) T ia[W], ib[W], lo[W], hi[W];
  for (std::size_t i = 0; i < a.size(); i += W) {
    for (std::size_t l = 0; l < W; ++l) { ia[l] = a[i + l]; ib[l] = b[i + l]; }
    simd::store<B>(lo, simd::min(simd::load<B>(ia), simd::load<B>(ib)));
    simd::store<B>(hi, simd::max(simd::load<B>(ia), simd::load<B>(ib)));
    for (std::size_t l = 0; l < W; ++l) {
      const T want_lo = ia[l] < ib[l] ? ia[l] : ib[l], want_hi = ia[l] > ib[l] ? ia[l] : ib[l];
      INFO(ia[l], " ", ib[l]);
      // Bitwise: the same lane, so -0 and +0 and NaN are told apart.
      CHECK(std::memcmp(&lo[l], &want_lo, sizeof(T)) == 0);
      CHECK(std::memcmp(&hi[l], &want_hi, sizeof(T)) == 0);
    }
  }
}

TEST_CASE("simd::sqrt of double batches is the correctly rounded square root in every lane") {
  using B = simd::batch<double>;
  constexpr std::size_t W = simd::lanes_v<B>;
  std::vector<double> x = {0.0, -0.0, 1.0, 2.0, 1e-300, 1e300, 0.25, 3.0, std::numeric_limits<double>::infinity(), 7.5e-5};
  while (x.size() % W) x.push_back(4.0);
  alignas(simd::alignment) double in[W], out[W];
  for (std::size_t i = 0; i < x.size(); i += W) {
    for (std::size_t l = 0; l < W; ++l) in[l] = x[i + l];
    simd::store<B>(out, simd::sqrt(simd::load<B>(in)));
    for (std::size_t l = 0; l < W; ++l) {
      const double want = std::sqrt(in[l]);
      CHECK(std::memcmp(&out[l], &want, sizeof(double)) == 0);
    }
  }
}
