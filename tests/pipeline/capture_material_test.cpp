// pipeline/capture_material.hpp and pipeline/networks.hpp: the entry point decides the stages and
// schedules as documented, returns canonical maps, and the weights are found (or refused) as the
// search order says.
#include <doctest/doctest.h>

#include <cstdlib>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "../data/test_folder.hpp"
#include "../render/render_reference.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "support/two_threads.hpp"

using namespace anisocap;
using namespace anisocap::testing;
namespace fs = std::filesystem;

namespace {

/// Sets an environment variable for a scope, restoring the old value after.
class scoped_env {
 public:
  scoped_env(const char* name, const std::string& value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old;
    setenv(name, value.c_str(), 1);
  }
  ~scoped_env() {
    if (old_) setenv(name_, old_->c_str(), 1);
    else unsetenv(name_);
  }

 private:
  const char* name_;
  std::optional<std::string> old_;
};

const fs::path shipped = fs::path(ANISOCAP_SOURCE_DIR) / "models";

/// A folder with `estimator` and `autoencoder` as its compact weights.
fs::path weights_folder(const fs::path& root, const fs::path& estimator, const fs::path& autoencoder) {
  fs::create_directories(root / "compact");
  fs::copy_file(estimator, root / "compact/estimator.safetensors");
  fs::copy_file(autoencoder, root / "compact/autoencoder.safetensors");
  return root;
}

}  // namespace

TEST_CASE("capture_options: the named schedules and the validation of every field") {
  const capture_options fast = capture_options::schedule("fast");
  CHECK(fast.finetune.steps == 800);
  CHECK(fast.refine.steps == 500);
  CHECK(fast.neighbour_restarts == std::vector<int>{8});
  CHECK(fast.refine_alone.steps == 1000);
  CHECK(fast.neighbour_restarts_alone.empty());
  CHECK(fast.second_run.residual);
  CHECK(fast.second_run.second_prior);
  CHECK(capture_options::schedule("thorough").finetune.steps == 2000);
  CHECK(capture_options::schedule("thorough").refine.steps == 1000);
  // auto: the fast schedule's steps at least, the thorough schedule's at most, early stopping between.
  const capture_options automatic = capture_options::schedule("auto");
  CHECK(automatic.finetune.min_steps == capture_options::fast().finetune.steps);
  CHECK(automatic.finetune.steps == capture_options::thorough().finetune.steps);
  CHECK(automatic.finetune.min_improvement > 0);
  CHECK(automatic.refine.min_steps == capture_options::fast().refine.steps);
  CHECK(automatic.refine.steps == capture_options::thorough().refine.steps);
  CHECK(automatic.refine.min_relative_improvement > 0);
  CHECK(automatic.finetune.learning_rate == capture_options::fast().finetune.learning_rate);
  const capture_options paper = capture_options::schedule("paper");
  CHECK(paper.finetune.steps == 5000);
  CHECK(paper.neighbour_restarts.empty());
  CHECK_THROWS_WITH_AS(capture_options::schedule("slow"), doctest::Contains("unknown schedule 'slow'"), std::invalid_argument);
  // apply_schedule takes what a schedule sets and keeps the rest.
  capture_options applied;
  applied.estimate.window = 128;
  applied.refine_alone.steps = 77;
  applied.apply_schedule("paper");
  CHECK(applied.finetune.steps == 5000);
  CHECK(applied.refine.steps == paper.refine.steps);
  CHECK(applied.refine.learning_rate == paper.refine.learning_rate);
  CHECK(applied.neighbour_restarts.empty());
  CHECK(applied.estimate.window == 128);
  CHECK(applied.refine_alone.steps == 77);
  CHECK_THROWS_AS(applied.apply_schedule("slow"), std::invalid_argument);
  capture_options o;
  CHECK_NOTHROW(o.validate());
  o.neighbour_restarts_alone = {0};
  CHECK_THROWS_AS(o.validate(), std::invalid_argument);
  o = {};
  o.second_run.above = -1;
  CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("second_run.above"), std::invalid_argument);
  o = {};
  o.second_run.residual_ratio = std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("capture_options::second_run.residual_ratio must be a finite number >= 0"),
                       std::invalid_argument);
  o = {};
  o.kernel.prior_f0 = 1.5f;
  CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("capture_options::kernel.prior_f0 must be in [0, 1]"), std::invalid_argument);
  o = {};
  o.kernel.auto_tolerance = -1e-3;
  CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("capture_options::kernel.auto_tolerance"), std::invalid_argument);
  o = {};
  o.kernel.prior_f0 = 1.0f;  // a metal's prior: allowed
  o.kernel.auto_tolerance = 0;
  CHECK_NOTHROW(o.validate());
  // The visitors list every field, by the names the messages use.
  std::vector<std::string> names;
  second_run_options::visit_fields(o.second_run, [&](const char* name, const auto&) { names.emplace_back(name); });
  kernel_options::visit_fields(o.kernel, [&](const char* name, const auto&) { names.emplace_back(name); });
  CHECK(names == std::vector<std::string>{"residual", "second_prior", "above", "residual_ratio", "features", "auto_tolerance", "prior_f0"});
  o = {};
  o.refine_alone.steps = -1;
  CHECK_THROWS_AS(o.validate(), std::invalid_argument);
}

TEST_CASE("capture_material without networks: the first guess and the refine alone, with its own schedule, canonical maps") {
  const two_threads threads;
  const capture cap = random_capture(5, 6);
  const std::vector<image> photos = render(random_maps(24, 16, 4), cap);
  capture_options o;
  o.refine_alone.steps = 12;
  o.refine.steps = 3;  // the refine after the network stages: not used here
  const capture_result r = capture_material(cap, photos, networks{}, o);
  CHECK_FALSE(r.networks_ran);
  CHECK_FALSE(r.choice);
  REQUIRE(r.stages.size() == 2);
  CHECK(r.stages[0].name == "first_guess");
  CHECK(r.stages[1].name == "refine");
  CHECK(r.stages[1].steps == 12);
  // The same as one run of exactly those stages, brought into canonical form.
  capture_options alone = o;
  alone.stages = {false, false, false, true};
  alone.refine = o.refine_alone;
  alone.neighbour_restarts = o.neighbour_restarts_alone;
  capture_result once = capture_once(cap, photos, alone);
  canonicalise(once.maps);
  CHECK(r.loss == once.loss);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < r.maps.texel_count(); ++i) REQUIRE(r.maps.plane(k)[i] == once.maps.plane(k)[i]);
  for (std::size_t i = 0; i < r.maps.texel_count(); ++i)
    CHECK(is_canonical(r.maps.plane(lobe_x)[i], r.maps.plane(lobe_y)[i], r.maps.plane(rotation)[i]));
  // Start maps of the wrong size are refused before any work.
  const material_maps wrong(8, 8);
  CHECK_THROWS_WITH_AS(capture_material(cap, photos, networks{}, o, {}, &wrong), doctest::Contains("8x8"), std::invalid_argument);
}

TEST_CASE("load_networks: the search order, the second prior, and clear refusals") {
  test_folder t;
  // ANISOCAP_MODELS comes first in the search.
  {
    const scoped_env env("ANISOCAP_MODELS", shipped.string());
    CHECK(models_search_path().front() == shipped);
    CHECK(find_models_folder() == shipped);
    const networks n = load_networks();
    CHECK_FALSE(n.empty());
    CHECK(n.has_second_prior());
    CHECK(n.first()->folder == shipped);
    CHECK(n.first()->estimator_preset == std::string(estimator_compact_orientation_doubled_angle::name));
    CHECK(n.first()->autoencoder_preset == std::string(autoencoder_compact::name));
    CHECK(n.second()->folder == shipped / "also");
    CHECK(n.second()->autoencoder_preset == std::string(autoencoder_compact_fine_512::name));
    CHECK(n.describe().find(shipped.string()) != std::string::npos);
    // No second prior when asked for none.
    CHECK_FALSE(load_networks({}, {"compact", fs::path()}).has_second_prior());
  }
  // A folder without weights, and a second-prior folder without its auto-encoder: refused, named.
  CHECK_THROWS_WITH_AS(load_networks(t.path() / "none"), doctest::Contains((t.path() / "none").string().c_str()), std::invalid_argument);
  fs::create_directories(t.path() / "empty");
  CHECK_THROWS_WITH_AS(load_networks(shipped, {"compact", t.path() / "empty"}), doctest::Contains("no second prior there"),
                       std::invalid_argument);
  CHECK_THROWS_WITH_AS(load_networks(shipped, {"wide", std::nullopt}), doctest::Contains("compact or paper"), std::invalid_argument);
  // A file of a preset the capture does not run is refused with its name and the presets it runs.
  const fs::path swapped = weights_folder(t.path() / "swapped", shipped / "also/compact/autoencoder.safetensors",
                                          shipped / "compact/autoencoder.safetensors");
  CHECK_THROWS_WITH_AS(load_networks(swapped), doctest::Contains("compact-fine-512"), std::invalid_argument);
  // Without a second prior of its own, a folder has none.
  const fs::path plain = weights_folder(t.path() / "plain", shipped / "compact/estimator.safetensors",
                                        shipped / "compact/autoencoder.safetensors");
  const networks n = load_networks(plain);
  CHECK_FALSE(n.has_second_prior());
  CHECK(n.without_second_prior().first() == n.first());
}
