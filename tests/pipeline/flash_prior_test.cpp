// What a capture writes where the photographs do not determine F0 (a phone's flash: every photo
// sees the Fresnel factor F / F0 = 1): the networks' estimate, the start maps' F0 or a documented
// prior, never the reduced kernel's placeholder F0 = 1; and where they do, the fitted F0.
#include <doctest/doctest.h>

#include <algorithm>
#include <filesystem>
#include <numbers>

#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"

using namespace anisocap;

namespace {

/// `count` photographs with the light a phone's flash would be: beside the lens, 8% of the sample's
/// size away, the camera anywhere a configuration puts it.
capture flash_capture(int count, int size, std::uint64_t seed) {
  random_generator rng(seed);
  return flash_set(count, rng, size, size, {0.08f, 0.03f, 0.0f});
}

/// Camera and lamp 17 degrees above the sample's plane on opposite sides (where a fabric shows
/// its sheen), along three azimuths.
capture grazing_views() {
  capture views;
  const double elevation = 17 * std::numbers::pi / 180;
  for (double azimuth : {0.0, 0.25 * std::numbers::pi, 0.5 * std::numbers::pi})
    views.images.push_back(mirror_configuration_at(
        {0, 0, 0}, {std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth), std::sin(elevation)}, 2.0, 2.0));
  return views;
}

material_maps satin(int size) {
  procedural_options po;
  po.kind = material_kind::satin;
  return generate_material(100, size, size, po);
}

}  // namespace

TEST_CASE("a flash capture without networks writes the prior F0, with start maps theirs, never the placeholder") {
  const int n = 32;
  const material_maps truth = satin(n);
  const capture cap = flash_capture(6, n, 7);
  const std::vector<image> photos = render(truth, cap);
  capture_options o;
  o.refine_alone.steps = 20;
  o.normalise_exposure = false;  // the loss below is then in the photographs' units
  const capture_result alone = capture_material(cap, photos, networks{}, o);
  CHECK_FALSE(alone.features.fresnel);
  CHECK(alone.f0_source == "prior");
  for (std::size_t i = 0; i < alone.maps.texel_count(); ++i) REQUIRE(alone.maps.plane(fresnel_f0)[i] == o.kernel.prior_f0);
  // The maps as written render the photographs as the reduced kernel fitted them: F0 is invisible there.
  const double reduced = with_features(alone.features, [&]<brdf_features F>() {
    return loss_and_gradient<F>(alone.maps, cap, make_loss_targets(photos), nullptr);
  });
  CHECK(alone.loss == doctest::Approx(reduced).epsilon(1e-4));

  o.kernel.prior_f0 = 0.1f;  // the prior is the caller's to set
  CHECK(capture_material(cap, photos, networks{}, o).maps.plane(fresnel_f0)[0] == 0.1f);

  // Start maps stand where an estimate would: their F0 is kept, texel by texel.
  material_maps start = truth;
  for (std::size_t i = 0; i < start.texel_count(); ++i) start.plane(fresnel_f0)[i] = 0.02f + 0.5f * float(i % 7) / 7;
  const capture_result from_start = capture_material(cap, photos, networks{}, o, {}, &start);
  CHECK(from_start.f0_source == "estimate");
  for (std::size_t i = 0; i < start.texel_count(); ++i) REQUIRE(from_start.maps.plane(fresnel_f0)[i] == start.plane(fresnel_f0)[i]);

  // A Fresnel (grazing) configuration among the photographs makes F0 theirs to fit.
  capture with_grazing = cap;
  random_generator rng(3);
  with_grazing.images.push_back(fresnel_configuration(rng, n, n));
  const capture_result fitted = capture_material(with_grazing, render(truth, with_grazing), networks{}, o);
  CHECK(fitted.features.fresnel);
  CHECK(fitted.f0_source == "photographs");
  CHECK(std::any_of(fitted.maps.plane(fresnel_f0), fitted.maps.plane(fresnel_f0) + fitted.maps.texel_count(),
                    [&](float f) { return f != o.kernel.prior_f0; }));
}

TEST_CASE("a flash capture with the shipped networks keeps the estimate's F0: grazing views within 1.3x of the true F0's") {
  const int n = 128;
  const material_maps truth = satin(n);
  const capture cap = flash_capture(10, n, 7);
  const std::vector<image> photos = render(truth, cap);
  const networks nets = load_networks(std::filesystem::path(ANISOCAP_SOURCE_DIR) / "models");
  capture_options o;  // the default pipeline, shortened: what is kept does not depend on the step counts
  o.finetune.steps = 100;
  o.finetune.warmup = 20;
  o.refine.steps = 100;
  o.neighbour_restarts.clear();
  o.second_run.residual = o.second_run.second_prior = false;
  const capture_result r = capture_material(cap, photos, nets, o);
  CHECK_FALSE(r.features.fresnel);
  CHECK(r.f0_source == "estimate");
  const float* f0 = r.maps.plane(fresnel_f0);
  const auto [lowest, highest] = std::minmax_element(f0, f0 + r.maps.texel_count());
  CHECK(*highest < 1.0f);      // not the placeholder
  CHECK(*lowest < *highest);   // an estimate per texel, not a constant
  // The error the F0 map carries into a renderer's grazing view, against the same maps with the true F0.
  material_maps with_true_f0 = r.maps;
  std::copy(truth.plane(fresnel_f0), truth.plane(fresnel_f0) + truth.texel_count(), with_true_f0.plane(fresnel_f0));
  const capture views = grazing_views();
  const double written = novel_view_error(r.maps, truth, views), ideal = novel_view_error(with_true_f0, truth, views);
  INFO("grazing-view error: written maps " << written << ", with the true F0 " << ideal);
  CHECK(written <= 1.3 * ideal);
}
