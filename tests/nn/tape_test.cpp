// The tape (ad/reverse/tape.hpp) with layers: backward order, frozen parameters, no-grad mode, and
// that recorded closures (which live in the arena) are destroyed.
#include <doctest/doctest.h>

#include <memory>
#include <vector>

#include "anisocap/nn/layers.hpp"
#include "layer_check.hpp"

using namespace anisocap;

namespace {
bool all_zero(const nn::basic_parameter<float>& p) {
  for (float g : p.grad) if (g != 0) return false;
  return true;
}
}  // namespace

TEST_CASE("tape: backward runs the recorded steps in reverse order, once") {
  ad::tape t;
  std::vector<int> order;
  order.reserve(8);
  for (int i = 0; i < 4; ++i) t.record([&order, i] { order.push_back(i); });
  CHECK(t.size() == 4);
  t.backward();
  CHECK(order == std::vector<int>{3, 2, 1, 0});
  CHECK(t.size() == 0);
  t.backward();
  CHECK(order.size() == 4);
}

TEST_CASE("tape: closures are destroyed by backward and by clear") {
  auto token = std::make_shared<int>(1);
  ad::tape t;
  t.record([token] {});
  t.record([token] {});
  CHECK(token.use_count() == 3);
  t.backward();
  CHECK(token.use_count() == 1);
  t.record([token] {});
  CHECK(token.use_count() == 2);
  t.clear();
  CHECK(token.use_count() == 1);
  {
    ad::tape u;
    u.record([token] {});
    CHECK(token.use_count() == 2);
  }
  CHECK(token.use_count() == 1);
}

TEST_CASE("tape: frozen layers get no gradient, nothing is computed below the lowest trainable layer") {
  nn::random_generator g(21);
  auto x = test_nn::random_tensor<6, float>(g, 3, 5, 7);
  nn::linear<6, 8> fc1("fc1", 1);
  nn::linear<8, 8> fc2("fc2", 2);
  nn::linear<8, 4> fc3("fc3", 3);
  auto run = [&](ad::tape& t) {
    auto h = nn::leaky_relu(t, fc1(t, t.leaf(x)), 0.2f);
    auto y = fc3(t, nn::tanh(t, fc2(t, h)));
    if (y.requires_grad) {
      y.grad.fill(1.0f);
      t.backward();
    }
    return std::make_pair(h, y);
  };

  SUBCASE("lowest layer frozen: it records nothing and gets no gradient") {
    fc1.weight.frozen = fc1.bias.frozen = true;
    ad::tape t;
    auto x_leaf = t.leaf(x);
    auto h1 = fc1(t, x_leaf);
    CHECK_FALSE(h1.requires_grad);
    CHECK(h1.grad.data() == nullptr);
    CHECK(t.size() == 0);
    auto h = nn::leaky_relu(t, h1, 0.2f);
    CHECK(t.size() == 0);  // no input needs a gradient: the activation records nothing either
    auto y = fc3(t, nn::tanh(t, fc2(t, h)));
    CHECK(t.size() == 3);  // fc2, tanh, fc3
    y.grad.fill(1.0f);
    t.backward();
    CHECK(all_zero(fc1.weight));
    CHECK(all_zero(fc1.bias));
    CHECK_FALSE(all_zero(fc2.weight));
    CHECK_FALSE(all_zero(fc3.weight));
  }
  SUBCASE("middle layer frozen: the gradient passes through it to the layer below") {
    fc2.weight.frozen = fc2.bias.frozen = true;
    ad::tape t;
    auto [h, y] = run(t);
    CHECK(all_zero(fc2.weight));
    CHECK(all_zero(fc2.bias));
    CHECK_FALSE(all_zero(fc1.weight));
    CHECK_FALSE(all_zero(fc3.bias));
  }
  SUBCASE("everything frozen: nothing is recorded") {
    for (auto* p : {&fc1.weight, &fc1.bias, &fc2.weight, &fc2.bias, &fc3.weight, &fc3.bias}) p->frozen = true;
    ad::tape t;
    auto [h, y] = run(t);
    CHECK_FALSE(y.requires_grad);
    CHECK(t.size() == 0);
  }
}

TEST_CASE("tape: no-grad mode records nothing and allocates no gradients") {
  nn::random_generator g(22);
  auto x = test_nn::random_tensor<6, float>(g, 2, 4, 4);
  nn::linear<6, 4> fc("fc", 1);
  nn::batch_norm<4> bn("bn");
  ad::tape t;
  {
    ad::tape::no_grad_guard guard(t);
    CHECK_FALSE(t.recording());
    auto y = nn::selu(t, bn(t, fc(t, t.leaf(x, true))));
    CHECK_FALSE(y.requires_grad);
    CHECK(y.grad.data() == nullptr);
    CHECK(t.size() == 0);
  }
  CHECK(t.recording());
  auto y = nn::selu(t, bn(t, fc(t, t.leaf(x, true))));
  CHECK(y.requires_grad);
  CHECK(t.size() == 3);
}

TEST_CASE("tape: a composed network's gradients match finite differences (shared inputs accumulate)") {
  // Every intermediate feeds two operations (concat(h, h), add(u, u), the global track), so the
  // check fails unless gradients accumulate.
  nn::random_generator g(23);
  nn::linear<3, 6, double> fc1("fc1", 1);
  nn::instance_norm<6, double> norm("norm");
  nn::linear<6, 6, double> global("global", 2);
  nn::linear<12, 2, double> fc2("fc2", 3);
  nn::uniform_init(norm.bias, 0.5, 4);
  auto net = [&](ad::tape& t, const ad::variable<3, double>& x) {
    auto h = nn::leaky_relu(t, norm(t, fc1(t, x)), 0.2);
    h = nn::add_channel_bias(t, h, global(t, nn::spatial_mean(t, h)));
    auto u = nn::upsample_nearest2x(t, nn::max_over_images(t, nn::concat(t, h, nn::selu(t, h)), 2));
    return nn::tanh(t, fc2(t, nn::add(t, u, u)));
  };
  auto x = test_nn::random_tensor<3>(g, 4, 3, 5);
  test_nn::check_layer(net, x, {&fc1.weight, &norm.weight, &norm.bias, &global.weight, &fc2.bias});
}

TEST_CASE("retained_tape: one tape across calls, cleared each time, its memory kept; a copy starts without one") {
  ad::retained_tape kept;
  CHECK(kept.capacity_bytes() == 0);
  ad::tape& first = kept.fresh();
  (void)first.make_tensor<4>(1, 32, 32);
  first.record([] {});
  const std::size_t capacity = kept.capacity_bytes();
  CHECK(capacity > 0);
  ad::tape& second = kept.fresh();
  CHECK(&second == &first);
  CHECK(second.size() == 0);                     // nothing recorded survives
  CHECK(second.memory().high_water_bytes() > 0);  // the arena was used before
  CHECK(kept.capacity_bytes() == capacity);
  ad::retained_tape copy = kept;
  CHECK(copy.capacity_bytes() == 0);
  CHECK(&copy.fresh() != &first);
  kept.release();
  CHECK(kept.capacity_bytes() == 0);
}
