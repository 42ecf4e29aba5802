// Network space (networks/network_space.hpp): round trips per parameter, ranges, the chain rule
// of network_to_maps against finite differences, and the photographs' eq. 7 map.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <numbers>
#include <random>
#include <utility>

#include "anisocap/core/random.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/network_space.hpp"

using namespace anisocap;
namespace ns = anisocap::network_space;

TEST_CASE("network space: every parameter round-trips and valid values land in [-1, 1]") {
  const material_maps maps = generate_material(7, 24, 17);
  tensor<parameter_count> u(1, 17, 24);
  ns::maps_to_network(maps, u, 0);
  for (std::size_t i = 0; i < u.size(); ++i) {
    CHECK(u.data()[i] >= -1.0f - 1e-6f);
    CHECK(u.data()[i] <= 1.0f + 1e-6f);
  }
  const material_maps back = ns::network_to_maps(u, 0);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < 17; ++y)
      for (int x = 0; x < 24; ++x) {
        const double v = maps.at(k, x, y), w = back.at(k, x, y);
        if (k == rotation) {
          // alpha is pi-periodic: compare modulo pi.
          const double d = v - w;
          CHECK(std::abs(d - std::numbers::pi * std::nearbyint(d / std::numbers::pi)) < 1e-5);
        } else if (k == lobe_x || k == lobe_y) {
          CHECK(w == doctest::Approx(std::max(v, double(min_lobe_width))).epsilon(1e-4));
        } else {
          CHECK(w == doctest::Approx(v).epsilon(1e-5));
        }
      }
}

TEST_CASE("network space: range ends map to the documented values") {
  CHECK(ns::to_network(lobe_x, 1.0) == doctest::Approx(1.0));
  CHECK(ns::to_network(lobe_y, 1e-4) == doctest::Approx(-1.0));
  CHECK(ns::to_network(lobe_y, 1e-9) == doctest::Approx(-1.0));  // below the range: clamped
  CHECK(ns::to_network(diffuse_g, 0.0) == -1.0);
  CHECK(ns::to_network(fresnel_f0, 1.0) == 1.0);
  CHECK(ns::to_network(rotation, std::numbers::pi / 2 - 1e-9) == doctest::Approx(1.0));
  CHECK(ns::to_network(rotation, std::numbers::pi * 0.75) == doctest::Approx(-0.5));  // wrapped by pi
  CHECK(ns::input_value(0.0) == doctest::Approx(-1.0));
  CHECK(ns::input_value(1.0) == doctest::Approx(1.0));
  // Decoded normals never leave the disc of radius 0.999.
  tensor<parameter_count> u(1, 1, 1);
  u(0, 0, 0, normal_x) = 0.9f;
  u(0, 0, 0, normal_y) = -0.9f;
  const material_maps m = ns::network_to_maps(u, 0);
  CHECK(std::hypot(m.at(normal_x, 0, 0), m.at(normal_y, 0, 0)) == doctest::Approx(0.999).epsilon(1e-5));
}

TEST_CASE("network space: network_to_maps is from_network texel by texel, at any width, in parallel, into a reused map set") {
  // 131 x 129 runs rows in parallel; 131 is no whole number of SIMD batches. Entry 1 of 2.
  const int W = 131, H = 129;
  tensor<parameter_count> u(2, H, W);
  random_generator rng(5);
  for (std::size_t i = 0; i < u.size(); ++i) u.data()[i] = float(rng.uniform() * 2.2 - 1.1);
  material_maps m(3, 3);
  ns::network_to_maps(u, 1, m);
  REQUIRE(m.width() == W);
  REQUIRE(m.height() == H);
  int outside = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float* p = u.pixel(1, y, x);
      const double nx = p[normal_x], ny = p[normal_y], r = std::hypot(nx, ny);
      for (int k = 0; k < parameter_count; ++k) {
        double expected = ns::from_network(k, p[k]);
        if ((k == normal_x || k == normal_y) && r > ns::max_normal_xy) expected = p[k] * ns::max_normal_xy / r;
        if (m.at(k, x, y) != float(expected)) {
          CHECK(m.at(k, x, y) == doctest::Approx(expected).epsilon(1e-6));
        }
      }
      outside += r > ns::max_normal_xy;
    }
  CHECK(outside > 1000);
  // A map set of the right size is written in place.
  const float* storage = m.plane(0);
  ns::network_to_maps(u, 0, m);
  CHECK(m.plane(0) == storage);
  CHECK(m.at(diffuse_r, 5, 7) == float(ns::from_network(diffuse_r, u(0, 7, 5, diffuse_r))));
}

TEST_CASE("network space: the chain rule matches finite differences, inside and outside the normal disc") {
  for (const int W : {3, 11}) {  // 11: a row that is no whole number of SIMD batches
    CAPTURE(W);
    const int H = 2;
    tensor<parameter_count> u(1, H, W), grad(1, H, W);
    random_generator rng(11);
    for (std::size_t i = 0; i < u.size(); ++i) u.data()[i] = float(rng.uniform() * 1.8 - 0.9);
    u(0, 0, 0, normal_x) = 0.95f;  // outside the disc: scaled back
    u(0, 0, 0, normal_y) = 0.6f;
    // L = sum_k,p c_k,p maps_k,p: dL/dmaps = c.
    material_maps c(W, H);
    for (int k = 0; k < parameter_count; ++k)
      for (int i = 0; i < W * H; ++i) c.plane(k)[i] = float(rng.uniform() * 2 - 1);
    auto loss = [&] {
      const material_maps m = ns::network_to_maps(u, 0);
      double s = 0;
      for (int k = 0; k < parameter_count; ++k)
        for (int i = 0; i < W * H; ++i) s += double(c.plane(k)[i]) * m.plane(k)[i];
      return s;
    };
    grad.fill(0.0f);
    ns::add_network_gradient(u, 0, c, 2.0, grad);  // scale 2 to check the scale argument
    for (std::size_t i = 0; i < u.size(); ++i) {
      const float saved = u.data()[i];
      const float h = 1e-3f;
      u.data()[i] = saved + h;
      const double up = loss();
      u.data()[i] = saved - h;
      const double down = loss();
      u.data()[i] = saved;
      const double numeric = 2.0 * (up - down) / (2.0 * h);
      CHECK(double(grad.data()[i]) == doctest::Approx(numeric).epsilon(2e-2).scale(1.0));
    }
  }
}

TEST_CASE("network space: the orientation channels give the direction of the strongest change, doubled") {
  // Stripes whose brightness changes along the angle phi: (c3, c4) = (cos 2 phi, sin 2 phi) away
  // from the border, near 1 in length (one direction only); a flat image: (0, 0) and contrast -1.
  for (double phi : {0.0, 0.3, std::numbers::pi / 4, 1.2, std::numbers::pi / 2, -0.7}) {
    CAPTURE(phi);
    image im(48, 40, 3);
    for (int y = 0; y < 40; ++y)
      for (int x = 0; x < 48; ++x)
        for (int c = 0; c < 3; ++c) im.at(c, x, y) = float(0.5 + 0.3 * std::sin(0.35 * (x * std::cos(phi) + y * std::sin(phi))));
    tensor<6> out(2, 40, 48);
    ns::photo_to_network(im, out, 1);
    for (auto [x, y] : {std::pair{24, 20}, std::pair{10, 30}}) {
      const float* p = out.pixel(1, y, x);
      CHECK(p[0] == doctest::Approx(ns::input_value(im.at(0, x, y))).epsilon(1e-5));
      CHECK(std::abs(p[3] - std::cos(2 * phi)) < 0.03);
      CHECK(std::abs(p[4] - std::sin(2 * phi)) < 0.03);
      CHECK(p[5] > -0.5);
    }
    for (std::size_t i = 0; i < std::size_t(40 * 48 * 6); ++i) CHECK(out.data()[i] == 0.0f);  // entry 0 untouched
  }
  image flat(16, 16, 3);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x) flat.at(c, x, y) = 0.25f;
  tensor<6> out(1, 16, 16);
  ns::photo_to_network(flat, out, 0);
  CHECK(out.pixel(0, 8, 8)[3] == 0.0f);
  CHECK(out.pixel(0, 8, 8)[4] == 0.0f);
  CHECK(out.pixel(0, 8, 8)[5] == doctest::Approx(-1.0));
}


namespace {
/// The orientation channels as their definition reads: every sum with its edge clamps.
std::array<float, 3> orientation_reference(const tensor<6>& t, int b, int x, int y) {
  const int H = t.height(), W = t.width();
  auto v = [&](int xx, int yy) {
    const float* p = t.pixel(b, std::clamp(yy, 0, H - 1), std::clamp(xx, 0, W - 1));
    return (double(p[0]) + p[1] + p[2]) / 3;
  };
  auto structure = [&](int xx, int yy) {
    const double gx = (v(xx + 1, yy) - v(xx - 1, yy)) / 2, gy = (v(xx, yy + 1) - v(xx, yy - 1)) / 2;
    return std::array<double, 3>{gx * gx, gx * gy, gy * gy};
  };
  std::array<double, 3> j{};
  for (int k = 0; k < 3; ++k) {
    double sum = 0;
    for (int dy = -3; dy <= 3; ++dy) {
      double row = 0;
      for (int dx = -3; dx <= 3; ++dx)
        row += structure(std::clamp(x + dx, 0, W - 1), std::clamp(y + dy, 0, H - 1))[std::size_t(k)];
      sum += row;
    }
    j[std::size_t(k)] = sum;
  }
  const double trace = j[0] + j[2], floor = 1e-4, log_floor = std::log(1e-4);
  return {float((j[0] - j[2]) / (trace + 1e-6)), float(2 * j[1] / (trace + 1e-6)),
          float(2 * (std::log(trace + floor) - log_floor) / -log_floor - 1)};
}
}  // namespace

TEST_CASE("network space: the orientation channels are their clamped-window definition, bit for bit, at every size") {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (const auto& size : {std::pair{1, 1}, std::pair{2, 3}, std::pair{5, 4}, std::pair{7, 7}, std::pair{8, 1}, std::pair{13, 9},
                           std::pair{37, 20}}) {
    const int W = size.first, H = size.second;
    CAPTURE(W);
    CAPTURE(H);
    image im(W, H, 3);
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) im.at(c, x, y) = u(rng) * u(rng);
    tensor<6> out(1, H, W);
    ns::photo_to_network(im, out, 0);
    int differ = 0;
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const auto expected = orientation_reference(out, 0, x, y);
        for (int c = 0; c < 3; ++c)
          if (std::memcmp(&out.pixel(0, y, x)[3 + c], &expected[std::size_t(c)], sizeof(float)) != 0) ++differ;
      }
    CHECK(differ == 0);
  }
}

TEST_CASE("network space: shift_to takes decoded values to a map set, shifted applies it, wrapping the rotation and clamping the rest") {
  const int W = 5, H = 4;
  const material_maps target = generate_material(12, W, H);
  tensor<parameter_count> u(1, H, W), expected(1, H, W);
  random_generator rng(3);
  for (std::size_t i = 0; i < u.size(); ++i) u.data()[i] = float(rng.uniform() * 1.8 - 0.9);
  ns::maps_to_network(target, expected, 0);
  const tensor<parameter_count> r = ns::shift_to(u, target);
  const tensor<parameter_count> s = ns::shifted(u, r);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      for (int k = 0; k < parameter_count; ++k) {
        if (k == rotation) {
          // The difference is wrapped into [-1, 1] (a half turn of alpha is 2 in network space)...
          CHECK(std::abs(r(0, y, x, k)) <= 1.0f + 1e-6f);
          // ...and the shifted value is the target's modulo that half turn.
          const double d = double(s(0, y, x, k)) - expected(0, y, x, k);
          CHECK(std::abs(d - 2.0 * std::nearbyint(d / 2.0)) < 1e-5);
        } else {
          CHECK(s(0, y, x, k) == doctest::Approx(expected(0, y, x, k)).epsilon(1e-5).scale(1.0));
        }
      }
  // The decoded maps of the shifted values are the target (alpha modulo pi).
  const material_maps back = ns::network_to_maps(s, 0);
  for (int k = 0; k < parameter_count; ++k)
    for (int i = 0; i < W * H; ++i)
      if (k != rotation && k != lobe_x && k != lobe_y) CHECK(back.plane(k)[i] == doctest::Approx(target.plane(k)[i]).epsilon(1e-4));
  // A value pushed past the range is clamped to it, except the rotation.
  tensor<parameter_count> big(1, 1, 1), zero(1, 1, 1);
  big.fill(0.8f);
  const tensor<parameter_count> out = ns::shifted(zero, big);
  CHECK(out(0, 0, 0, diffuse_r) == doctest::Approx(0.8f));
  const tensor<parameter_count> twice = ns::shifted(out, big);
  CHECK(twice(0, 0, 0, fresnel_f0) == 1.0f);
  CHECK(twice(0, 0, 0, rotation) == doctest::Approx(1.6f));
  tensor<parameter_count> other(1, 2, 1);
  CHECK_THROWS_AS(ns::shifted(zero, other), std::invalid_argument);
}
