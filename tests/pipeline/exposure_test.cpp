#include <doctest/doctest.h>

#include <cmath>

#include "../render/render_reference.hpp"
#include "anisocap/render/evaluate.hpp"
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
