// The conv2d / conv_transpose2d layers on the tape: recorded gradients equal the functions',
// frozen parameters get no gradient, inputs that need none get none, no-grad mode records nothing.
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <random>
#include <vector>

#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/precision.hpp"
#include "reference.hpp"

using namespace anisocap;
using anisocap::testing::fill_random;

namespace {

template <class Layer>
void randomise(Layer& layer, std::mt19937& rng) {
  layer.for_each_parameter([&](nn::parameter& p) { fill_random(p.value.data(), p.size(), rng); });
}

bool all_zero(const nn::parameter& p) {
  for (float g : p.grad)
    if (g != 0.0f) return false;
  return true;
}

}  // namespace

TEST_CASE("conv2d layer records its backward and honours frozen parameters") {
  std::mt19937 rng(41);
  nn::conv2d<3, 5, 4, 2, 1> layer("enc0");
  CHECK(layer.weight.name == "enc0.weight");
  CHECK(layer.bias.name == "enc0.bias");
  CHECK(layer.weight.shape == std::vector<int>{4, 4, 3, 5});
  randomise(layer, rng);
  tensor<3> input(2, 7, 9);
  fill_random(input, rng);

  SUBCASE("everything trainable: gradients equal the backward functions'") {
    ad::tape t;
    auto x = t.leaf(input, true);
    auto y = layer(t, x);
    REQUIRE(y.requires_grad);
    CHECK(y.value.height() == 3);
    CHECK(y.value.width() == 4);
    fill_random(y.grad, rng);
    t.backward();
    tensor<3> gin(2, 7, 9);
    nn::conv2d_backward_input<3, 5, 4, 2, 1>(y.grad, layer.weight.value.data(), gin);
    std::vector<float> gw(layer.weight.size(), 0.0f), gb(5, 0.0f);
    nn::conv2d_backward_weight<3, 5, 4, 2, 1>(input, y.grad, gw.data(), gb.data());
    for (std::size_t i = 0; i < gin.size(); ++i) CHECK(x.grad.data()[i] == gin.data()[i]);
    for (std::size_t i = 0; i < gw.size(); ++i) CHECK(layer.weight.grad[i] == gw[i]);
    for (int i = 0; i < 5; ++i) CHECK(layer.bias.grad[i] == gb[i]);
  }

  SUBCASE("frozen weight, input without gradient: only the bias gradient") {
    layer.weight.frozen = true;
    ad::tape t;
    auto x = t.leaf(input, false);
    auto y = layer(t, x);
    REQUIRE(y.requires_grad);  // the bias still trains
    fill_random(y.grad, rng);
    t.backward();
    CHECK(x.grad.empty());
    CHECK(all_zero(layer.weight));
    CHECK_FALSE(all_zero(layer.bias));
  }

  SUBCASE("all frozen and input without gradient: nothing recorded") {
    layer.weight.frozen = true;
    layer.bias.frozen = true;
    ad::tape t;
    auto x = t.leaf(input, false);
    auto y = layer(t, x);
    CHECK_FALSE(y.requires_grad);
    CHECK(t.size() == 0);
  }

  SUBCASE("all frozen, input needs a gradient: input gradient only") {
    layer.weight.frozen = true;
    layer.bias.frozen = true;
    ad::tape t;
    auto x = t.leaf(input, true);
    auto y = layer(t, x);
    REQUIRE(y.requires_grad);
    fill_random(y.grad, rng);
    t.backward();
    double s = 0;
    for (std::size_t i = 0; i < x.grad.size(); ++i) s += std::abs(x.grad.data()[i]);
    CHECK(s > 0);
    CHECK(all_zero(layer.weight));
    CHECK(all_zero(layer.bias));
  }

  SUBCASE("no-grad mode records nothing") {
    ad::tape t;
    ad::tape::no_grad_guard guard(t);
    auto x = t.leaf(input, true);
    auto y = layer(t, x);
    CHECK_FALSE(y.requires_grad);
    CHECK(t.size() == 0);
  }
}

TEST_CASE("conv_transpose2d layer records its backward and honours frozen parameters") {
  std::mt19937 rng(42);
  nn::conv_transpose2d<3, 5> layer("dec0", false);
  CHECK_FALSE(layer.has_bias());
  int count = 0;
  layer.for_each_parameter([&](nn::parameter&) { ++count; });
  CHECK(count == 1);
  randomise(layer, rng);
  tensor<3> input(2, 3, 5);
  fill_random(input, rng);
  {
    ad::tape t;
    auto x = t.leaf(input, true);
    auto y = layer(t, x);
    CHECK(y.value.height() == 6);
    CHECK(y.value.width() == 10);
    fill_random(y.grad, rng);
    t.backward();
    tensor<3> gin(2, 3, 5);
    nn::conv_transpose2d_backward_input<3, 5>(y.grad, layer.weight.value.data(), gin);
    std::vector<float> gw(layer.weight.size(), 0.0f);
    nn::conv_transpose2d_backward_weight<3, 5>(input, y.grad, gw.data(), static_cast<float*>(nullptr));
    for (std::size_t i = 0; i < gin.size(); ++i) CHECK(x.grad.data()[i] == gin.data()[i]);
    for (std::size_t i = 0; i < gw.size(); ++i) CHECK(layer.weight.grad[i] == gw[i]);
  }
  {
    layer.weight.zero_grad();
    layer.weight.frozen = true;
    ad::tape t;
    auto x = t.leaf(input, true);
    auto y = layer(t, x);
    fill_random(y.grad, rng);
    t.backward();
    CHECK(all_zero(layer.weight));
  }
}

namespace {

// A layer called with an activation (applied in place, its gradient written into a tensor of its
// own) against the activation recorded after the layer: the same output and the same gradients
// for the input, the weights and the bias, bit for bit.
template <int Cin, class Layer, class Act, class Separate>
void check_in_place_activation(Layer& layer, const tensor<Cin>& input, const Act& act, Separate separate, std::mt19937& rng,
                               bool input_needs_grad = true) {
  ad::tape t1, t2;
  auto x1 = t1.leaf(input, input_needs_grad);
  auto y1 = layer(t1, x1, act);
  auto x2 = t2.leaf(input, input_needs_grad);
  auto y2 = separate(t2, layer(t2, x2));
  REQUIRE(y1.value.size() == y2.value.size());
  int negative = 0;
  for (std::size_t i = 0; i < y1.value.size(); ++i) {
    CHECK(y1.value.data()[i] == y2.value.data()[i]);
    negative += y1.value.data()[i] < 0.0f;
  }
  CHECK(negative > 0);  // both sides of the activation are exercised
  fill_random(y1.grad, rng);
  std::copy(y1.grad.data(), y1.grad.data() + y1.grad.size(), y2.grad.data());
  std::vector<float> gw, gb;
  layer.for_each_parameter([&](nn::parameter& p) { p.zero_grad(); });
  t1.backward();
  layer.for_each_parameter([&](nn::parameter& p) {
    (gw.empty() ? gw : gb).assign(p.grad.begin(), p.grad.end());
    p.zero_grad();
  });
  t2.backward();
  std::size_t k = 0;
  layer.for_each_parameter([&](nn::parameter& p) {
    const std::vector<float>& expected = k++ == 0 ? gw : gb;
    REQUIRE(expected.size() == p.size());
    for (std::size_t i = 0; i < expected.size(); ++i) CHECK(p.grad[i] == expected[i]);
  });
  for (std::size_t i = 0; i < x1.grad.size(); ++i) CHECK(x1.grad.data()[i] == x2.grad.data()[i]);
}

}  // namespace

TEST_CASE("a layer's activation applied in place gives the values and gradients of the separate activation") {
  std::mt19937 rng(43);
  const float slope = 0.2f;
  auto leaky = [&](ad::tape& t, const auto& y) { return nn::leaky_relu(t, y, slope); };
  auto tanh = [](ad::tape& t, const auto& y) { return nn::tanh(t, y); };
  nn::conv2d<3, 20, 4, 2, 1> conv("enc0");
  randomise(conv, rng);
  tensor<3> input(2, 9, 11);
  fill_random(input, rng);
  SUBCASE("conv2d, leaky ReLU") { check_in_place_activation(conv, input, nn::leaky_relu_activation<float>{slope}, leaky, rng); }
  SUBCASE("conv2d, tanh") { check_in_place_activation(conv, input, nn::tanh_activation<float>{}, tanh, rng); }
  nn::conv_transpose2d<20, 12> up("dec0");
  randomise(up, rng);
  tensor<20> small(2, 5, 6);
  fill_random(small, rng);
  SUBCASE("conv_transpose2d, leaky ReLU") { check_in_place_activation(up, small, nn::leaky_relu_activation<float>{slope}, leaky, rng); }
  SUBCASE("conv_transpose2d, tanh") { check_in_place_activation(up, small, nn::tanh_activation<float>{}, tanh, rng); }
  // Shapes whose backward passes read one padded copy of the output gradient: the activation's
  // gradient is written straight into it (conv_transpose2d_backward_activated).
  nn::conv_transpose2d<20, 16> up16("dec1");
  nn::conv_transpose2d<16, 12> up12("dec2");  // the weight pass exchanges the operands' roles
  randomise(up16, rng);
  randomise(up12, rng);
  tensor<16> small16(2, 6, 5);
  fill_random(small16, rng);
  for (bool input_grad : {true, false}) {
    CAPTURE(input_grad);
    SUBCASE("conv_transpose2d 20 -> 16, leaky ReLU") {
      check_in_place_activation(up16, small, nn::leaky_relu_activation<float>{slope}, leaky, rng, input_grad);
    }
    SUBCASE("conv_transpose2d 16 -> 12, tanh") { check_in_place_activation(up12, small16, nn::tanh_activation<float>{}, tanh, rng, input_grad); }
    SUBCASE("conv_transpose2d 16 -> 12, leaky ReLU, bf16") {
      if (nn::bf16_available()) {
        nn::precision_scope bf16(nn::precision::bf16);
        check_in_place_activation(up12, small16, nn::leaky_relu_activation<float>{slope}, leaky, rng, input_grad);
      }
    }
  }
  SUBCASE("a negative slope is refused: the output's sign would not give the derivative") {
    ad::tape t;
    auto x = t.leaf(small, true);
    CHECK_THROWS_WITH_AS(up(t, x, nn::leaky_relu_activation<float>{-0.1f}), doctest::Contains("slope >= 0"), std::invalid_argument);
  }
}

TEST_CASE("a layer zeroes its output's gradient itself, on memory the tape used before") {
  // The layers make their output with gradient_init::by_caller and zero its gradient in the pass
  // that applies the activation: a reused arena's old values must not leak into it.
  std::mt19937 rng(47);
  nn::conv2d<3, 20, 4, 2, 1> conv("enc0");
  nn::conv_transpose2d<20, 12> up("dec0");
  randomise(conv, rng);
  randomise(up, rng);
  tensor<3> input(1, 130, 66);  // outputs of 65 x 33 and 130 x 66 pixels: large enough for the threads
  fill_random(input, rng);
  auto check = [&](const auto& act) {
    ad::tape t;
    for (int step = 0; step < 2; ++step) {
      t.clear();  // the second step reuses the first one's memory
      auto x = t.leaf(input, true);
      auto h = conv(t, x, act);
      auto y = up(t, h, act);
      REQUIRE(h.requires_grad);
      REQUIRE(y.requires_grad);
      CHECK(std::all_of(h.grad.data(), h.grad.data() + h.grad.size(), [](float v) { return v == 0.0f; }));
      CHECK(std::all_of(y.grad.data(), y.grad.data() + y.grad.size(), [](float v) { return v == 0.0f; }));
      // Dirty every tensor of the step for the next one.
      for (auto* g : {h.grad.data(), h.value.data()}) std::fill_n(g, h.grad.size(), 7.0f);
      for (auto* g : {y.grad.data(), y.value.data()}) std::fill_n(g, y.grad.size(), -3.0f);
    }
  };
  SUBCASE("no activation") { check(nn::identity_activation{}); }
  SUBCASE("leaky ReLU") { check(nn::leaky_relu_activation<float>{0.2f}); }
  SUBCASE("tanh") { check(nn::tanh_activation<float>{}); }
}

TEST_CASE("conv_transpose2d layers linked as a chain: the values and gradients of unlinked layers, on reused memory") {
  // With chain_link the gradient between two layers is never zeroed: the later layer's backward
  // writes it. The same bits as the unlinked layers, also when the tape's memory holds an
  // earlier step's values, in both precisions and through both of the input gradient's weight
  // paths (transposed in cache or copied).
  std::mt19937 rng(53);
  nn::conv_transpose2d<20, 16> l0("dec0");
  nn::conv_transpose2d<16, 12> l1("dec1");
  nn::conv_transpose2d<12, 5> l2("dec2");
  randomise(l0, rng);
  randomise(l1, rng);
  randomise(l2, rng);
  tensor<20> input(2, 9, 7);
  fill_random(input, rng);
  tensor<5> seed(2, 72, 56);
  fill_random(seed, rng);
  const nn::leaky_relu_activation<float> leaky{0.2f};
  struct result {
    std::vector<float> y, gx, grads;
  };
  auto run = [&](ad::tape& t, bool linked) {
    auto x = t.leaf(input, true);
    auto h0 = l0(t, x, leaky, nn::chain_link{false, linked});
    auto h1 = l1(t, h0, leaky, nn::chain_link{linked, linked});
    auto y = l2(t, h1, nn::tanh_activation<float>{}, nn::chain_link{linked, false});
    std::copy(seed.data(), seed.data() + seed.size(), y.grad.data());
    l0.for_each_parameter([](nn::parameter& p) { p.zero_grad(); });
    l1.for_each_parameter([](nn::parameter& p) { p.zero_grad(); });
    l2.for_each_parameter([](nn::parameter& p) { p.zero_grad(); });
    t.backward();
    result r{{y.value.data(), y.value.data() + y.value.size()}, {x.grad.data(), x.grad.data() + x.grad.size()}, {}};
    auto keep = [&](nn::parameter& p) { r.grads.insert(r.grads.end(), p.grad.begin(), p.grad.end()); };
    l0.for_each_parameter(keep);
    l1.for_each_parameter(keep);
    l2.for_each_parameter(keep);
    // Dirty the step's memory for the next step on this tape.
    for (auto* v : {&h0.value, &h0.grad}) std::fill_n(v->data(), v->size(), 5.0f);
    for (auto* v : {&h1.value, &h1.grad}) std::fill_n(v->data(), v->size(), -9.0f);
    return r;
  };
  auto check = [&] {
    ad::tape plain;
    const result expected = run(plain, false);
    ad::tape t;
    for (int step = 0; step < 2; ++step) {
      t.clear();
      const result got = run(t, true);
      REQUIRE(got.y.size() == expected.y.size());
      REQUIRE(got.gx.size() == expected.gx.size());
      REQUIRE(got.grads.size() == expected.grads.size());
      CHECK(got.y == expected.y);
      CHECK(got.gx == expected.gx);
      CHECK(got.grads == expected.grads);
    }
  };
  const std::size_t before = nn::detail::conv::in_cache_transpose_weights_per_pixel;
  for (std::size_t threshold : {std::size_t(0), SIZE_MAX}) {
    nn::detail::conv::in_cache_transpose_weights_per_pixel = threshold;
    check();
    if (nn::bf16_available()) {
      nn::precision_scope bf16(nn::precision::bf16);
      check();
    }
  }
  nn::detail::conv::in_cache_transpose_weights_per_pixel = before;
}

TEST_CASE("conv_transpose2d of a concatenation: the values of the formed concatenation, formed only where a gradient flows") {
  std::mt19937 rng(44);
  // 12 + 20 channels: the second input starts inside a register; odd sizes for the padded edges.
  nn::conv_transpose2d<32, 16> up("dec1");
  randomise(up, rng);
  tensor<12> a(3, 5, 7);
  tensor<20> b(3, 5, 7);
  fill_random(a, rng);
  fill_random(b, rng);
  const nn::leaky_relu_activation<float> leaky{0.2f};
  auto same_bits = [](const tensor<16>& x, const tensor<16>& y) {
    return x.size() == y.size() && std::memcmp(x.data(), y.data(), x.size() * sizeof(float)) == 0;
  };
  ad::tape reference;
  const auto expected = up(reference, nn::concat(reference, reference.leaf(a), reference.leaf(b)), leaky);

  SUBCASE("inference: no concatenation on the tape") {
    for (const auto precision : {nn::precision::fp32, nn::precision::bf16}) {
      if (precision == nn::precision::bf16 && !nn::bf16_available()) continue;
      const nn::precision_scope scope(precision);
      ad::tape t1, t2;
      const ad::tape::no_grad_guard g1(t1), g2(t2);
      const auto formed = up(t1, nn::concat(t1, t1.leaf(a), t1.leaf(b)), leaky);
      const auto fused = up.of_concat(t2, t2.leaf(a), t2.leaf(b), leaky);
      CHECK(same_bits(fused.value, formed.value));
      CHECK(!fused.requires_grad);
      // Only the output (and its layer's scratch) went on the tape: less than the concatenation would take.
      CHECK(t2.memory().high_water_bytes() < t1.memory().high_water_bytes());
    }
  }
  SUBCASE("recording: the recorded layers, the same gradients") {
    ad::tape t1, t2;
    const auto xb1 = t1.leaf(b, true), xb2 = t2.leaf(b, true);
    auto formed = up(t1, nn::concat(t1, t1.leaf(a), xb1), leaky);
    auto fused = up.of_concat(t2, t2.leaf(a), xb2, leaky);
    REQUIRE(fused.requires_grad);
    CHECK(same_bits(fused.value, expected.value));
    tensor<16> w(3, 10, 14);
    fill_random(w, rng);
    formed.grad.copy_from(w);
    fused.grad.copy_from(w);
    t1.backward();
    const std::vector<float> weight_grad(up.weight.grad.begin(), up.weight.grad.end());
    up.weight.zero_grad();
    up.bias.zero_grad();
    t2.backward();
    CHECK(std::memcmp(xb1.grad.data(), xb2.grad.data(), b.size() * sizeof(float)) == 0);
    CHECK(std::equal(weight_grad.begin(), weight_grad.end(), up.weight.grad.begin()));
    CHECK(!all_zero(up.weight));
  }
  SUBCASE("inputs of different shapes are refused") {
    ad::tape t;
    const ad::tape::no_grad_guard g(t);
    tensor<20> other(3, 5, 6);
    CHECK_THROWS_AS(up.of_concat(t, t.leaf(a), t.leaf(other)), std::invalid_argument);
  }
}
