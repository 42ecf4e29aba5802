// Gradient checks of the stateless layers (nn/activation.hpp, combine.hpp, upsample.hpp,
// pooling.hpp) at odd shapes, in double precision, with channel counts below and above one SIMD
// register so both the vector body and the padded tail are exercised.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "anisocap/nn/layers.hpp"
#include "layer_check.hpp"

using namespace anisocap;
using test_nn::check_layer;
using test_nn::random_tensor;

TEST_CASE("activations: values and gradients") {
  nn::random_generator g(1);
  auto x = random_tensor<5>(g, 3, 5, 7, 2.0);
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::leaky_relu(t, v, 0.2); }, x, {});
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::selu(t, v); }, x, {});
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::tanh(t, v); }, x, {});
  auto x17 = random_tensor<17>(g, 2, 3, 5, 2.0);
  check_layer([](ad::tape& t, const ad::variable<17, double>& v) { return nn::selu(t, v); }, x17, {});

  // Values against the scalar definitions.
  ad::tape t;
  auto v = t.leaf(x);
  auto l = nn::leaky_relu(t, v, 0.2);
  auto s = nn::selu(t, v);
  auto h = nn::tanh(t, v);
  const double alpha = 1.6732632423543772848, scale = 1.0507009873554804934;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double xi = x.data()[i];
    CHECK(l.value.data()[i] == (xi > 0 ? xi : 0.2 * xi));
    CHECK(s.value.data()[i] == doctest::Approx(xi > 0 ? scale * xi : scale * alpha * (std::exp(xi) - 1)).epsilon(1e-14));
    CHECK(h.value.data()[i] == doctest::Approx(std::tanh(xi)).epsilon(1e-14));
  }
}

TEST_CASE("add, concat and per-channel bias broadcast") {
  nn::random_generator g(2);
  auto a = random_tensor<5>(g, 3, 5, 7);
  auto b = random_tensor<5>(g, 3, 5, 7);
  auto c = random_tensor<17>(g, 3, 5, 7);
  auto bias = random_tensor<5>(g, 3, 1, 1);
  // Gradient with respect to each input in turn (the other is a constant captured by the lambda).
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::add(t, v, t.leaf(b)); }, a, {});
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::concat(t, v, t.leaf(c)); }, a, {});
  check_layer([&](ad::tape& t, const ad::variable<17, double>& v) { return nn::concat(t, t.leaf(a), v); }, c, {});
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::add_channel_bias(t, v, t.leaf(bias)); }, a, {});
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::add_channel_bias(t, t.leaf(a), v); }, bias, {});
  // With the activation applied in the same pass: finite differences, and the separate ops' bits.
  const nn::leaky_relu_activation<double> leaky{0.2};
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::add_channel_bias(t, v, t.leaf(bias), leaky); }, a, {});
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return nn::add_channel_bias(t, t.leaf(a), v, leaky); }, bias, {});
  {
    ad::tape t1, t2;
    auto x1 = t1.leaf(a, true), b1 = t1.leaf(bias, true);
    auto x2 = t2.leaf(a, true), b2 = t2.leaf(bias, true);
    auto y1 = nn::add_channel_bias(t1, x1, b1, leaky);
    auto y2 = nn::leaky_relu(t2, nn::add_channel_bias(t2, x2, b2), 0.2);
    auto gy = random_tensor<5>(g, 3, 5, 7);
    std::copy(gy.data(), gy.data() + gy.size(), y1.grad.data());
    std::copy(gy.data(), gy.data() + gy.size(), y2.grad.data());
    t1.backward();
    t2.backward();
    for (std::size_t i = 0; i < a.size(); ++i) {
      CHECK(y1.value.data()[i] == y2.value.data()[i]);
      CHECK(x1.grad.data()[i] == x2.grad.data()[i]);
    }
    for (std::size_t i = 0; i < bias.size(); ++i) CHECK(b1.grad.data()[i] == b2.grad.data()[i]);
    CHECK_THROWS_AS(nn::add_channel_bias(t1, x1, b1, nn::leaky_relu_activation<double>{-1.0}), std::invalid_argument);
  }

  ad::tape t;
  auto y = nn::concat(t, t.leaf(a), t.leaf(c));
  auto z = nn::add_channel_bias(t, t.leaf(a), t.leaf(bias));
  CHECK(y.value(2, 4, 6, 3) == a(2, 4, 6, 3));
  CHECK(y.value(2, 4, 6, 5 + 16) == c(2, 4, 6, 16));
  CHECK(z.value(1, 3, 2, 4) == a(1, 3, 2, 4) + bias(1, 0, 0, 4));
  CHECK_THROWS_AS(nn::add(t, t.leaf(a), t.leaf(random_tensor<5>(g, 3, 5, 6))), std::invalid_argument);
}

TEST_CASE("nearest upsampling and spatial mean") {
  nn::random_generator g(3);
  auto x = random_tensor<5>(g, 3, 5, 7);
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::upsample_nearest2x(t, v); }, x, {});
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::spatial_mean(t, v); }, x, {});

  ad::tape t;
  auto u = nn::upsample_nearest2x(t, t.leaf(x));
  auto m = nn::spatial_mean(t, t.leaf(x));
  REQUIRE(u.value.height() == 10);
  REQUIRE(u.value.width() == 14);
  CHECK(u.value(2, 9, 13, 4) == x(2, 4, 6, 4));
  CHECK(u.value(1, 6, 3, 2) == x(1, 3, 1, 2));
  double sum = 0;
  for (int r = 0; r < 5; ++r)
    for (int i = 0; i < 7; ++i) sum += x(1, r, i, 3);
  CHECK(m.value(1, 0, 0, 3) == doctest::Approx(sum / 35).epsilon(1e-14));
}

TEST_CASE("max over the images of a set") {
  // Distinct values (a shuffled grid 0.01 apart), so the argmax is unique and finite differences
  // do not cross a tie.
  const int sets = 2, n = 3;
  tensor<5, double> x(sets * n, 5, 7);
  std::vector<int> order(x.size());
  std::iota(order.begin(), order.end(), 0);
  nn::random_generator g(4);
  for (std::size_t i = order.size() - 1; i > 0; --i) std::swap(order[i], order[g.next() % (i + 1)]);
  for (std::size_t i = 0; i < x.size(); ++i) x.data()[i] = (order[i] - double(x.size()) / 2) * 0.01;
  check_layer([](ad::tape& t, const ad::variable<5, double>& v) { return nn::max_over_images(t, v, 3); }, x, {});

  ad::tape t;
  auto xv = t.leaf(x, true);
  auto y = nn::max_over_images(t, xv, n);
  REQUIRE(y.value.batch() == sets);
  y.grad.fill(1.0);
  t.backward();
  for (int s = 0; s < sets; ++s)
    for (int r = 0; r < 5; ++r)
      for (int i = 0; i < 7; ++i)
        for (int c = 0; c < 5; ++c) {
          double best = -1e300;
          int arg = -1;
          for (int k = 0; k < n; ++k)
            if (x(s * n + k, r, i, c) > best) { best = x(s * n + k, r, i, c); arg = k; }
          CHECK(y.value(s, r, i, c) == best);
          for (int k = 0; k < n; ++k) CHECK(xv.grad(s * n + k, r, i, c) == (k == arg ? 1.0 : 0.0));
        }
  CHECK_THROWS_AS(nn::max_over_images(t, xv, 4), std::invalid_argument);
}

TEST_CASE("layers read strided views (tiles) as they read dense tensors") {
  nn::random_generator g(5);
  auto big = random_tensor<5>(g, 4, 9, 11);
  auto other = random_tensor<17>(g, 4, 5, 7);
  const auto view = big.tile(2, 3, 5, 7);  // rows 11 pixels apart, 7 used
  REQUIRE_FALSE(view.is_dense());
  const auto dense = view.clone();
  auto same = [](const auto& a, const auto& b) {
    for (std::size_t i = 0; i < a.size(); ++i)
      if (a.data()[i] != b.data()[i]) return false;
    return a.size() == b.size();
  };
  ad::tape t;
  CHECK(same(nn::leaky_relu(t, t.leaf(view), 0.1).value, nn::leaky_relu(t, t.leaf(dense), 0.1).value));
  CHECK(same(nn::spatial_mean(t, t.leaf(view)).value, nn::spatial_mean(t, t.leaf(dense)).value));
  CHECK(same(nn::max_over_images(t, t.leaf(view), 2).value, nn::max_over_images(t, t.leaf(dense), 2).value));
  CHECK(same(nn::upsample_nearest2x(t, t.leaf(view)).value, nn::upsample_nearest2x(t, t.leaf(dense)).value));
  CHECK(same(nn::concat(t, t.leaf(view), t.leaf(other)).value, nn::concat(t, t.leaf(dense), t.leaf(other)).value));
  nn::instance_norm<5, double> norm("in");
  CHECK(same(norm(t, t.leaf(view)).value, norm(t, t.leaf(dense)).value));
  // Gradients flow into a view's own (dense) gradient tensor.
  auto v = t.leaf(view, true);
  auto y = nn::tanh(t, v);
  y.grad.fill(1.0);
  t.backward();
  CHECK(v.grad(3, 4, 6, 2) == doctest::Approx(1 - std::pow(std::tanh(big(3, 6, 9, 2)), 2)).epsilon(1e-14));
}
