#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/core/simd.hpp"
#include "support/gradient_check.hpp"

using namespace anisocap;
using D3 = ad::dual<double, 3>;

// A function exercising every dual operation.
template <class T>
T composite(const T& a, const T& b, const T& c) {
  using std::exp; using std::log; using std::sqrt; using std::sin; using std::cos;
  using ad::exp; using ad::log; using ad::sqrt; using ad::sin; using ad::cos;
  T r = a * b / (c + 2.0) - 3.0 / (a * a + 1.0) + exp(-b * b) * log(c * c + 0.5);
  r += sqrt(a * a + b * b + 1.0) * sin(c) - cos(a * b);
  r -= 2.0 - c;
  return r * 0.5 + (1.0 / (b + 3.0));
}

TEST_CASE("dual gradients match central finite differences in double") {
  std::mt19937 gen(7);
  std::uniform_real_distribution<double> u(-1.5, 1.5);
  for (int trial = 0; trial < 200; ++trial) {
    double x[3] = {u(gen), u(gen), u(gen) + 0.3};
    const D3 r = composite(D3::variable(x[0], 0), D3::variable(x[1], 1), D3::variable(x[2], 2));
    const double analytic[3] = {r.grad[0], r.grad[1], r.grad[2]};
    auto res = testing::check_gradient<double>([&] { return composite(x[0], x[1], x[2]); }, x, 3, analytic, 1e-6);
    CHECK(res.max_rel_error < 1e-7);
    CHECK(r.value == doctest::Approx(composite(x[0], x[1], x[2])).epsilon(1e-14));
  }
}

TEST_CASE("pow_int, select, min and max") {
  const D3 x = D3::variable(1.7, 1);
  const D3 p = ad::pow_int<5>(x);
  CHECK(p.value == doctest::Approx(std::pow(1.7, 5)));
  CHECK(p.grad[1] == doctest::Approx(5 * std::pow(1.7, 4)));
  CHECK(p.grad[0] == 0.0);
  CHECK(ad::max(x, 2.0).grad[1] == 0.0);
  CHECK(ad::max(x, 1.0).grad[1] == 1.0);
  CHECK(ad::min(x, 1.0).value == 1.0);
  CHECK(ad::select(true, x, D3(4.0)).grad[1] == 1.0);
}

TEST_CASE("dual over SIMD batches equals lane-wise scalar duals") {
  using V = simd::batch<float>;
  constexpr std::size_t L = simd::lanes_v<V>;
  alignas(64) float a[L], b[L], c[L];
  for (std::size_t i = 0; i < L; ++i) { a[i] = 0.1f * float(i) - 0.4f; b[i] = 0.3f + 0.05f * float(i); c[i] = 0.7f - 0.02f * float(i); }
  using DV = ad::dual<V, 3>;
  auto r = composite(DV::variable(V::load_aligned(a), 0), DV::variable(V::load_aligned(b), 1), DV::variable(V::load_aligned(c), 2));
  alignas(64) float val[L], g0[L], g2[L];
  r.value.store_aligned(val); r.grad[0].store_aligned(g0); r.grad[2].store_aligned(g2);
  for (std::size_t i = 0; i < L; ++i) {
    const D3 s = composite(D3::variable(a[i], 0), D3::variable(b[i], 1), D3::variable(c[i], 2));
    CHECK(val[i] == doctest::Approx(s.value).epsilon(1e-5));
    CHECK(g0[i] == doctest::Approx(s.grad[0]).epsilon(1e-4));
    CHECK(g2[i] == doctest::Approx(s.grad[2]).epsilon(1e-4));
  }
}
