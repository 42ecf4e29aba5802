// The fused renderer against the readable reference `ward_evaluate` (docs/method.md section 3-4), which is itself
// checked against finite differences in tests/brdf/ward_test.cpp.
#include <doctest/doctest.h>

#include <cmath>
#include <random>

#include "anisocap/render/renderer.hpp"
#include "render_reference.hpp"

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("render matches the reference implementation, SIMD and scalar") {
  const material_maps maps = random_maps(23, 17, 5);
  const capture cap = random_capture(6, 11);
  const auto simd_images = render(maps, cap);
  const auto scalar_images = render<all_features, float>(maps, cap);
  for (std::size_t k = 0; k < cap.images.size(); ++k) {
    for (int y = 0; y < maps.height(); ++y)
      for (int x = 0; x < maps.width(); ++x) {
        const auto ref = reference_radiance<double>(maps, cap.images[k], x, y, {});
        for (int c = 0; c < 3; ++c) {
          const double tol = 2e-4 * std::max(1.0, std::abs(ref[c]));
          REQUIRE(std::abs(simd_images[k].at(c, x, y) - ref[c]) < tol + 1e-5 * std::abs(ref[c]) * 100);
          REQUIRE(std::abs(scalar_images[k].at(c, x, y) - ref[c]) < tol + 1e-3 * std::abs(ref[c]));
        }
      }
  }
}

TEST_CASE("a tile renders exactly as the same texels of the whole material") {
  const material_maps maps = random_maps(40, 30, 9);
  const capture cap = random_capture(3, 4);
  const auto whole = render(maps, cap);
  const int x0 = 13, y0 = 7, w = 19, h = 11;
  material_maps tile(w, h);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) tile.at(k, x, y) = maps.at(k, x0 + x, y0 + y);
  const auto part = render(tile, cap, tile_placement{40, 30, x0, y0});
  for (std::size_t k = 0; k < cap.images.size(); ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (int c = 0; c < 3; ++c) REQUIRE(part[k].at(c, x, y) == whole[k].at(c, x0 + x, y0 + y));
}

template <brdf_features F>
void check_loss_gradient(std::uint64_t seed) {
  const int w = 9, h = 7;
  const material_maps maps = random_maps(w, h, seed, F);
  const capture cap = random_capture(5, seed + 1);
  const material_maps truth = random_maps(w, h, seed + 2, F);
  const loss_targets targets = make_loss_targets(render<F>(truth, cap));
  material_maps grad(w, h);
  const double loss = loss_and_gradient<F>(maps, cap, targets, &grad);
  material_maps grad_scalar(w, h);
  const double loss_scalar = loss_and_gradient<F, float>(maps, cap, targets, &grad_scalar);
  std::vector<double> ref_grad;
  const double ref_loss = reference_loss<F>(maps, cap, targets, ref_grad);
  CHECK(loss == doctest::Approx(ref_loss).epsilon(1e-4));
  CHECK(loss_scalar == doctest::Approx(ref_loss).epsilon(1e-4));
  // Compare gradients relative to the largest gradient of each plane.
  for (int k = 0; k < parameter_count; ++k) {
    double scale = 1e-12;
    for (int i = 0; i < w * h; ++i) scale = std::max(scale, std::abs(ref_grad[std::size_t(k) * w * h + i]));
    for (int i = 0; i < w * h; ++i) {
      const double r = ref_grad[std::size_t(k) * w * h + i];
      INFO("plane " << k << " texel " << i << " ref " << r << " simd " << grad.plane(k)[i]);
      REQUIRE(std::abs(grad.plane(k)[i] - r) < 2e-3 * scale + 1e-6);
      REQUIRE(std::abs(grad_scalar.plane(k)[i] - r) < 2e-3 * scale + 1e-6);
    }
  }
}

TEST_CASE("fused loss and gradient match the reference's dual-number gradient") {
  check_loss_gradient<all_features>(100);
  check_loss_gradient<all_features>(200);
  check_loss_gradient<brdf_features{false, true, true}>(300);
  check_loss_gradient<brdf_features{true, false, true}>(400);
  check_loss_gradient<brdf_features{true, true, false}>(500);
  check_loss_gradient<brdf_features{false, false, false}>(600);
}

TEST_CASE("specular culling changes the loss by at most its stated bound") {
  const material_maps maps = random_maps(32, 24, 77);
  const capture cap = random_capture(6, 78);
  const loss_targets targets = make_loss_targets(render(random_maps(32, 24, 79), cap));
  for (float tol : {1e-4f, 1e-3f, 1e-2f}) {
    render_options o;
    o.cull_tolerance = tol;
    const double exact = loss_and_gradient(maps, cap, targets, nullptr);
    const double culled = loss_and_gradient(maps, cap, targets, nullptr, {}, o);
    // Each of the (images x texels x 3) terms moves by at most tol; the loss averages them per image.
    CHECK(std::abs(culled - exact) <= double(tol) * double(cap.images.size()) + 1e-6);
  }
}

TEST_CASE("a lobe past exp(max_log_lobe) renders at that bound, with no gradient in its shape") {
  // Camera and lamp grazing from opposite sides, 2e-6 radians above a flat texel of the narrowest
  // lobe and the smallest F0: E = log(h.h F/F0 / h_z^4) - log(pi sx sy) is about 51.4.
  CHECK(ward_limits::max_lobe == float(std::exp(double(ward_limits::max_log_lobe))));
  material_maps maps(1, 1);
  for (int c = 0; c < 3; ++c) {
    maps.at(diffuse_r + c, 0, 0) = 0.0f;
    maps.at(specular_r + c, 0, 0) = 1.0f;
  }
  maps.at(lobe_x, 0, 0) = maps.at(lobe_y, 0, 0) = ward_limits::min_lobe;
  maps.at(fresnel_f0, 0, 0) = ward_limits::min_f0;
  maps.at(normal_x, 0, 0) = maps.at(normal_y, 0, 0) = maps.at(rotation, 0, 0) = 0.0f;
  const float z = 4e-6f;
  capture cap;
  capture_image im;
  im.light = {2.0f, 0.0f, z};
  im.camera = {-2.0f, 0.0f, z};
  cap.images.push_back(im);
  const double r2 = 4.0 + double(z) * z, cos_l = double(z) / std::sqrt(r2);
  const double bound = double(ward_limits::max_lobe) * cos_l / r2;  // a'_s = 1, intensity 1
  for (const auto& images : {render(maps, cap), render<all_features, float>(maps, cap)})
    for (int c = 0; c < 3; ++c) CHECK(double(images[0].at(c, 0, 0)) == doctest::Approx(bound).epsilon(1e-4));
  CHECK(double(reference_radiance<double>(maps, im, 0, 0, all_features)[0]) == doctest::Approx(bound).epsilon(1e-4));
  // The gradient in the lobe's shape is zero at the bound; the albedo's is not.
  const loss_targets targets = make_loss_targets({image(1, 1, 3)});
  material_maps g(1, 1);
  loss_and_gradient(maps, cap, targets, &g);
  for (int k : {lobe_x, lobe_y, fresnel_f0, rotation}) CHECK(g.at(k, 0, 0) == 0.0f);
  CHECK(g.at(specular_r, 0, 0) > 0.0f);
}
