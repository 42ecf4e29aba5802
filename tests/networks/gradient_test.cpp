// End-to-end gradient checks of both networks in double (tiny presets): the tape's gradients of a
// few weights of every kind of layer against central differences.
#include <doctest/doctest.h>

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "anisocap/core/random.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/nn/safetensors.hpp"
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

/// Runs the estimator forward on `images` random 64 x 64 images (sets of `per_set`) and backward
/// from the loss sum(w * y) with random w (seeded), leaving the gradients in the parameters, and
/// returns that loss as a function of the current weights for central differences.
template <class Net>
std::function<double()> backward_of_weighted_output(Net& net, int images, int per_set, std::uint64_t seed) {
  random_generator rng(seed);
  auto input = std::make_shared<tensor<3, double>>(images, 64, 64);
  for (std::size_t i = 0; i < input->size(); ++i) input->data()[i] = rng.uniform() * 2 - 1;
  auto weights = std::make_shared<tensor<parameter_count, double>>(images / per_set, 64, 64);
  for (std::size_t i = 0; i < weights->size(); ++i) weights->data()[i] = rng.uniform() * 2 - 1;
  ad::tape t;
  auto y = net.forward(t, t.leaf(*input), per_set);
  std::copy_n(weights->data(), weights->size(), y.grad.data());
  t.backward();
  return [&net, input, weights, per_set] {
    ad::tape u;
    ad::tape::no_grad_guard guard(u);
    auto z = net.forward(u, u.leaf(*input), per_set);
    double s = 0;
    for (std::size_t i = 0; i < z.value.size(); ++i) s += z.value.data()[i] * weights->data()[i];
    return s;
  };
}
}  // namespace

TEST_CASE("estimator gradient: end to end in double against central differences") {
  estimation_network<anisocap::testing::estimator_tiny, double> net(7);
  const auto loss = backward_of_weighted_output(net, 4, 2, 21);
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

TEST_CASE("estimator gradient: the doubled-angle head end to end in double against central differences") {
  estimation_network<anisocap::testing::estimator_tiny_doubled_angle, double> net(8);
  REQUIRE(net.head2.c2.bias.size() == 4);
  // Bring (c, s) away from (1, 0) so that the angle's gradient is not trivially small.
  net.head2.c2.bias.value[2] = 0.3;
  net.head2.c2.bias.value[3] = -0.4;
  const auto loss = backward_of_weighted_output(net, 3, 3, 22);
  check_parameter(net.head2.c2.bias, loss, 4);
  check_parameter(net.head2.c2.weight, loss, 8);
  check_parameter(net.head2.c1.weight, loss, 3);
  check_parameter(net.track2.up5.weight, loss, 3);
}

TEST_CASE("doubled angle: alpha / (pi/2) = atan2(s, c) / pi, continuous across alpha = +-pi/2, gradient against central differences") {
  ad::tape t;
  auto x = t.make_variable<4, double>(1, 1, 5, true);
  const double raw[5][4] = {{0.2, -0.5, 1, 0}, {0, 0, 0, 1}, {-1, 2, -1, 1e-6}, {3, 1, -1, -1e-6}, {-0.7, 0.1, -0.4, 0.9}};
  for (int i = 0; i < 5; ++i) std::copy_n(raw[i], 4, x.value.pixel(0, 0, i));
  auto y = network_detail::normals_and_doubled_angle(t, x);
  const double pi = 3.14159265358979323846;
  CHECK(y.value.pixel(0, 0, 0)[0] == doctest::Approx(std::tanh(0.2)));
  CHECK(y.value.pixel(0, 0, 0)[2] == doctest::Approx(0.0));        // (1, 0): alpha 0
  CHECK(y.value.pixel(0, 0, 1)[2] == doctest::Approx(0.5));        // (0, 1): 2 alpha = pi/2
  CHECK(y.value.pixel(0, 0, 2)[2] == doctest::Approx(1).epsilon(1e-5));   // (-1, +0): alpha -> +pi/2
  CHECK(y.value.pixel(0, 0, 3)[2] == doctest::Approx(-1).epsilon(1e-5));  // (-1, -0): alpha -> -pi/2, the same lobe
  // Neighbouring raw outputs give alphas that differ by pi: the same rotation modulo pi.
  const double a2 = y.value.pixel(0, 0, 2)[2] * pi / 2, a3 = y.value.pixel(0, 0, 3)[2] * pi / 2;
  CHECK(std::abs(std::remainder(a2 - a3, pi)) < 1e-5);
  CHECK(y.value.pixel(0, 0, 4)[2] == doctest::Approx(std::atan2(0.9, -0.4) / pi));
  random_generator rng(5);
  std::vector<double> w(y.value.size());
  for (auto& v : w) v = rng.uniform() * 2 - 1;
  std::copy(w.begin(), w.end(), y.grad.data());
  t.backward();
  // Pixels 0, 1 and 4 (away from the cut at c < 0, s = 0, where atan2 jumps by 2 pi).
  for (int i : {0, 1, 4}) {
    for (int k = 0; k < 4; ++k) {
      double* v = x.value.pixel(0, 0, i) + k;
      const double h = 1e-6, keep = *v;
      auto f = [&] {
        ad::tape u;
        ad::tape::no_grad_guard guard(u);
        auto z = network_detail::normals_and_doubled_angle(u, u.leaf(x.value));
        double s = 0;
        for (std::size_t j = 0; j < z.value.size(); ++j) s += z.value.data()[j] * w[j];
        return s;
      };
      *v = keep + h;
      const double up = f();
      *v = keep - h;
      const double down = f();
      *v = keep;
      INFO("pixel " << i << " channel " << k);
      CHECK(x.grad.pixel(0, 0, i)[k] == doctest::Approx((up - down) / (2 * h)).epsilon(1e-6));
    }
  }
}

TEST_CASE_TEMPLATE("auto-encoder gradient: end to end in double, and a frozen encoder gets no gradient", P,
                   anisocap::testing::autoencoder_tiny, anisocap::testing::autoencoder_tiny_four_levels) {
  using net_type = auto_encoder<P, double>;
  constexpr std::size_t last = net_type::levels - 1;
  net_type net(8);
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
    auto z = net.encode(t, t.leaf(input));
    CHECK(z.value.height() == 64 / net_type::size_multiple);
    CHECK(z.value.width() == 32 / net_type::size_multiple);
    auto y = net.decode(t, z);
    REQUIRE(y.value.height() == 64);
    REQUIRE(y.value.width() == 32);
    std::copy_n(weights.data(), weights.size(), y.grad.data());
    t.backward();
  }
  check_parameter(net.template enc<0>().weight, loss, 3);
  check_parameter(net.template enc<last>().weight, loss, 3);
  check_parameter(net.latent_norm.bias, loss, 3);
  check_parameter(net.template dec<0>().weight, loss, 3);
  check_parameter(net.template dec<last>().bias, loss, 3);
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
  for (double g : net.template enc<2>().weight.grad) encoder_zero &= g == 0;
  for (double g : net.latent_norm.weight.grad) encoder_zero &= g == 0;
  for (double g : net.template dec<1>().weight.grad) decoder_nonzero |= g != 0;
  CHECK(encoder_zero);
  CHECK(decoder_nonzero);
}

TEST_CASE("auto-encoder layers: named enc0... and dec0... in file order, the widths of the preset") {
  std::vector<std::string> names;
  auto_encoder<autoencoder_compact_fine> fine(1);
  fine.for_each_parameter([&](nn::basic_parameter<float>& p) { names.push_back(p.name); });
  const std::vector<std::string> expected{"enc0.weight", "enc0.bias", "enc1.weight", "enc1.bias", "enc2.weight", "enc2.bias",
                                          "enc3.weight", "enc3.bias", "latent_norm.weight", "latent_norm.bias", "dec0.weight",
                                          "dec0.bias", "dec1.weight", "dec1.bias", "dec2.weight", "dec2.bias", "dec3.weight", "dec3.bias"};
  CHECK(names == expected);
  CHECK(auto_encoder<autoencoder_compact_fine>::size_multiple == 16);
  CHECK(auto_encoder<autoencoder_compact>::size_multiple == 32);
  CHECK(auto_encoder<autoencoder_compact_fine>::latent_channels == 128);
  // The compact preset's five levels: enc4 reads 128 channels, dec4 writes the 12 maps.
  auto_encoder<autoencoder_compact> compact(1);
  CHECK(compact.enc<4>().weight.shape == std::vector<int>{4, 4, 128, 128});
  CHECK(compact.dec<4>().weight.shape == std::vector<int>{4, 4, 32, parameter_count});
  CHECK(fine.dec<0>().weight.shape == std::vector<int>{4, 4, 128, 128});
  CHECK(fine.dec<3>().weight.shape == std::vector<int>{4, 4, 32, parameter_count});
  std::size_t count = 0;
  fine.for_each_parameter([&](nn::basic_parameter<float>& p) { count += p.size(); });
  CHECK(count == 865'100);  // 0.87 M: 432 736 in the encoder and its batch norm, 432 364 in the decoder
}

TEST_CASE("auto-encoder layers: compact-fine-wide is compact-fine with a 256-wide latent, the paper's 12 map values per latent value") {
  using wide = auto_encoder<autoencoder_compact_fine_wide>;
  CHECK(wide::size_multiple == 16);
  CHECK(wide::latent_channels == 256);
  // A cell of 16 x 16 texels holds 16 * 16 * 12 map values in 256 latent values, as the paper's
  // 32 * 32 * 12 in 1024.
  CHECK(16 * 16 * parameter_count / wide::latent_channels == 32 * 32 * parameter_count / auto_encoder<autoencoder_paper>::latent_channels);
  wide net(1);
  CHECK(net.enc<3>().weight.shape == std::vector<int>{4, 4, 128, 256});
  CHECK(net.dec<0>().weight.shape == std::vector<int>{4, 4, 256, 128});
  CHECK(net.dec<3>().weight.shape == std::vector<int>{4, 4, 32, parameter_count});
  std::size_t count = 0;
  net.for_each_parameter([&](nn::basic_parameter<float>& p) { count += p.size(); });
  // compact-fine's 865 100 plus 128 more filters in enc3 (262 272), their batch norm (256) and
  // dec0's weights for the 128 more latent channels (262 144).
  CHECK(count == 865'100 + 262'272 + 256 + 262'144);
}

TEST_CASE("auto-encoder layers: compact-fine-wider is compact-fine-wide with the levels above the latent twice as wide") {
  using wider = auto_encoder<autoencoder_compact_fine_wider>;
  CHECK(wider::size_multiple == 16);
  CHECK(wider::latent_channels == auto_encoder<autoencoder_compact_fine_wide>::latent_channels);
  wider net(1);
  CHECK(net.enc<0>().weight.shape == std::vector<int>{4, 4, parameter_count, 64});
  CHECK(net.enc<3>().weight.shape == std::vector<int>{4, 4, 256, 256});
  CHECK(net.dec<0>().weight.shape == std::vector<int>{4, 4, 256, 256});
  CHECK(net.dec<3>().weight.shape == std::vector<int>{4, 4, 64, parameter_count});
  std::size_t count = 0;
  net.for_each_parameter([&](nn::basic_parameter<float>& p) { count += p.size(); });
  // Encoder 12-64-128-256-256 (weights and biases), the batch norm's 256 scales and shifts, and
  // the mirrored decoder 256-256-128-64-12.
  const std::size_t encoder = (12 * 64 + 64 * 128 + 128 * 256 + 256 * 256) * 16 + (64 + 128 + 256 + 256);
  const std::size_t decoder = (256 * 256 + 256 * 128 + 128 * 64 + 64 * 12) * 16 + (256 + 128 + 64 + 12);
  CHECK(count == encoder + 2 * 256 + decoder);
  CHECK(count == 3'434'124);
}

TEST_CASE("auto-encoder layers: compact-fine-widest is compact-fine-wider with a 384-wide latent") {
  using widest = auto_encoder<autoencoder_compact_fine_widest>;
  CHECK(widest::size_multiple == 16);
  CHECK(widest::latent_channels == 384);
  widest net(1);
  CHECK(net.enc<2>().weight.shape == std::vector<int>{4, 4, 128, 256});
  CHECK(net.enc<3>().weight.shape == std::vector<int>{4, 4, 256, 384});
  CHECK(net.latent_norm.weight.size() == 384);
  CHECK(net.dec<0>().weight.shape == std::vector<int>{4, 4, 384, 256});
  CHECK(net.dec<3>().weight.shape == std::vector<int>{4, 4, 64, parameter_count});
  std::size_t count = 0;
  net.for_each_parameter([&](nn::basic_parameter<float>& p) { count += p.size(); });
  // compact-fine-wider's 3 434 124 plus 128 more filters in enc3 (256 x 128 x 16 weights and 128
  // biases), their batch norm (256) and dec0's weights for the 128 more latent channels.
  CHECK(count == 3'434'124 + (256 * 128 * 16 + 128) + 256 + 128 * 256 * 16);
  CHECK(count * 4 < 20'000'000);  // under the repository's 20 MB a weight file
}

TEST_CASE("auto-encoder layers: compact-fine-512 is compact-fine-wider with a 512-wide latent, under 20 MB with half-float kernels") {
  using net_512 = auto_encoder<autoencoder_compact_fine_512>;
  CHECK(net_512::size_multiple == 16);
  CHECK(net_512::latent_channels == 512);
  net_512 net(1);
  CHECK(net.enc<3>().weight.shape == std::vector<int>{4, 4, 256, 512});
  CHECK(net.latent_norm.weight.size() == 512);
  CHECK(net.dec<0>().weight.shape == std::vector<int>{4, 4, 512, 256});
  std::size_t count = 0, half_stored = 0;
  net.for_each_parameter([&](nn::basic_parameter<float>& p) {
    count += p.size();
    if (p.size() >= nn::half_storage_min_elements) half_stored += p.size();
  });
  // compact-fine-wider's 3 434 124 plus 256 more filters in enc3 (256 x 256 x 16 weights and 256
  // biases), their batch norm (512) and dec0's weights for the 256 more latent channels.
  CHECK(count == 3'434'124 + (256 * 256 * 16 + 256) + 512 + 256 * 256 * 16);
  CHECK(count * 4 > 20'000'000);                                   // as floats: over the 20 MB
  CHECK(half_stored * 2 + (count - half_stored) * 4 < 20'000'000);  // convert-weights --half: under
}
