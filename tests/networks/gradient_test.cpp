// End-to-end gradient checks of both networks in double (tiny presets): the tape's gradients of a
// few weights of every kind of layer against central differences.
#include <doctest/doctest.h>

#include <vector>

#include "anisocap/core/random.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "support/gradient_check.hpp"
#include "tiny_presets.hpp"

using namespace anisocap;

namespace {
/// Checks the first `count` entries of parameter p: analytic gradient (already in p.grad) against
/// central differences of loss().
void check_parameter(nn::basic_parameter<double>& p, const std::function<double()>& loss, std::size_t count) {
  INFO("parameter " << p.name);
  const std::size_t n = std::min(count, p.size());
  std::vector<double> analytic(p.grad.data(), p.grad.data() + n);
  const auto r = anisocap::testing::check_gradient<double>(loss, p.value.data(), n, analytic.data(), 1e-6);
  CHECK(r.max_rel_error < 1e-5);
}
}  // namespace

TEST_CASE("estimator gradient: end to end in double against central differences") {
  estimation_network<anisocap::testing::estimator_tiny, double> net(7);
  ad::tape t;
  random_generator rng(21);
  tensor<3, double> input(4, 64, 64);
  for (std::size_t i = 0; i < input.size(); ++i) input.data()[i] = rng.uniform() * 2 - 1;
  tensor<parameter_count, double> weights(2, 64, 64);
  for (std::size_t i = 0; i < weights.size(); ++i) weights.data()[i] = rng.uniform() * 2 - 1;
  auto loss = [&] {
    ad::tape u;
    ad::tape::no_grad_guard guard(u);
    auto y = net.forward(u, u.leaf(input), 2);
    double s = 0;
    for (std::size_t i = 0; i < y.value.size(); ++i) s += y.value.data()[i] * weights.data()[i];
    return s;
  };
  auto y = net.forward(t, t.leaf(input), 2);
  std::copy_n(weights.data(), weights.size(), y.grad.data());
  t.backward();
  check_parameter(net.enc0.weight, loss, 3);
  check_parameter(net.enc3.weight, loss, 3);
  check_parameter(net.norm2.weight, loss, 2);
  check_parameter(net.global2.weight, loss, 3);
  check_parameter(net.bias4.weight, loss, 2);
  check_parameter(net.track1.up2.weight, loss, 3);
  check_parameter(net.track2.up5.weight, loss, 3);
  check_parameter(net.track2.g1.weight, loss, 2);
  check_parameter(net.head1.c0.weight, loss, 3);
  check_parameter(net.head2.c2.bias, loss, 3);
  check_parameter(net.head1.global.weight, loss, 2);
}

TEST_CASE("auto-encoder gradient: end to end in double, and a frozen encoder gets no gradient") {
  auto_encoder<anisocap::testing::autoencoder_tiny, double> net(8);
  random_generator rng(22);
  tensor<parameter_count, double> input(2, 64, 32);
  for (std::size_t i = 0; i < input.size(); ++i) input.data()[i] = rng.uniform() * 2 - 1;
  tensor<parameter_count, double> weights(2, 64, 32);
  for (std::size_t i = 0; i < weights.size(); ++i) weights.data()[i] = rng.uniform() * 2 - 1;
  // Batch statistics change the running statistics on every forward; the check uses running ones.
  net.set_training(false);
  auto loss = [&] {
    ad::tape u;
    ad::tape::no_grad_guard guard(u);
    auto y = net.decode(u, net.encode(u, u.leaf(input)));
    double s = 0;
    for (std::size_t i = 0; i < y.value.size(); ++i) s += y.value.data()[i] * weights.data()[i];
    return s;
  };
  {
    ad::tape t;
    auto y = net.decode(t, net.encode(t, t.leaf(input)));
    std::copy_n(weights.data(), weights.size(), y.grad.data());
    t.backward();
  }
  check_parameter(net.enc0.weight, loss, 3);
  check_parameter(net.enc4.weight, loss, 3);
  check_parameter(net.latent_norm.bias, loss, 3);
  check_parameter(net.dec0.weight, loss, 3);
  check_parameter(net.dec4.bias, loss, 3);
  net.for_each_parameter([](auto& p) { p.zero_grad(); });
  net.freeze_encoder();
  {
    ad::tape t;
    auto z = net.encode(t, t.leaf(input));
    CHECK_FALSE(z.requires_grad);
    auto y = net.decode(t, z);
    std::copy_n(weights.data(), weights.size(), y.grad.data());
    t.backward();
  }
  bool encoder_zero = true, decoder_nonzero = false;
  for (double g : net.enc2.weight.grad) encoder_zero &= g == 0;
  for (double g : net.dec1.weight.grad) decoder_nonzero |= g != 0;
  CHECK(encoder_zero);
  CHECK(decoder_nonzero);
}
