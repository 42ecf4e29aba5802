// Masks in the fused image loss (render/renderer.hpp, loss_targets): masked pixels add exact zeros
// to the loss and the gradient whatever their targets hold, each image's loss is the mean over its
// used pixels, the gradient matches finite differences with a mask, and crops keep the weights.
// Fractional mask values weigh their pixels: the loss is the weighted mean and its gradient matches
// finite differences.
#include <doctest/doctest.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "anisocap/render/renderer.hpp"
#include "loss_gradient_check.hpp"
#include "render_reference.hpp"
#include "support/two_threads.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

/// One mask per image, about `share` of the pixels left out (0), from `seed`.
std::vector<image> random_masks(int w, int h, std::size_t n, double share, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::bernoulli_distribution out(share);
  std::vector<image> masks;
  for (std::size_t k = 0; k < n; ++k) {
    image m(w, h, 1);
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] = out(gen) ? 0.0f : 1.0f;
    m.plane(0)[k % m.pixel_count()] = 1.0f;  // never an empty image
    masks.push_back(std::move(m));
  }
  return masks;
}

/// One mask per image of weights drawn from {0, 0.25, 0.6, 1}, from `seed`.
std::vector<image> fractional_masks(int w, int h, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_int_distribution<int> pick(0, 3);
  const float levels[] = {0.0f, 0.25f, 0.6f, 1.0f};
  std::vector<image> masks;
  for (std::size_t k = 0; k < n; ++k) {
    image m(w, h, 1);
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] = levels[pick(gen)];
    m.plane(0)[k % m.pixel_count()] = 0.6f;  // never an empty image
    masks.push_back(std::move(m));
  }
  return masks;
}

struct scene {
  int w = 21, h = 13;  // not a multiple of the SIMD width: the last block has padding lanes
  material_maps maps = random_maps(21, 13, 41);
  capture cap = random_capture(4, 42);
  std::vector<image> photos = render(random_maps(21, 13, 43), cap);
  std::vector<image> masks = random_masks(21, 13, 4, 0.3, 44);
};

/// Loss and gradient of every kernel path: SIMD float, scalar float, SIMD double.
template <class Check>
void for_each_path(const scene& s, const loss_targets& t, Check&& check) {
  material_maps g(s.w, s.h);
  double l = loss_and_gradient(s.maps, s.cap, t, &g);
  check(l, g);
  l = loss_and_gradient<all_features, float>(s.maps, s.cap, t, &g);
  check(l, g);
  render_options dbl;
  dbl.double_precision = true;
  l = loss_and_gradient(s.maps, s.cap, t, &g, {}, dbl);
  check(l, g);
}

}  // namespace

TEST_CASE("masked pixels: loss and gradient bit-identical whatever their targets hold") {
  const two_threads threads;
  const scene s;
  const loss_targets base = make_loss_targets(s.photos, s.masks);
  std::vector<double> losses;
  std::vector<material_maps> grads;
  for_each_path(s, base, [&](double l, const material_maps& g) {
    losses.push_back(l);
    grads.push_back(g);
  });
  // Targets changed at masked pixels only, directly (huge, tiny, negative, NaN, the rendered value).
  const auto rendered = render(s.maps, s.cap);
  for (int variant = 0; variant < 5; ++variant) {
    loss_targets t = base;
    for (std::size_t k = 0; k < t.images.size(); ++k)
      for (int c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < t.images[k].pixel_count(); ++i)
          if (t.masks[k].plane(0)[i] == 0.0f) {
            const float values[4] = {1e30f, 1e-30f, -1e6f, std::numeric_limits<float>::quiet_NaN()};
            t.images[k].plane(c)[i] = variant < 4 ? values[variant] : rendered[k].plane(c)[i] + loss_epsilon;
          }
    std::size_t path = 0;
    for_each_path(s, t, [&](double l, const material_maps& g) {
      INFO("variant " << variant << " path " << path);
      CHECK(l == losses[path]);  // bit-identical, not approximately
      CHECK(same_bits(g, grads[path]));
      ++path;
    });
  }
  // Photographs changed at masked pixels (to 1e6 and to the rendered value): identical targets.
  for (int variant = 0; variant < 2; ++variant) {
    std::vector<image> photos = s.photos;
    for (std::size_t k = 0; k < photos.size(); ++k)
      for (int c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < photos[k].pixel_count(); ++i)
          if (s.masks[k].plane(0)[i] == 0.0f) photos[k].plane(c)[i] = variant == 0 ? 1e6f : rendered[k].plane(c)[i];
    const loss_targets t = make_loss_targets(photos, s.masks);
    material_maps g(s.w, s.h);
    CHECK(loss_and_gradient(s.maps, s.cap, t, &g) == losses[0]);
    CHECK(same_bits(g, grads[0]));
  }
}

TEST_CASE("masked pixels: an unmasked change does move the loss (the test above can fail)") {
  const scene s;
  loss_targets t = make_loss_targets(s.photos, s.masks);
  const double before = loss_and_gradient(s.maps, s.cap, t, nullptr);
  std::size_t used = 0;
  while (t.masks[0].plane(0)[used] == 0.0f) ++used;
  t.images[0].plane(1)[used] *= 2.0f;
  CHECK(loss_and_gradient(s.maps, s.cap, t, nullptr) != before);
}

TEST_CASE("masks: each image's loss is the mean over its used pixels; an all-ones mask changes nothing") {
  const two_threads threads;
  const scene s;
  const loss_targets t = make_loss_targets(s.photos, s.masks);
  const auto rendered = render(s.maps, s.cap);
  double expected = 0;
  for (std::size_t k = 0; k < s.cap.images.size(); ++k) {
    double sum = 0;
    std::size_t used = 0;
    for (std::size_t i = 0; i < rendered[k].pixel_count(); ++i) {
      if (s.masks[k].plane(0)[i] == 0.0f) continue;
      ++used;
      for (int c = 0; c < 3; ++c)
        sum += std::abs(std::log(double(rendered[k].plane(c)[i]) + loss_epsilon) - std::log(double(s.photos[k].plane(c)[i]) + loss_epsilon));
    }
    CHECK(t.weights[k] == doctest::Approx(double(s.w * s.h) / double(used)));
    expected += sum / (3.0 * double(used));
  }
  CHECK(loss_and_gradient(s.maps, s.cap, t, nullptr) == doctest::Approx(expected).epsilon(1e-5));

  // All ones: the same bits as no mask at all.
  std::vector<image> ones;
  for (std::size_t k = 0; k < s.photos.size(); ++k) {
    image m(s.w, s.h, 1);
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] = 1.0f;
    ones.push_back(std::move(m));
  }
  material_maps g_none(s.w, s.h), g_ones(s.w, s.h);
  const double l_none = loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos), &g_none);
  const double l_ones = loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, ones), &g_ones);
  CHECK(l_none == l_ones);
  CHECK(same_bits(g_none, g_ones));
}

TEST_CASE("masks: a texel masked in every image gets an exactly zero gradient") {
  scene s;
  const int x = 5, y = 3;
  for (auto& m : s.masks) m.at(0, x, y) = 0.0f;
  material_maps g(s.w, s.h);
  loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, s.masks), &g);
  bool any_nonzero_elsewhere = false;
  for (int k = 0; k < parameter_count; ++k) {
    CHECK(g.at(k, x, y) == 0.0f);
    CHECK(!std::signbit(g.at(k, x, y)));  // +0, not -0
    any_nonzero_elsewhere |= g.at(k, x + 1, y) != 0.0f;
  }
  CHECK(any_nonzero_elsewhere);
}

TEST_CASE("masks: the gradient matches central differences") {
  scene s;
  s.w = 7, s.h = 5;
  s.maps = random_maps(7, 5, 51);
  s.photos = render(random_maps(7, 5, 53), s.cap);
  s.masks = random_masks(7, 5, 4, 0.4, 54);
  check_loss_gradient(s.maps, s.cap, make_loss_targets(s.photos, s.masks));
}

TEST_CASE("masks: crops keep the whole image's weights, so crop losses add up to the whole loss") {
  const scene s;
  const loss_targets t = make_loss_targets(s.photos, s.masks);
  const double whole = loss_and_gradient(s.maps, s.cap, t, nullptr);
  // Four tiles covering the material: area-weighted tile losses sum to the whole loss.
  const int xs[] = {0, 10, 21}, ys[] = {0, 6, 13};
  double sum = 0;
  loss_targets crop;
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 2; ++i) {
      const int x0 = xs[i], y0 = ys[j], w = xs[i + 1] - x0, h = ys[j + 1] - y0;
      crop_loss_targets(t, x0, y0, w, h, crop);
      CHECK(crop.masks.size() == t.masks.size());
      CHECK(crop.masks[2].at(0, 1, 1) == t.masks[2].at(0, x0 + 1, y0 + 1));
      material_maps tile(w, h);
      for (int k = 0; k < parameter_count; ++k)
        for (int y = 0; y < h; ++y)
          for (int x = 0; x < w; ++x) tile.at(k, x, y) = s.maps.at(k, x0 + x, y0 + y);
      sum += loss_and_gradient(tile, s.cap, crop, nullptr, tile_placement{s.w, s.h, x0, y0}) * double(w * h) / double(s.w * s.h);
    }
  CHECK(sum == doctest::Approx(whole).epsilon(1e-5));
}

TEST_CASE("masks: wrong counts and sizes, and an image with every pixel masked, are refused") {
  const scene s;
  std::vector<image> masks = s.masks;
  masks.pop_back();
  CHECK_THROWS_AS(make_loss_targets(s.photos, masks), std::invalid_argument);
  masks = s.masks;
  masks[1] = image(s.w + 1, s.h, 1);
  CHECK_THROWS_AS(make_loss_targets(s.photos, masks), std::invalid_argument);
  masks = s.masks;
  for (std::size_t i = 0; i < masks[2].pixel_count(); ++i) masks[2].plane(0)[i] = 0.0f;
  CHECK_THROWS_WITH_AS(make_loss_targets(s.photos, masks), doctest::Contains("every pixel of image 2 is masked"), std::invalid_argument);
  // A NaN target where the mask leaves the pixel out is harmless; where it is used, an error.
  std::vector<image> photos = s.photos;
  std::size_t masked = 0;
  while (s.masks[0].plane(0)[masked] != 0.0f) ++masked;
  photos[0].plane(0)[masked] = std::nanf("");
  CHECK_NOTHROW(make_loss_targets(photos, s.masks));
  CHECK_THROWS_AS(make_loss_targets(photos), std::invalid_argument);
}

TEST_CASE("fractional masks: each image's loss is the mask-weighted mean; values above 1 count as 1") {
  const two_threads threads;
  scene s;
  s.masks = fractional_masks(s.w, s.h, 4, 61);
  const loss_targets t = make_loss_targets(s.photos, s.masks);
  const auto rendered = render(s.maps, s.cap);
  std::vector<image> binary = s.masks;
  for (auto& m : binary)
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] = m.plane(0)[i] != 0.0f ? 1.0f : 0.0f;
  // The mean of |log differences| over each image's pixels with the weights of `masks`.
  auto weighted_mean = [&](const std::vector<image>& masks) {
    double total = 0;
    for (std::size_t k = 0; k < s.cap.images.size(); ++k) {
      double sum = 0, used = 0;
      for (std::size_t i = 0; i < rendered[k].pixel_count(); ++i) {
        const double m = masks[k].plane(0)[i];
        used += m;
        for (int c = 0; c < 3; ++c)
          sum += m * std::abs(std::log(double(rendered[k].plane(c)[i]) + loss_epsilon) - std::log(double(s.photos[k].plane(c)[i]) + loss_epsilon));
      }
      if (&masks == &s.masks) CHECK(t.weights[k] == doctest::Approx(double(s.w * s.h) / used));
      total += sum / (3.0 * used);
    }
    return total;
  };
  const double expected = weighted_mean(s.masks);
  for_each_path(s, t, [&](double l, const material_maps&) { CHECK(l == doctest::Approx(expected).epsilon(1e-5)); });
  // The weights matter: the same pixels used with weight 1 give the unweighted mean, another value.
  const double expected_binary = weighted_mean(binary);
  CHECK(std::abs(expected - expected_binary) > 1e-4 * expected);
  CHECK(loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, binary), nullptr) == doctest::Approx(expected_binary).epsilon(1e-5));
  // Above 1: the same as 1.
  std::vector<image> above = binary;
  for (auto& m : above)
    for (std::size_t i = 0; i < m.pixel_count(); ++i) m.plane(0)[i] *= 7.0f;
  CHECK(loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, above), nullptr) ==
        loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, binary), nullptr));
  // Negative or NaN weights are refused.
  std::vector<image> bad = s.masks;
  bad[1].plane(0)[3] = -0.5f;
  CHECK_THROWS_WITH_AS(make_loss_targets(s.photos, bad), doctest::Contains("mask 1 has a negative or non-finite value"), std::invalid_argument);
  bad[1].plane(0)[3] = std::nanf("");
  CHECK_THROWS_AS(make_loss_targets(s.photos, bad), std::invalid_argument);
}

TEST_CASE("fractional masks: the gradient matches central differences") {
  scene s;
  s.w = 7, s.h = 5;
  s.maps = random_maps(7, 5, 71);
  s.photos = render(random_maps(7, 5, 73), s.cap);
  s.masks = fractional_masks(7, 5, 4, 74);
  check_loss_gradient(s.maps, s.cap, make_loss_targets(s.photos, s.masks));
}

TEST_CASE("masks: a mask is not read where it is all ones, with the same loss and gradient bits as when it is") {
  const scene s;  // 21 x 13 = 273 texels: texel groups of 64, 64, 64, 64 and 17
  const std::size_t groups = 5;
  // Image 1 leaves out texel (3, 2) = 45 of group 0 and image 3 halves texel (5, 7) = 152 of
  // group 2; images 0 and 2 are all ones.
  std::vector<image> masks(4, image(s.w, s.h, 1));
  for (image& m : masks) std::fill(m.plane(0), m.plane(0) + m.pixel_count(), 1.0f);
  masks[1].at(0, 3, 2) = 0.0f;
  masks[3].at(0, 5, 7) = 0.5f;
  const loss_targets flagged = make_loss_targets(s.photos, masks);
  REQUIRE(flagged.mask_all_ones == std::vector<std::uint8_t>{1, 1, 1, 1, 1,  0, 1, 1, 1, 1,  1, 1, 1, 1, 1,  1, 1, 0, 1, 1});
  loss_targets read_all = flagged;
  read_all.mask_all_ones.clear();
  // A group that the flags wrongly called all ones would be skipped: the flags decide.
  loss_targets wrong = flagged;
  wrong.mask_all_ones.assign(4 * groups, 1);
  const two_threads threads;
  {
    material_maps g_flagged(s.w, s.h), g_read(s.w, s.h), g_wrong(s.w, s.h);
    const double l_flagged = loss_and_gradient(s.maps, s.cap, flagged, &g_flagged);
    const double l_read = loss_and_gradient(s.maps, s.cap, read_all, &g_read);
    const double l_wrong = loss_and_gradient(s.maps, s.cap, wrong, &g_wrong);
    CHECK(l_flagged == l_read);
    CHECK(l_wrong != l_read);
    for (int k = 0; k < parameter_count; ++k)
      for (std::size_t i = 0; i < g_read.texel_count(); ++i) REQUIRE(g_flagged.plane(k)[i] == g_read.plane(k)[i]);
    // Without any masks the loss is the same too: every mask of the all-ones set is skipped.
    const std::vector<image> ones(4, masks[0]);
    const loss_targets all_ones = make_loss_targets(s.photos, ones);
    REQUIRE(all_ones.mask_all_ones == std::vector<std::uint8_t>(4 * groups, 1));
    CHECK(loss_and_gradient(s.maps, s.cap, all_ones, nullptr) == loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos), nullptr));
  }
  // Flags of another size are refused rather than read out of place.
  loss_targets stale = flagged;
  stale.mask_all_ones.assign(4, 1);
  CHECK_THROWS_AS(loss_and_gradient(s.maps, s.cap, stale, nullptr), std::invalid_argument);
  // A crop takes its flags from its own window: (2, 1) + 9 x 6 holds texel (3, 2) and not (5, 7).
  loss_targets crop;
  crop_loss_targets(flagged, 2, 1, 9, 6, crop);
  CHECK(crop.mask_all_ones == std::vector<std::uint8_t>{1, 0, 1, 1});
  loss_targets crop_read = crop;
  crop_read.mask_all_ones.clear();
  const material_maps crop_maps = random_maps(9, 6, 45);
  const tile_placement place{s.w, s.h, 2, 1};
  CHECK(loss_and_gradient(crop_maps, s.cap, crop, nullptr, place) == loss_and_gradient(crop_maps, s.cap, crop_read, nullptr, place));
}
