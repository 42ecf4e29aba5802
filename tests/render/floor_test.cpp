// Floors in the fused image loss (render/renderer.hpp, loss_targets): below an image's floor f the
// loss takes photograph and render as f, so the loss is the plain formula on max(value, f), a
// render under the floor gets no gradient, all-zero floors change nothing, the gradient matches
// central differences on every kernel path, and bad floors are refused.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "anisocap/render/renderer.hpp"
#include "loss_gradient_check.hpp"
#include "render_reference.hpp"
#include "support/two_threads.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

struct scene {
  int w = 21, h = 13;  // not a multiple of the SIMD width: the last block has padding lanes
  material_maps maps = random_maps(21, 13, 81);
  capture cap = random_capture(4, 82);
  std::vector<image> photos = render(random_maps(21, 13, 83), cap);
};

/// A floor that about `share` of the rendered and photographed values lie under, half-way across
/// the widest gap between neighbouring values near that quantile, so that no value sits on the
/// floor's kink (central differences would straddle it).
float level_between(const scene& s, double share) {
  std::vector<float> v;
  for (const auto& set : {render(s.maps, s.cap), s.photos})
    for (const image& im : set)
      for (int c = 0; c < 3; ++c) v.insert(v.end(), im.plane(c), im.plane(c) + im.pixel_count());
  std::sort(v.begin(), v.end());
  const std::size_t at = std::size_t(share * double(v.size() - 1));
  std::size_t best = at;
  for (std::size_t i = at > 20 ? at - 20 : 0; i + 1 < v.size() && i < at + 20; ++i)
    if (v[i + 1] - v[i] > v[best + 1] - v[best]) best = i;
  return 0.5f * (v[best] + v[best + 1]);
}

/// sum_i mean_{p, c} |log(max(R, f_i) + eps) - log(max(B, f_i) + eps)| in double.
double reference_loss(const scene& s, const std::vector<float>& floors) {
  const auto rendered = render(s.maps, s.cap);
  double total = 0;
  for (std::size_t k = 0; k < rendered.size(); ++k) {
    const double f = floors[k];
    double sum = 0;
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < rendered[k].pixel_count(); ++i)
        sum += std::abs(std::log(std::max(double(rendered[k].plane(c)[i]), f) + loss_epsilon) -
                        std::log(std::max(double(s.photos[k].plane(c)[i]), f) + loss_epsilon));
    total += sum / (3.0 * double(rendered[k].pixel_count()));
  }
  return total;
}

}  // namespace

TEST_CASE("floors: the loss is the plain loss of max(value, floor) on every kernel path") {
  const two_threads threads;
  const scene s;
  const std::vector<float> floors = {level_between(s, 0.5), 0.0f, level_between(s, 0.3), level_between(s, 0.7)};  // one image without a floor
  REQUIRE(floors[2] > 0);
  const loss_targets t = make_loss_targets(s.photos, {}, floors);
  const double expected = reference_loss(s, floors);
  CHECK(loss_and_gradient(s.maps, s.cap, t, nullptr) == doctest::Approx(expected).epsilon(1e-5));
  CHECK(loss_and_gradient<all_features, float>(s.maps, s.cap, t, nullptr) == doctest::Approx(expected).epsilon(1e-5));
  render_options dbl;
  dbl.double_precision = true;
  CHECK(loss_and_gradient(s.maps, s.cap, t, nullptr, {}, dbl) == doctest::Approx(expected).epsilon(1e-5));
  // The floors matter: the plain loss is another value.
  const double plain = loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos), nullptr, {}, dbl);
  CHECK(std::abs(plain - expected) > 1e-3 * plain);
  CHECK(plain == doctest::Approx(reference_loss(s, {0.0f, 0.0f, 0.0f, 0.0f})).epsilon(1e-5));
}

TEST_CASE("floors: all-zero floors are the plain loss, bit for bit") {
  const scene s;
  material_maps g0(s.w, s.h), g1(s.w, s.h);
  const double plain = loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos), &g0);
  const loss_targets zero = make_loss_targets(s.photos, {}, {0.0f, 0.0f, 0.0f, 0.0f});
  CHECK(zero.floors.empty());
  CHECK(loss_and_gradient(s.maps, s.cap, zero, &g1) == plain);
  CHECK(same_bits(g0, g1));
}

TEST_CASE("floors: a texel rendered and photographed under the floor in every image adds nothing") {
  scene s;
  const int x = 4, y = 6;
  // Black at (x, y): no albedo renders 0, and the photographs hold 0 there.
  s.maps.at(diffuse_r, x, y) = s.maps.at(diffuse_g, x, y) = s.maps.at(diffuse_b, x, y) = 0.0f;
  s.maps.at(specular_r, x, y) = s.maps.at(specular_g, x, y) = s.maps.at(specular_b, x, y) = 0.0f;
  for (image& p : s.photos)
    for (int c = 0; c < 3; ++c) p.at(c, x, y) = 0.0f;
  const std::vector<float> floors(4, 1e-3f);
  material_maps g(s.w, s.h);
  loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, {}, floors), &g);
  bool any_nonzero_elsewhere = false;
  for (int k = 0; k < parameter_count; ++k) {
    CHECK(g.at(k, x, y) == 0.0f);
    any_nonzero_elsewhere |= g.at(k, x + 1, y) != 0.0f;
  }
  CHECK(any_nonzero_elsewhere);
  // Without the floor the same texel is pulled (a zero render against a zero photo is a tie, so
  // give the photographs a little light there): the test above can fail.
  for (image& p : s.photos)
    for (int c = 0; c < 3; ++c) p.at(c, x, y) = 5e-4f;
  loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos), &g);
  CHECK(g.at(diffuse_r, x, y) != 0.0f);
  loss_and_gradient(s.maps, s.cap, make_loss_targets(s.photos, {}, floors), &g);
  for (int k = 0; k < parameter_count; ++k) CHECK(g.at(k, x, y) == 0.0f);
}

TEST_CASE("floors: the gradient matches central differences") {
  scene s;
  s.w = 7, s.h = 5;
  s.maps = random_maps(7, 5, 91);
  s.photos = render(random_maps(7, 5, 93), s.cap);
  const loss_targets t = make_loss_targets(s.photos, {}, {level_between(s, 0.5), level_between(s, 0.3), level_between(s, 0.5), level_between(s, 0.7)});
  const material_maps g = check_loss_gradient(s.maps, s.cap, t);
  std::size_t zero_entries = 0;
  for (int k = 0; k < parameter_count; ++k) zero_entries += std::size_t(std::count(g.plane(k), g.plane(k) + g.texel_count(), 0.0f));
  // Floors near the median leave some texels under the floor in every image: their entries are 0.
  CHECK(zero_entries > 0);
  // Float SIMD and scalar paths give the double path's gradient to float accuracy.
  material_maps gs(s.w, s.h), gf(s.w, s.h);
  loss_and_gradient(s.maps, s.cap, t, &gs);
  loss_and_gradient<all_features, float>(s.maps, s.cap, t, &gf);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < g.texel_count(); ++i) {
      const double tolerance = 1e-3 * (std::abs(g.plane(k)[i]) + 1e-3);
      CHECK(std::abs(gs.plane(k)[i] - g.plane(k)[i]) <= tolerance);
      CHECK(std::abs(gf.plane(k)[i] - g.plane(k)[i]) <= tolerance);
    }
}

TEST_CASE("floors: wrong counts, negative and non-finite floors are refused") {
  const scene s;
  CHECK_THROWS_WITH_AS(make_loss_targets(s.photos, {}, {0.1f, 0.1f}), doctest::Contains("2 floors for 4 images"), std::invalid_argument);
  CHECK_THROWS_WITH_AS(make_loss_targets(s.photos, {}, {0.1f, -0.1f, 0.1f, 0.1f}), doctest::Contains("floor of image 1"),
                       std::invalid_argument);
  CHECK_THROWS_AS(make_loss_targets(s.photos, {}, {0.1f, 0.1f, std::nanf(""), 0.1f}), std::invalid_argument);
  CHECK_THROWS_AS(make_loss_targets(s.photos, {}, {0.1f, 0.1f, 0.1f, INFINITY}), std::invalid_argument);
}
