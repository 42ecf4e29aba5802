// estimation_network (networks/estimator.hpp): shapes for odd sizes and 1, 3, 5 images, invariance to
// the order of the images (max-pool), output ranges, multiple sets in one batch.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <vector>

#include "anisocap/core/random.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "tiny_presets.hpp"

using namespace anisocap;
using Net = estimation_network<testing::estimator_tiny>;

namespace {
std::vector<image> random_photos(int n, int width, int height, std::uint64_t seed) {
  random_generator rng(seed);
  std::vector<image> photos;
  for (int i = 0; i < n; ++i) {
    image im(width, height, 3);
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) im.at(c, x, y) = float(rng.uniform() * 1.5);
    photos.push_back(im);
  }
  return photos;
}

/// True when every value of the map set lies in its parameter's valid range (docs/method.md section 1).
bool in_range(const material_maps& m) {
  for (int y = 0; y < m.height(); ++y)
    for (int x = 0; x < m.width(); ++x) {
      for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0})
        if (!(m.at(k, x, y) >= 0 && m.at(k, x, y) <= 1)) return false;
      for (int k : {lobe_x, lobe_y})
        if (!(m.at(k, x, y) >= min_lobe_width * 0.999f && m.at(k, x, y) <= 1)) return false;
      if (!(std::hypot(m.at(normal_x, x, y), m.at(normal_y, x, y)) < 1)) return false;
      if (!(std::abs(m.at(rotation, x, y)) <= 1.5708f)) return false;
    }
  return true;
}
}  // namespace

TEST_CASE("estimator: any size and 1, 3 or 5 images give maps of the input's size in range") {
  Net net(3);
  for (int n : {1, 3, 5}) {
    for (auto [w, h] : {std::pair{37, 21}, std::pair{64, 64}, std::pair{70, 129}}) {
      const material_maps m = net.estimate(random_photos(n, w, h, 100 + n));
      CHECK(m.width() == w);
      CHECK(m.height() == h);
      CHECK(in_range(m));
    }
  }
  CHECK_THROWS_AS(net.estimate({}), std::invalid_argument);
  auto mixed = random_photos(2, 16, 16, 5);
  mixed.push_back(random_photos(1, 17, 16, 6)[0]);
  CHECK_THROWS_AS(net.estimate(mixed), std::invalid_argument);
}

TEST_CASE("estimator: estimate() keeps its tape between calls: same results, no new memory for a same-size call, copies do not share it") {
  Net net(4);
  const auto photos = random_photos(3, 70, 40, 21), other = random_photos(2, 33, 65, 22);
  CHECK(net.scratch_bytes() == 0);
  const material_maps first = net.estimate(photos);
  CHECK(net.scratch_bytes() > 0);
  const material_maps between = net.estimate(other);  // a different size in between
  const material_maps again = net.estimate(photos);
  CHECK(net.scratch_bytes() > 0);  // consolidated into one block of the largest call's size
  const std::size_t grown = net.scratch_bytes();
  (void)net.estimate(photos);
  CHECK(net.scratch_bytes() == grown);  // steady state: the same call takes nothing new
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < first.height(); ++y)
      for (int x = 0; x < first.width(); ++x) REQUIRE(again.at(k, x, y) == first.at(k, x, y));
  Net copy = net;
  CHECK(copy.scratch_bytes() == 0);
  const material_maps from_copy = copy.estimate(other);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < other[0].height(); ++y)
      for (int x = 0; x < other[0].width(); ++x) REQUIRE(from_copy.at(k, x, y) == between.at(k, x, y));
  net.release_scratch();
  CHECK(net.scratch_bytes() == 0);
}

TEST_CASE("estimator: the result does not depend on the order of the images (max-pool over images)") {
  Net net(4);
  auto photos = random_photos(4, 40, 33, 9);
  const material_maps a = net.estimate(photos);
  std::reverse(photos.begin(), photos.end());
  std::swap(photos[1], photos[2]);
  const material_maps b = net.estimate(photos);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < a.texel_count(); ++i) REQUIRE(a.plane(k)[i] == b.plane(k)[i]);
  // A different image set gives different maps (the network does read its inputs).
  const material_maps c = net.estimate(random_photos(4, 40, 33, 10));
  double diff = 0;
  for (std::size_t i = 0; i < a.texel_count(); ++i) diff += std::abs(a.plane(diffuse_r)[i] - c.plane(diffuse_r)[i]);
  CHECK(diff > 0);
}

TEST_CASE("estimator: two sets in one batch give what each gives alone; forward rejects sizes not multiple of 64") {
  Net net(5);
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  auto x = t.make_variable<3>(6, 64, 128, false);
  random_generator rng(3);
  for (std::size_t i = 0; i < x.value.size(); ++i) x.value.data()[i] = float(rng.uniform() * 2 - 1);
  auto y = net.forward(t, x, 3);
  REQUIRE(y.value.batch() == 2);
  CHECK(y.value.height() == 64);
  CHECK(y.value.width() == 128);
  auto x1 = t.make_variable<3>(3, 64, 128, false);
  std::copy_n(x.value.pixel(3, 0, 0), x1.value.size(), x1.value.data());
  auto y1 = net.forward(t, x1, 3);
  for (std::size_t i = 0; i < y1.value.size(); ++i) REQUIRE(y1.value.data()[i] == doctest::Approx(y.value.pixel(1, 0, 0)[i]).epsilon(1e-5));
  auto bad = t.make_variable<3>(1, 96, 64, false);
  CHECK_THROWS_AS(net.forward(t, bad, 1), std::invalid_argument);
}

TEST_CASE("estimator, doubled-angle preset: maps in range, alpha starts at 0, starts from a tanh-preset file but for its last layer") {
  using Doubled = estimation_network<testing::estimator_tiny_doubled_angle>;
  Doubled net(3);
  const material_maps m = net.estimate(random_photos(3, 50, 40, 7));
  CHECK(in_range(m));
  // The fresh head's (c, s) is (1, ~0): alpha near 0 everywhere.
  float largest = 0;
  for (std::size_t i = 0; i < m.texel_count(); ++i) largest = std::max(largest, std::abs(m.plane(rotation)[i]));
  CHECK(largest < 0.2f);

  // A file of the tanh preset loads into every layer but the last of track 2 (3 outputs there, 4 here).
  Net plain(11);
  const auto file = std::filesystem::temp_directory_path() / "anisocap_doubled_angle_init.safetensors";
  nn::save_weights(file, plain);
  CHECK_THROWS_AS(nn::load_weights(file, net), std::runtime_error);
  const float before_c = net.head2.c2.bias.value[2];
  const std::vector<std::string> fresh = nn::load_matching_weights(file, net);
  std::vector<std::string> last_layer;
  net.head2.c2.for_each_parameter([&](auto& p) { last_layer.push_back(p.name); });
  CHECK(fresh == last_layer);
  CHECK(net.head2.c2.bias.value[2] == before_c);  // kept its initial value
  for (std::size_t i = 0; i < net.enc2.weight.size(); ++i) REQUIRE(net.enc2.weight.value[i] == plain.enc2.weight.value[i]);
  for (std::size_t i = 0; i < net.head2.c1.weight.size(); ++i) REQUIRE(net.head2.c1.weight.value[i] == plain.head2.c1.weight.value[i]);
  // A file that shares no tensor with the network is refused.
  nn::linear<4, 4> other("unrelated", 2);
  nn::save_weights(file, other);
  CHECK_THROWS_WITH_AS(nn::load_matching_weights(file, net), doctest::Contains("no tensor matches"), std::runtime_error);
  std::filesystem::remove(file);
}

TEST_CASE("estimator, doubled-angle preset started from a tanh file: normals and track 1 as they were, alpha / (pi/2) = atan(pi z) / pi") {
  Net plain(11);
  // Spread the tanh head's pre-activations z over a range where tanh is far from linear.
  for (std::size_t i = 0; i < plain.head2.c2.weight.size(); ++i) plain.head2.c2.weight.value[i] *= 6.0f;
  plain.head2.c2.bias.value[2] = 0.3f;
  const auto file = std::filesystem::temp_directory_path() / "anisocap_doubled_angle_start.safetensors";
  nn::save_weights(file, plain);
  estimation_network<testing::estimator_tiny_doubled_angle> net(3);
  REQUIRE(!nn::load_matching_weights(file, net).empty());
  REQUIRE(start_doubled_angle_head(file, net));
  const auto photos = random_photos(3, 40, 30, 21);
  const material_maps a = plain.estimate(photos), b = net.estimate(photos);
  double largest_u = 0;
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) {
      for (int k = 0; k < parameter_count; ++k)
        if (k != rotation) REQUIRE(b.at(k, x, y) == doctest::Approx(a.at(k, x, y)).epsilon(1e-5));
      const double u = a.at(rotation, x, y) / (std::numbers::pi / 2);
      if (std::abs(u) > 0.95) continue;  // tanh's tail: atanh of a float there is too inexact to compare
      largest_u = std::max(largest_u, std::abs(u));
      const double expected = std::atan(std::numbers::pi * std::atanh(u)) / std::numbers::pi;
      REQUIRE(b.at(rotation, x, y) / (std::numbers::pi / 2) == doctest::Approx(expected).epsilon(1e-4).scale(1));
    }
  CHECK(largest_u > 0.3);  // the check covered the non-linear range
  // A file whose last layer already has 4 outputs is not a tanh head: nothing changes.
  nn::save_weights(file, net);
  const float c_bias = net.head2.c2.bias.value[2] = 0.5f;
  CHECK_FALSE(start_doubled_angle_head(file, net));
  CHECK(net.head2.c2.bias.value[2] == c_bias);
  std::filesystem::remove(file);
}

TEST_CASE("estimator, orientation preset: 6 input channels, maps of any size in range, starts from a 3-channel file but for its first layer") {
  using Oriented = estimation_network<testing::estimator_tiny_orientation>;
  static_assert(Oriented::inputs == 6 && Net::inputs == 3);
  Oriented net(3);
  for (auto [w, h] : {std::pair{37, 21}, std::pair{70, 129}, std::pair{20, 20}}) {  // 20 -> 64: the repeated-mirror path
    const material_maps m = net.estimate(random_photos(3, w, h, 40));
    CHECK(m.width() == w);
    CHECK(m.height() == h);
    CHECK(in_range(m));
  }
  // The orientation channels reach the network: the same photo with channels 3-5 zeroed gives other maps.
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  auto x = t.make_variable<6>(1, 64, 64, false);
  network_space::photo_to_network(random_photos(1, 64, 64, 41)[0], x.value, 0);
  const auto y = net.forward(t, x, 1).value;
  for (int py = 0; py < 64; ++py)
    for (int px = 0; px < 64; ++px)
      for (int c = 3; c < 6; ++c) x.value.pixel(0, py, px)[c] = 0;
  const auto z = net.forward(t, x, 1).value;
  double diff = 0;
  for (std::size_t i = 0; i < y.size(); ++i) diff += std::abs(y.data()[i] - z.data()[i]);
  CHECK(diff > 0);
  // A file of the 3-channel preset loads into every tensor but the first layer's weights.
  const auto file = std::filesystem::temp_directory_path() / "anisocap_estimator_orientation_init.safetensors";
  Net plain(8);
  nn::save_weights(file, plain);
  const std::vector<std::string> fresh = nn::load_matching_weights(file, net);
  CHECK(fresh == std::vector<std::string>{"enc0.weight"});
  CHECK(net.enc0.bias.value[0] == plain.enc0.bias.value[0]);
  std::filesystem::remove(file);
}

