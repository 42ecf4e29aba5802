// brdf/canonical_maps.hpp: the canonical form renders every pixel as before, and is canonical.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "../render/render_reference.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/renderer.hpp"

using namespace anisocap;

namespace {

/// Random maps whose lobes take every form: sy > sx, alpha anywhere in (-2 pi, 2 pi).
material_maps scrambled_maps(int w, int h, std::uint64_t seed) {
  material_maps m = testing::random_maps(w, h, seed);
  std::mt19937_64 gen(seed + 1);
  std::uniform_real_distribution<float> angle(-2 * std::numbers::pi_v<float>, 2 * std::numbers::pi_v<float>);
  for (std::size_t i = 0; i < m.texel_count(); ++i) m.plane(rotation)[i] = angle(gen);
  return m;
}

void require_same_renders(const material_maps& a, const material_maps& b, const capture& cap) {
  const auto ra = render(a, cap), rb = render(b, cap);
  double worst = 0;
  for (std::size_t k = 0; k < cap.images.size(); ++k)
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < ra[k].pixel_count(); ++i) {
        const double x = ra[k].plane(c)[i], y = rb[k].plane(c)[i];
        worst = std::max(worst, std::abs(x - y) / std::max(1e-3, std::abs(x)));
      }
  CHECK(worst < 2e-4);  // float rounding of cos/sin of alpha, amplified by narrow lobes
}

}  // namespace

TEST_CASE("make_canonical: sx >= sy, alpha in [-pi/2, pi/2), and the same lobe") {
  constexpr float pi = std::numbers::pi_v<float>;
  const float cases[][3] = {{0.1f, 0.3f, 0.2f}, {0.3f, 0.1f, 2.0f}, {0.2f, 0.2f, -pi / 2}, {0.05f, 0.4f, -3.0f},
                            {0.4f, 0.05f, float(std::numbers::pi / 2)}, {0.3f, 0.3f, 7.0f}, {0.1f, 0.2f, -float(std::numbers::pi / 2)}};
  for (const auto& c : cases) {
    const canonical_lobe k = make_canonical(c[0], c[1], c[2]);
    CAPTURE(c[0]); CAPTURE(c[1]); CAPTURE(c[2]);
    CHECK(is_canonical(k.sx, k.sy, k.alpha));
    CHECK(std::max(c[0], c[1]) == k.sx);
    CHECK(std::min(c[0], c[1]) == k.sy);
    // The lobe's quadratic form is the same: compare the exponent along a few slope directions.
    for (double phi = 0; phi < 6.3; phi += 0.5) {
      auto q = [&](double sx, double sy, double a) {
        const double u = std::cos(phi - a), v = std::sin(phi - a);
        return u * u / (sx * sx) + v * v / (sy * sy);
      };
      CHECK(q(k.sx, k.sy, k.alpha) == doctest::Approx(q(c[0], c[1], c[2])).epsilon(1e-5));
    }
    const canonical_lobe again = make_canonical(k.sx, k.sy, k.alpha);  // idempotent
    CHECK(again.sx == k.sx);
    CHECK(again.sy == k.sy);
    CHECK(again.alpha == k.alpha);
  }
}

TEST_CASE("canonicalise leaves every rendered pixel unchanged and the maps canonical") {
  for (std::uint64_t seed : {3u, 4u}) {
    const material_maps before = scrambled_maps(24, 19, seed);
    material_maps after = before;
    canonicalise(after);
    std::size_t swapped = 0;
    for (std::size_t i = 0; i < after.texel_count(); ++i) {
      REQUIRE(is_canonical(after.plane(lobe_x)[i], after.plane(lobe_y)[i], after.plane(rotation)[i]));
      swapped += after.plane(lobe_x)[i] != before.plane(lobe_x)[i];
    }
    CHECK(swapped > after.texel_count() / 4);  // the test exercises the swap
    require_same_renders(before, after, testing::random_capture(6, seed + 10));
    require_same_renders(before, after, set_alpha(8, seed, before.width(), before.height()));
  }
  // A procedural material (anisotropic weave) with its lobes deliberately given in swapped form.
  material_maps weave = generate_material(7, 32, 32);
  material_maps swapped = weave;
  for (std::size_t i = 0; i < weave.texel_count(); ++i) {
    std::swap(swapped.plane(lobe_x)[i], swapped.plane(lobe_y)[i]);
    swapped.plane(rotation)[i] += std::numbers::pi_v<float> / 2;
  }
  canonicalise(swapped);
  require_same_renders(weave, swapped, set_beta(10, 5, 32, 32));
}
