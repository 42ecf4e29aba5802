#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "anisocap/brdf/ward.hpp"
#include "support/gradient_check.hpp"

using namespace anisocap;
using D = ad::dual<double, 12>;

namespace {
std::array<double, 3> unit(double x, double y, double z) {
  const double n = std::sqrt(x * x + y * y + z * z);
  return {x / n, y / n, z / n};
}
ward_parameters<D> seeded(const double* q) {
  ward_parameters<D> p;
  for (int c = 0; c < 3; ++c) { p.diffuse[c] = D::variable(q[c], c); p.specular[c] = D::variable(q[3 + c], 3 + c); }
  p.sx = D::variable(q[6], 6); p.sy = D::variable(q[7], 7); p.f0 = D::variable(q[8], 8);
  p.nx = D::variable(q[9], 9); p.ny = D::variable(q[10], 10); p.alpha = D::variable(q[11], 11);
  return p;
}
ward_parameters<double> plain(const double* q) {
  ward_parameters<double> p;
  for (int c = 0; c < 3; ++c) { p.diffuse[c] = q[c]; p.specular[c] = q[3 + c]; }
  p.sx = q[6]; p.sy = q[7]; p.f0 = q[8]; p.nx = q[9]; p.ny = q[10]; p.alpha = q[11];
  return p;
}
}  // namespace

TEST_CASE("ward BRDF: the 12 dual derivatives match finite differences in double") {
  std::mt19937_64 gen(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int checked = 0;
  for (int trial = 0; trial < 300; ++trial) {
    double q[12];
    for (int i = 0; i < 6; ++i) q[i] = 0.1 + 0.8 * u(gen);
    q[6] = 0.05 + 0.6 * u(gen); q[7] = 0.05 + 0.6 * u(gen); q[8] = 0.05 + 0.9 * u(gen);
    const double r = 0.5 * u(gen), phi = 2 * std::numbers::pi * u(gen);
    q[9] = r * std::cos(phi); q[10] = r * std::sin(phi); q[11] = (u(gen) - 0.5) * 3.0;
    const auto l = unit(u(gen) - 0.5, u(gen) - 0.5, 0.2 + u(gen));
    const auto v = unit(u(gen) - 0.5, u(gen) - 0.5, 0.2 + u(gen));
    const auto fd = ward_evaluate(seeded(q), l, v);
    for (int c = 0; c < 3; ++c) {
      if (fd[c].value == 0.0) continue;
      double analytic[12];
      for (int i = 0; i < 12; ++i) analytic[i] = fd[c].grad[i];
      auto res = testing::check_gradient<double>([&] { return ward_evaluate(plain(q), l, v)[c]; }, q, 12, analytic, 1e-7);
      INFO("trial " << trial << " worst parameter " << res.worst_index);
      CHECK(res.max_rel_error < 1e-5);
      ++checked;
    }
  }
  CHECK(checked > 500);
}

TEST_CASE("ward BRDF: reduces to Lambert without a specular albedo, and to the isotropic lobe when sx == sy") {
  double q[12] = {0.3, 0.5, 0.7, 0, 0, 0, 0.2, 0.2, 0.5, 0.1, -0.2, 0.0};
  const auto l = unit(0.3, -0.2, 1.0), v = unit(-0.4, 0.1, 0.8);
  const auto f = ward_evaluate(plain(q), l, v);
  for (int c = 0; c < 3; ++c) CHECK(f[c] == doctest::Approx(q[c] / std::numbers::pi));
  q[3] = q[4] = q[5] = 0.6;
  const auto iso = ward_evaluate<brdf_features{false, true, true}>(plain(q), l, v);
  for (double a : {-1.2, 0.0, 0.7}) {  // alpha is irrelevant when sx == sy
    q[11] = a;
    const auto full = ward_evaluate(plain(q), l, v);
    CHECK(full[0] == doctest::Approx(iso[0]).epsilon(1e-12));
  }
}

TEST_CASE("ward BRDF: alpha is pi-periodic and swapping lobes equals rotating by pi/2") {
  double q[12] = {0.2, 0.2, 0.2, 0.5, 0.5, 0.5, 0.1, 0.4, 0.3, 0.15, 0.05, 0.3};
  const auto l = unit(0.5, 0.2, 1.0), v = unit(-0.45, -0.1, 0.9);
  const double base = ward_evaluate(plain(q), l, v)[0];
  q[11] += std::numbers::pi;
  CHECK(ward_evaluate(plain(q), l, v)[0] == doctest::Approx(base).epsilon(1e-10));
  q[11] = 0.3 + std::numbers::pi / 2;
  std::swap(q[6], q[7]);
  CHECK(ward_evaluate(plain(q), l, v)[0] == doctest::Approx(base).epsilon(1e-10));
}

TEST_CASE("ward BRDF: Schlick Fresnel grows towards grazing angles, Fresnel-free kernel uses F = F0") {
  double q[12] = {0.0, 0.0, 0.0, 0.5, 0.5, 0.5, 0.3, 0.3, 0.04, 0, 0, 0};
  // Mirror configurations at decreasing elevation: the specular peak grows with Fresnel.
  double previous = 0;
  for (double elev : {1.2, 0.8, 0.4, 0.15}) {
    const auto l = unit(std::cos(elev), 0, std::sin(elev)), v = unit(-std::cos(elev), 0, std::sin(elev));
    const double with = ward_evaluate(plain(q), l, v)[0];
    const double without = ward_evaluate<brdf_features{true, false, true}>(plain(q), l, v)[0];
    CHECK(with > without);
    CHECK(with / without > previous);
    previous = with / without;
  }
}
