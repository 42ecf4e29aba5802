// Hundreds of thousands of random and extreme cases through the fused kernel: values and gradients
// stay finite; where the function is smooth, dual derivatives agree with finite differences.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "anisocap/render/renderer.hpp"
#include "render_reference.hpp"
#include "support/gradient_check.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

/// Maps mixing ordinary and extreme texels.
material_maps extreme_maps(int w, int h, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  auto pick = [&](std::initializer_list<float> v) { return *(v.begin() + std::size_t(u(gen) * float(v.size()) * 0.9999f)); };
  material_maps m(w, h);
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    for (int c = 0; c < 6; ++c) m.plane(c)[i] = u(gen) < 0.2f ? pick({0.0f, 1.0f}) : u(gen);
    for (int k : {lobe_x, lobe_y}) m.plane(k)[i] = u(gen) < 0.4f ? pick({1e-4f, 2e-4f, 1e-3f, 1.0f}) : u(gen);
    m.plane(fresnel_f0)[i] = u(gen) < 0.4f ? pick({0.0f, 1.0f}) : u(gen);
    float r = u(gen) < 0.3f ? pick({0.999f, 0.99999f, 1.0f}) : u(gen);
    const float phi = 2 * std::numbers::pi_v<float> * u(gen);
    m.plane(normal_x)[i] = r * std::cos(phi);
    m.plane(normal_y)[i] = r * std::sin(phi);
    m.plane(rotation)[i] = u(gen) < 0.3f ? pick({-std::numbers::pi_v<float> / 2, std::numbers::pi_v<float> / 2}) : 3.2f * (u(gen) - 0.5f);
  }
  return m;
}

/// Configurations: grazing view and light, mirror (h_z -> 0 when both graze opposite), lights below
/// the plane, intensities from 1e-6 to 1e6, lights touching the surface.
capture extreme_capture(int n, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  capture c;
  for (int i = 0; i < n; ++i) {
    capture_image im;
    const float az = 3.14159f * u(gen);
    const float elev_v = i % 3 == 0 ? 1e-4f : 0.02f + 0.7f * (u(gen) + 1.0f);
    const float elev_l = i % 4 == 0 ? -0.3f : (i % 3 == 0 ? 1e-4f : 0.02f + 0.7f * (u(gen) + 1.0f));
    const float dv = 2.0f + u(gen), dl = i % 5 == 0 ? 1e-3f : 2.0f + u(gen);
    im.camera = {dv * std::cos(az) * std::cos(elev_v), dv * std::sin(az) * std::cos(elev_v), std::max(dv * std::sin(elev_v), 1e-6f)};
    im.light = {-dl * std::cos(az) * std::cos(elev_l), -dl * std::sin(az) * std::cos(elev_l), dl * std::sin(elev_l)};
    const float intensity = std::pow(10.0f, -6.0f + 12.0f * 0.5f * (u(gen) + 1.0f));
    im.intensity = {intensity, intensity * 0.5f, intensity * 2.0f};
    c.images.push_back(im);
  }
  return c;
}

template <brdf_features F>
void check_finite(std::uint64_t seed, std::size_t& evaluations) {
  const int w = 96, h = 80;
  const material_maps maps = extreme_maps(w, h, seed);
  const capture cap = extreme_capture(12, seed + 1);
  const auto images = render<F>(maps, cap);
  for (const auto& im : images)
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < im.pixel_count(); ++i) REQUIRE(std::isfinite(im.plane(c)[i]));
  const loss_targets targets = make_loss_targets(render<F>(extreme_maps(w, h, seed + 2), cap));
  material_maps grad(w, h);
  render_options culled;
  culled.cull_tolerance = 1e-3f;
  for (const render_options& o : {render_options{}, culled}) {
    const double loss = loss_and_gradient<F>(maps, cap, targets, &grad, {}, o);
    REQUIRE(std::isfinite(loss));
    for (int k = 0; k < parameter_count; ++k)
      for (std::size_t i = 0; i < maps.texel_count(); ++i) REQUIRE(std::isfinite(grad.plane(k)[i]));
    evaluations += maps.texel_count() * cap.images.size();
  }
}

}  // namespace

TEST_CASE("stress: no NaN or Inf in renders, losses or gradients over extreme cases") {
  std::size_t evaluations = 0;
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    check_finite<all_features>(seed * 10, evaluations);
    check_finite<brdf_features{false, false, false}>(seed * 10 + 3, evaluations);
  }
  check_finite<brdf_features{false, true, true}>(900, evaluations);
  check_finite<brdf_features{true, false, true}>(901, evaluations);
  check_finite<brdf_features{true, true, false}>(902, evaluations);
  MESSAGE("texel-image evaluations checked: " << evaluations);
  CHECK(evaluations >= 300000);
}

TEST_CASE("stress: duals agree with finite differences at extreme but smooth parameters") {
  // Narrow lobes (1e-3), F0 near 0 and 1, normals near the horizon, grazing directions: in double,
  // away from the clamps, the reference's dual gradient equals central differences.
  std::mt19937_64 gen(42);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int checked = 0;
  for (int trial = 0; trial < 4000 && checked < 1500; ++trial) {
    double q[12];
    for (int i = 0; i < 6; ++i) q[i] = u(gen);
    q[6] = u(gen) < 0.5 ? 1e-3 * (1 + u(gen)) : 0.05 + u(gen) * 0.9;
    q[7] = u(gen) < 0.5 ? 1e-3 * (1 + u(gen)) : 0.05 + u(gen) * 0.9;
    q[8] = u(gen) < 0.5 ? (u(gen) < 0.5 ? 1e-3 : 0.999) : u(gen);
    const double r = u(gen) < 0.3 ? 0.995 : 0.9 * u(gen), phi = 2 * std::numbers::pi * u(gen);
    q[9] = r * std::cos(phi); q[10] = r * std::sin(phi); q[11] = (u(gen) - 0.5) * std::numbers::pi;
    const double el = u(gen) < 0.5 ? 0.01 + 0.05 * u(gen) : 0.1 + 1.4 * u(gen), az = 2 * std::numbers::pi * u(gen);
    const double el2 = 0.01 + 1.5 * u(gen), az2 = az + std::numbers::pi + 0.3 * (u(gen) - 0.5);
    const std::array<double, 3> l{std::cos(az) * std::cos(el), std::sin(az) * std::cos(el), std::sin(el)};
    const std::array<double, 3> v{std::cos(az2) * std::cos(el2), std::sin(az2) * std::cos(el2), std::sin(el2)};
    using D = ad::dual<double, 12>;
    ward_parameters<D> pd;
    ward_parameters<double> pp;
    auto set = [&] {
      for (int c = 0; c < 3; ++c) { pp.diffuse[c] = q[c]; pp.specular[c] = q[3 + c]; }
      pp.sx = q[6]; pp.sy = q[7]; pp.f0 = q[8]; pp.nx = q[9]; pp.ny = q[10]; pp.alpha = q[11];
    };
    set();
    for (int c = 0; c < 3; ++c) { pd.diffuse[c] = D::variable(q[c], c); pd.specular[c] = D::variable(q[3 + c], 3 + c); }
    pd.sx = D::variable(q[6], 6); pd.sy = D::variable(q[7], 7); pd.f0 = D::variable(q[8], 8);
    pd.nx = D::variable(q[9], 9); pd.ny = D::variable(q[10], 10); pd.alpha = D::variable(q[11], 11);
    const auto f = ward_evaluate(pd, l, v);
    // Smooth region: lit, seen, lobe exponent moderate (the relative step stays meaningful).
    if (f[0].value <= 0.0 || !(f[0].value < 1e6)) continue;
    // Normalise by the value so the check is relative; narrow lobes need a small step.
    const double norm = 1.0 / std::max(1.0, f[0].value);
    double analytic[12];
    for (int i = 0; i < 12; ++i) analytic[i] = f[0].grad[i] * norm;
    auto res = testing::check_gradient<double>([&] { set(); return ward_evaluate(pp, l, v)[0] * norm; }, q, 12, analytic, 1e-8);
    INFO("trial " << trial << " parameter " << res.worst_index << " value " << f[0].value);
    CHECK(res.max_rel_error < 1e-4);
    ++checked;
  }
  CHECK(checked > 500);
}
