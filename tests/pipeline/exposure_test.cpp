#include <doctest/doctest.h>

#include <cmath>

#include "../render/render_reference.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("exposure_scale is the reciprocal of the median centre irradiance and scales inversely") {
  capture cap;
  // Lights straight above the centre at heights 1, 2, 4 with intensity pi h^2: irradiance 1 each.
  for (float hgt : {1.0f, 2.0f, 4.0f}) {
    capture_image im;
    im.light = {0, 0, hgt};
    const float i = std::numbers::pi_v<float> * hgt * hgt;
    im.intensity = {i, i, i};
    cap.images.push_back(im);
  }
  CHECK(exposure_scale(cap) == doctest::Approx(1.0).epsilon(1e-6));
  capture dim = cap;
  for (auto& im : dim.images)
    for (float& v : im.intensity) v *= 1e-4f;
  CHECK(exposure_scale(dim) == doctest::Approx(1e4).epsilon(1e-5));
  // Only lights above the material count; none above is an error, as is a bad intensity.
  capture below = cap;
  for (auto& im : below.images) im.light[2] = -1;
  CHECK_THROWS_AS(exposure_scale(below), std::invalid_argument);
  capture bad = cap;
  bad.images[1].intensity[0] = std::nanf("");
  CHECK_THROWS_WITH_AS(exposure_scale(bad), doctest::Contains("intensity"), std::invalid_argument);
}

TEST_CASE("a capture scaled by 1e-4 or 1e4 refines to the same maps after exposure normalisation") {
  const int w = 32, h = 24;
  const material_maps truth = random_maps(w, h, 71);
  const capture cap = set_alpha(12, 5, w, h);
  const std::vector<image> photos = render(truth, cap);
  refine_options options;
  options.steps = 150;
  options.learning_rate = 0.05f;
  auto run = [&](float factor) {
    capture c = cap;
    std::vector<image> p = photos;
    apply_exposure(c, p, factor);                    // the user's units
    apply_exposure(c, p, exposure_scale(c));         // what the pipeline does first
    material_maps maps = initial_guess(c, p);
    refine(maps, c, make_loss_targets(p), options);
    return maps;
  };
  // The optimisation itself is chaotic at the level of float rounding (the L1 loss's sign flips
  // where a rendering crosses its target), so individual texels may take other paths: compare the
  // maps' errors against the truth, which must match, not the maps texel by texel.
  const parameter_errors reference = compare_maps(run(1.0f), truth);
  auto close = [](double a, double b) { return std::abs(a - b) <= 0.15 * std::max(a, b) + 1e-4; };
  for (float factor : {1e-4f, 1e4f}) {
    const parameter_errors e = compare_maps(run(factor), truth);
    INFO("factor " << factor << ": a_d " << e.diffuse << " vs " << reference.diffuse << ", a_s " << e.specular << " vs "
                   << reference.specular << ", n " << e.normal << " vs " << reference.normal << ", sigma " << e.lobes << " vs "
                   << reference.lobes << ", F0 " << e.fresnel << " vs " << reference.fresnel);
    CHECK(close(e.diffuse, reference.diffuse));
    CHECK(close(e.specular, reference.specular));
    CHECK(close(e.normal, reference.normal));
    CHECK(close(e.lobes, reference.lobes));
    CHECK(close(e.fresnel, reference.fresnel));
  }
}

TEST_CASE("floors are in the files' values: the capture scales them by each image's exposure factor and the normalisation") {
  const int w = 16, h = 12;
  const material_maps truth = random_maps(w, h, 73), start = random_maps(w, h, 74);
  capture cap = set_alpha(8, 6, w, h);
  const std::vector<image> files = render(truth, cap);  // the files' values
  std::vector<image> photos = files;                    // as load_capture_photos hands them over
  for (std::size_t k = 0; k < cap.images.size(); ++k) {
    cap.images[k].exposure = k % 2 ? 2.0f : 0.5f;
    cap.images[k].floor = 0.02f * float(k + 1);
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < photos[k].pixel_count(); ++i) photos[k].plane(c)[i] *= cap.images[k].exposure;
  }
  capture_options o;
  o.stages = pipeline_stages::parse("refine");
  o.refine.steps = 0;
  o.kernel = kernel_options::parse("full");
  no_networks none;
  const capture_result r = capture_once(cap, photos, none, none, o, &start);
  // What the pipeline must have fitted: the normalised capture with floors f x exposure x scale.
  capture c = cap;
  std::vector<image> p = photos;
  const double scale = exposure_scale(c);
  apply_exposure(c, p, scale);
  auto loss_with = [&](auto floor_of) {
    std::vector<float> floors;
    for (const capture_image& im : cap.images) floors.push_back(floor_of(im));
    return loss_and_gradient<all_features>(start, c, make_loss_targets(p, {}, floors), nullptr);
  };
  const double expected = loss_with([&](const capture_image& im) { return float(im.floor * im.exposure * scale); });
  CHECK(r.stages.front().loss == doctest::Approx(expected).epsilon(1e-6));
  // Floors taken as they stand in capture.json, or without the normalisation, are another loss.
  CHECK(std::abs(loss_with([&](const capture_image& im) { return float(im.floor * scale); }) - expected) > 1e-4 * expected);
  CHECK(std::abs(loss_with([&](const capture_image& im) { return float(im.floor * im.exposure); }) - expected) > 1e-4 * expected);
  CHECK(std::abs(loss_with([](const capture_image&) { return 0.0f; }) - expected) > 1e-4 * expected);
}
