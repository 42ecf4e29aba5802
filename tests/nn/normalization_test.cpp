// Gradient checks of the layers with weights (nn/linear.hpp, nn/normalization.hpp) in double
// precision at odd shapes, and the statistics they compute.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "anisocap/nn/layers.hpp"
#include "layer_check.hpp"

using namespace anisocap;
using test_nn::check_layer;
using test_nn::random_tensor;

TEST_CASE("fully connected layer") {
  nn::random_generator g(11);
  nn::linear<19, 6, double> fc("fc", 5);
  nn::uniform_init(fc.bias, 0.5, 6);
  auto x = random_tensor<19>(g, 3, 5, 7);
  check_layer([&](ad::tape& t, const ad::variable<19, double>& v) { return fc(t, v); }, x, {&fc.weight, &fc.bias});
  auto x1 = random_tensor<19>(g, 3, 1, 1);
  check_layer([&](ad::tape& t, const ad::variable<19, double>& v) { return fc(t, v); }, x1, {&fc.weight, &fc.bias});

  ad::tape t;
  auto y = fc(t, t.leaf(x1));
  for (int o = 0; o < 6; ++o) {
    double s = fc.bias.value[o];
    for (int i = 0; i < 19; ++i) s += fc.weight.value[o * 19 + i] * x1(2, 0, 0, i);
    CHECK(y.value(2, 0, 0, o) == doctest::Approx(s).epsilon(1e-13));
  }
}

TEST_CASE("instance normalisation") {
  nn::random_generator g(12);
  nn::instance_norm<5, double> norm("in");
  nn::uniform_init(norm.weight, 2.0, 1);
  nn::uniform_init(norm.bias, 1.0, 2);
  auto x = random_tensor<5>(g, 3, 5, 7, 3.0);
  check_layer([&](ad::tape& t, const ad::variable<5, double>& v) { return norm(t, v); }, x, {&norm.weight, &norm.bias});

  // With unit scale and zero shift every image's channel has mean 0 and variance 1 (up to epsilon).
  nn::instance_norm<5, double> plain("plain");
  ad::tape t;
  auto y = plain(t, t.leaf(x));
  for (int b = 0; b < 3; ++b)
    for (int c = 0; c < 5; ++c) {
      double s = 0, s2 = 0;
      for (int r = 0; r < 5; ++r)
        for (int i = 0; i < 7; ++i) { s += y.value(b, r, i, c); s2 += y.value(b, r, i, c) * y.value(b, r, i, c); }
      CHECK(std::abs(s / 35) < 1e-12);
      CHECK(s2 / 35 == doctest::Approx(1).epsilon(1e-4));
    }
}

namespace {
/// with_channel_bias against instance_norm then add_channel_bias, for C channels.
template <int C, class Act>
void check_norm_with_bias(const Act& act) {
  nn::random_generator g(31);
  nn::instance_norm<C, float> norm("in");
  nn::uniform_init(norm.weight, 2.0, 3);
  nn::uniform_init(norm.bias, 1.0, 4);
  const auto x = random_tensor<C, float>(g, 3, 5, 7, 3.0);
  const auto bias = random_tensor<C, float>(g, 3, 1, 1);
  auto copy = [](const tensor<C, float>& a) {
    tensor<C, float> c(a.batch(), a.height(), a.width());
    std::copy_n(a.data(), a.size(), c.data());
    return c;
  };
  ad::tape t1, t2;
  ad::tape::no_grad_guard g1(t1), g2(t2);
  const auto expected = nn::add_channel_bias(t1, norm(t1, t1.leaf(x)), t1.leaf(bias), act);
  // Inference: the input's tensor is overwritten with the same bits.
  auto in = t2.leaf(copy(x));
  const float* storage = in.value.data();
  const auto y = norm.with_channel_bias(t2, std::move(in), t2.leaf(bias), act);
  CHECK(y.value.data() == storage);
  CHECK(!y.requires_grad);
  CHECK(std::memcmp(y.value.data(), expected.value.data(), x.size() * sizeof(float)) == 0);

  // Recording with trainable weights: the two layers, recorded; the input is left as it was.
  ad::tape t3;
  auto kept = t3.leaf(copy(x));
  const auto z = norm.with_channel_bias(t3, ad::variable<C, float>(kept), t3.leaf(bias), act);
  CHECK(z.value.data() != kept.value.data());
  CHECK(z.requires_grad);
  CHECK(std::memcmp(kept.value.data(), x.data(), x.size() * sizeof(float)) == 0);
  CHECK(std::memcmp(z.value.data(), expected.value.data(), x.size() * sizeof(float)) == 0);

  // An input that needs a gradient is not overwritten even where nothing is recorded.
  ad::tape t4;
  auto needs = t4.leaf(copy(x), true);
  ad::tape::no_grad_guard g4(t4);
  const auto w = norm.with_channel_bias(t4, ad::variable<C, float>(needs), t4.leaf(bias), act);
  CHECK(w.value.data() != needs.value.data());
  CHECK(std::memcmp(needs.value.data(), x.data(), x.size() * sizeof(float)) == 0);
  CHECK(std::memcmp(w.value.data(), expected.value.data(), x.size() * sizeof(float)) == 0);

  // A bias of another batch is refused before anything is written.
  auto other = t2.leaf(copy(x));
  CHECK_THROWS_AS(norm.with_channel_bias(t2, std::move(other), t2.leaf(random_tensor<C, float>(g, 2, 1, 1)), act),
                  std::invalid_argument);
}
}  // namespace

TEST_CASE("instance normalisation with a channel bias: in place where no gradient flows, the same bits") {
  check_norm_with_bias<5>(nn::identity_activation{});
  check_norm_with_bias<5>(nn::leaky_relu_activation<float>{0.2f});
  check_norm_with_bias<16>(nn::leaky_relu_activation<float>{0.2f});
  check_norm_with_bias<24>(nn::identity_activation{});
}

TEST_CASE("instance normalisation with a channel bias: gradients where they flow") {
  nn::random_generator g(32);
  nn::instance_norm<5, double> norm("in");
  nn::uniform_init(norm.weight, 2.0, 5);
  nn::uniform_init(norm.bias, 1.0, 6);
  const auto x = random_tensor<5>(g, 3, 5, 7, 3.0);
  const auto bias = random_tensor<5>(g, 3, 1, 1);
  const nn::leaky_relu_activation<double> leaky{0.2};
  // The input is consumed, so it comes from a layer of its own (v + 0), as in a network; the
  // finite differences run without recording, on the in-place path.
  const tensor<5, double> zero(3, 5, 7);
  check_layer(
      [&](ad::tape& t, const ad::variable<5, double>& v) {
        return norm.with_channel_bias(t, nn::add(t, v, t.leaf(zero)), t.leaf(bias), leaky);
      },
      x, {&norm.weight, &norm.bias});
  check_layer(
      [&](ad::tape& t, const ad::variable<5, double>& v) {
        return norm.with_channel_bias(t, nn::add(t, t.leaf(x), t.leaf(zero)), v, leaky);
      },
      bias, {&norm.weight, &norm.bias});
}

TEST_CASE("batch normalisation: training and evaluation") {
  nn::random_generator g(13);
  nn::batch_norm<17, double> bn("bn");
  nn::uniform_init(bn.weight, 2.0, 1);
  nn::uniform_init(bn.bias, 1.0, 2);
  auto x = random_tensor<17>(g, 3, 5, 7, 3.0);
  x.data()[0] += 4;  // a channel with a nonzero mean
  bn.training = true;
  check_layer([&](ad::tape& t, const ad::variable<17, double>& v) { return bn(t, v); }, x, {&bn.weight, &bn.bias});

  // Running statistics after one training step from (mean 0, var 1), momentum 0.1, unbiased variance.
  nn::batch_norm<17, double> fresh("fresh");
  {
    ad::tape t;
    fresh(t, t.leaf(x));
  }
  const int n = 3 * 5 * 7;
  for (int c : {0, 16}) {
    double s = 0, s2 = 0;
    for (int b = 0; b < 3; ++b)
      for (int r = 0; r < 5; ++r)
        for (int i = 0; i < 7; ++i) s += x(b, r, i, c);
    const double mean = s / n;
    for (int b = 0; b < 3; ++b)
      for (int r = 0; r < 5; ++r)
        for (int i = 0; i < 7; ++i) s2 += (x(b, r, i, c) - mean) * (x(b, r, i, c) - mean);
    CHECK(fresh.running_mean.value[c] == doctest::Approx(0.1 * mean).epsilon(1e-12));
    CHECK(fresh.running_var.value[c] == doctest::Approx(0.9 + 0.1 * s2 / (n - 1)).epsilon(1e-12));
  }

  // Evaluation: a fixed affine map with the running statistics.
  nn::uniform_init(bn.running_mean, 1.0, 3);
  for (auto& v : bn.running_var.value) v = 0.5 + g.symmetric_uniform() * 0.25;
  bn.training = false;
  check_layer([&](ad::tape& t, const ad::variable<17, double>& v) { return bn(t, v); }, x, {&bn.weight, &bn.bias});
  ad::tape t;
  auto y = bn(t, t.leaf(x));
  const int c = 9;
  const double expected = (x(2, 4, 6, c) - bn.running_mean.value[c]) / std::sqrt(bn.running_var.value[c] + 1e-5) *
                              bn.weight.value[c] + bn.bias.value[c];
  CHECK(y.value(2, 4, 6, c) == doctest::Approx(expected).epsilon(1e-13));
}
