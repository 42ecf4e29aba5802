// Texel-group skipping and the double-precision path of the fused loss (render/renderer.hpp).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "anisocap/render/renderer.hpp"
#include "render_reference.hpp"

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("skipped texel groups contribute their cached loss and keep their gradient entries") {
  const int w = 37, h = 29;  // 1073 texels: 17 groups, the last one partial
  const material_maps maps = random_maps(w, h, 4);
  const capture cap = random_capture(5, 9);
  const loss_targets targets = make_loss_targets(render(random_maps(w, h, 5), cap));
  const std::size_t groups_n = texel_groups::count(maps);
  REQUIRE(groups_n == (std::size_t(w * h) + texel_group_size - 1) / texel_group_size);

  material_maps full_grad(w, h);
  std::vector<double> losses(groups_n, -1.0);
  const texel_groups report{nullptr, losses.data()};
  const double full = loss_and_gradient(maps, cap, targets, &full_grad, {}, {}, &report);
  double sum = 0;
  for (double l : losses) { CHECK(l > 0); sum += l; }
  CHECK(sum == doctest::Approx(full).epsilon(1e-12));

  // Skip every other group: the loss is unchanged (cached values), skipped gradients untouched.
  std::vector<std::uint8_t> active(groups_n);
  for (std::size_t g = 0; g < groups_n; ++g) active[g] = g % 2;
  material_maps grad(w, h);
  const float sentinel = 12345.0f;
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < grad.texel_count(); ++i) grad.plane(k)[i] = sentinel;
  const texel_groups skip{active.data(), losses.data()};
  const double partial = loss_and_gradient(maps, cap, targets, &grad, {}, {}, &skip);
  CHECK(partial == doctest::Approx(full).epsilon(1e-12));
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < maps.texel_count(); ++i) {
      if (active[i / texel_group_size]) REQUIRE(grad.plane(k)[i] == full_grad.plane(k)[i]);
      else REQUIRE(grad.plane(k)[i] == sentinel);
    }

  // A skipped group really is not evaluated: a stale cached value shows up in the sum.
  losses[0] += 1.0;
  active[0] = 0;
  CHECK(loss_and_gradient(maps, cap, targets, nullptr, {}, {}, &skip) == doctest::Approx(full + 1.0).epsilon(1e-12));
  const texel_groups no_cache{active.data(), nullptr};
  CHECK_THROWS_AS(loss_and_gradient(maps, cap, targets, nullptr, {}, {}, &no_cache), std::invalid_argument);
}

TEST_CASE("the double-precision loss kernel agrees with float and with the scalar double build") {
  const int w = 23, h = 19;
  const material_maps maps = random_maps(w, h, 21);
  const capture cap = random_capture(8, 3);
  const loss_targets targets = make_loss_targets(render(random_maps(w, h, 22), cap));
  render_options dbl;
  dbl.double_precision = true;
  material_maps g_float(w, h), g_double(w, h), g_scalar(w, h);
  const double l_float = loss_and_gradient(maps, cap, targets, &g_float);
  const double l_double = loss_and_gradient(maps, cap, targets, &g_double, {}, dbl);
  const double l_scalar = loss_and_gradient<all_features, double>(maps, cap, targets, &g_scalar);
  // The SIMD double kernel and the scalar double kernel do the same arithmetic.
  CHECK(l_double == doctest::Approx(l_scalar).epsilon(1e-12));
  CHECK(l_float == doctest::Approx(l_double).epsilon(1e-5));
  for (int k = 0; k < parameter_count; ++k) {
    double scale = 0, diff = 0, diff_scalar = 0;
    for (std::size_t i = 0; i < maps.texel_count(); ++i) {
      scale = std::max(scale, double(std::abs(g_double.plane(k)[i])));
      diff = std::max(diff, double(std::abs(g_double.plane(k)[i] - g_float.plane(k)[i])));
      diff_scalar = std::max(diff_scalar, double(std::abs(g_double.plane(k)[i] - g_scalar.plane(k)[i])));
    }
    INFO("plane " << k);
    CHECK(diff <= 1e-3 * scale + 1e-12);
    CHECK(diff_scalar <= 1e-6 * scale + 1e-15);
  }
  // Rendering in double agrees with float.
  const auto rf = render(maps, cap);
  const auto rd = render<all_features, simd::batch<double>>(maps, cap);
  for (std::size_t k = 0; k < rf.size(); ++k)
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < rf[k].pixel_count(); ++i)
        REQUIRE(rd[k].plane(c)[i] == doctest::Approx(rf[k].plane(c)[i]).epsilon(1e-4));
}

TEST_CASE("restrict_to_features makes the full kernel render as the reduced one") {
  const int w = 16, h = 9;
  const capture cap = random_capture(6, 2);
  for (const brdf_features f : {brdf_features{false, true, true}, brdf_features{true, false, true}, brdf_features{true, true, false},
                                brdf_features{false, false, false}}) {
    material_maps maps = random_maps(w, h, 31);
    const auto reduced = with_features(f, [&]<brdf_features F>() { return render<F>(maps, cap); });
    restrict_to_features(maps, f);
    const auto full = render(maps, cap);
    for (std::size_t k = 0; k < full.size(); ++k)
      for (int c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < full[k].pixel_count(); ++i)
          REQUIRE(full[k].plane(c)[i] == doctest::Approx(reduced[k].plane(c)[i]).epsilon(1e-5));
  }
}

TEST_CASE("the loss targets reject NaN and infinite pixels") {
  std::vector<image> photos(2, image(4, 3, 3));
  CHECK_NOTHROW(make_loss_targets(photos));
  photos[1].plane(2)[5] = std::nanf("");
  CHECK_THROWS_WITH_AS(make_loss_targets(photos), doctest::Contains("image 1 has a non-finite value"), std::invalid_argument);
  photos[1].plane(2)[5] = INFINITY;
  CHECK_THROWS_AS(make_loss_targets(photos), std::invalid_argument);
}

TEST_CASE("the loss's one log for three channels agrees with three logs, also where the products leave float's range") {
  const int w = 23, h = 19;  // the last block has padding lanes
  const material_maps maps = random_maps(w, h, 31);
  for (const float brightness : {1.0f, 1e15f}) {
    // 1e15: renders near 1e14 against photographs near 1, so a pixel's three max(R', B') multiply
    // past float's range (3.4e38) and the kernel must take the logs one by one.
    CAPTURE(brightness);
    capture cap = random_capture(6, 32);
    const loss_targets targets = make_loss_targets(render(random_maps(w, h, 33), cap));
    for (auto& im : cap.images)
      for (float& i : im.intensity) i *= brightness;
    std::vector<double> reference_gradient;
    const double reference = reference_loss<all_features>(maps, cap, targets, reference_gradient);
    material_maps g(w, h);
    const double simd = loss_and_gradient(maps, cap, targets, &g);
    const double scalar = loss_and_gradient<all_features, float>(maps, cap, targets, nullptr);
    REQUIRE(std::isfinite(simd));
    CHECK(simd == doctest::Approx(reference).epsilon(1e-5));
    CHECK(scalar == doctest::Approx(reference).epsilon(1e-5));
    if (brightness > 1.0f) CHECK(reference > 6.0 * std::log(1e10));  // the renders are that far off
    // The gradient of the albedos is that of three separate terms.
    double scale = 0, diff = 0;
    for (int k = diffuse_r; k <= specular_b; ++k)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const double r = reference_gradient[std::size_t(k) * w * h + std::size_t(y) * w + x];
          scale = std::max(scale, std::abs(r));
          diff = std::max(diff, std::abs(double(g.at(k, x, y)) - r));
        }
    CHECK(diff <= 1e-4 * scale);
  }
}
