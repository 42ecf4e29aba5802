// The four-stage pipeline on tiny networks (untrained: what is tested is the plumbing, that each
// stage runs at any size, lowers or keeps the loss where it optimises, and resumes).
#include <doctest/doctest.h>

#include <filesystem>
#include <random>

#include "../networks/tiny_presets.hpp"
#include "../render/render_reference.hpp"
#include "anisocap/pipeline/capture_pipeline.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {
struct scene {
  material_maps truth;
  capture cap;
  std::vector<image> photos;
  scene(int w, int h) : truth(random_maps(w, h, 3)), cap(random_capture(5, 4)), photos(render(truth, cap)) {}
};
}  // namespace

TEST_CASE("pipeline: every stage runs on a non-square size that is not a multiple of 32, maps stay valid") {
  const scene s(45, 37);
  EstimationNet<estimator_tiny> estimator(1);
  AutoEncoder<autoencoder_tiny> autoencoder(2);
  pipeline_options o;
  o.window = 64;
  o.stride = 16;
  o.finetune_steps = 12;
  o.refine.steps = 10;
  int estimate_reports = 0;
  o.progress_every = 4;
  o.progress = [&](const std::string& stage, const optimisation_progress&) { estimate_reports += stage == "estimate"; };
  const pipeline_result r = run_pipeline(s.cap, s.photos, estimator, autoencoder, o);
  REQUIRE(r.stages.size() == 4);
  CHECK(r.stages[0].name == "estimate");
  CHECK(r.stages[2].name == "finetune");
  CHECK(r.stages[2].steps == 12);
  CHECK(estimate_reports == int(window_starts(45, 64, 16).size() * window_starts(37, 64, 16).size()));
  // Fine-tuning and refining optimise the image loss: neither ends above where it started.
  CHECK(r.stages[2].loss <= r.stages[1].loss * 1.001);
  CHECK(r.stages[3].loss <= r.stages[2].loss * 1.001);
  CHECK(r.maps.width() == 45);
  CHECK(r.maps.height() == 37);
  for (std::size_t i = 0; i < r.maps.texel_count(); ++i) {
    REQUIRE(std::isfinite(r.maps.plane(diffuse_r)[i]));
    REQUIRE(r.maps.plane(lobe_x)[i] > 0.0f);
    REQUIRE(r.maps.plane(fresnel_f0)[i] >= 0.0f);
    REQUIRE(r.maps.plane(fresnel_f0)[i] <= 1.0f);
  }
}

TEST_CASE("pipeline: the decoder fine-tune touches only the decoder and resumes from its check-point") {
  const scene s(32, 32);
  const auto dir = std::filesystem::temp_directory_path() / ("anisocap_pipeline_" + std::to_string(std::random_device{}()));
  pipeline_options o;
  o.window = 64;
  o.stages.estimate = false;  // start from the first guess: the networks' estimate is not needed here
  o.stages.refine = false;
  o.finetune_steps = 8;
  o.checkpoint_dir = dir;
  o.checkpoint_seconds = 0;  // check-point after every step

  // Uninterrupted: 8 steps.
  EstimationNet<estimator_tiny> estimator(1);
  AutoEncoder<autoencoder_tiny> straight(2);
  const auto encoder_before = straight.enc0.weight.value;
  const pipeline_result a = run_pipeline(s.cap, s.photos, estimator, straight, o);
  for (std::size_t i = 0; i < encoder_before.size(); ++i) REQUIRE(straight.enc0.weight.value[i] == encoder_before[i]);

  // Interrupted after 5 steps, then resumed with a fresh network (as a new process would be).
  std::filesystem::remove_all(dir);
  AutoEncoder<autoencoder_tiny> first(2);
  o.finetune_steps = 5;
  run_pipeline(s.cap, s.photos, estimator, first, o);
  AutoEncoder<autoencoder_tiny> second(2);
  o.finetune_steps = 8;
  o.resume = true;
  const pipeline_result b = run_pipeline(s.cap, s.photos, estimator, second, o);
  CHECK(b.stages[2].resumed);
  CHECK(b.stages[2].steps == 3);
  for (std::size_t i = 0; i < straight.dec4.weight.value.size(); ++i)
    REQUIRE(second.dec4.weight.value[i] == doctest::Approx(straight.dec4.weight.value[i]).epsilon(1e-5));
  CHECK(b.stages[2].loss == doctest::Approx(a.stages[2].loss).epsilon(1e-4));
  std::filesystem::remove_all(dir);
}

TEST_CASE("pipeline stages parse from text and reject nonsense") {
  const pipeline_stages s = pipeline_stages::parse("estimate,refine");
  CHECK(s.estimate);
  CHECK_FALSE(s.encode);
  CHECK(s.refine);
  CHECK(pipeline_stages::parse("all").finetune);
  CHECK_THROWS_WITH_AS(pipeline_stages::parse("estimate,polish"), doctest::Contains("polish"), std::invalid_argument);
  CHECK_THROWS_AS(pipeline_stages::parse("finetune"), std::invalid_argument);
}
