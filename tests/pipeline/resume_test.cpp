// Check-points of the capture pipeline: a fine-tune stopped after a divergence-guard restart, or
// killed between its check-point's two renames, resumes to exactly the uninterrupted run's
// decoder, and a check-point is only resumed by the capture and options that wrote it.
#include <doctest/doctest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "../networks/tiny_presets.hpp"
#include "../render/render_reference.hpp"
#include "../support/capture_options.hpp"
#include "anisocap/pipeline/capture.hpp"

using namespace anisocap;
using namespace anisocap::testing;
namespace fs = std::filesystem;

namespace {

fs::path fresh_folder(const char* name) {
  const fs::path p = fs::temp_directory_path() / (std::string("anisocap_") + name + "_" + std::to_string(std::random_device{}()));
  fs::remove_all(p);
  return p;
}

/// Options that run the fine-tune alone for `steps` steps, check-pointing into a fresh folder only
/// where stop_after asks.
capture_options finetune_alone(int steps, const char* folder) {
  capture_options o = measured_capture_options();
  o.stages.estimate = false;
  o.stages.refine = false;
  o.finetune.steps = steps;
  o.checkpoint.folder = fresh_folder(folder);
  o.checkpoint.seconds = 1e9;
  return o;
}

std::vector<float> decoder_weights(auto_encoder<autoencoder_tiny>& ae) {
  std::vector<float> w;
  ae.for_each_decoder_parameter([&](nn::parameter& p) { w.insert(w.end(), p.value.begin(), p.value.end()); });
  return w;
}

}  // namespace

TEST_CASE("fine-tune: stopped after a divergence-guard restart and resumed, it ends bit for bit where an uninterrupted run ends") {
  const material_maps truth = random_maps(64, 64, 3);
  const capture cap = random_capture(5, 4);
  const std::vector<image> photos = render(truth, cap);
  estimation_network<estimator_tiny> estimator(1);
  for (const int crop : {0, 1}) {  // whole tiles (the guard checks each step) and crops (5-step means)
    CAPTURE(crop);
    capture_options o = measured_capture_options();
    o.stages.estimate = false;
    o.stages.refine = false;
    o.finetune.steps = 40;
    o.finetune.crop.cells = crop;
    o.finetune.learning_rate = 0.5f;  // far too large: the guard goes back and halves the rate
    o.finetune.guard.every = 5;
    o.finetune.warmup = 6;  // the schedule's position matters (Adam's lags the loop's after a restart)
    o.finetune.half_life = 15;
    o.checkpoint.folder = fresh_folder("guard_resume");
    o.checkpoint.seconds = 1e9;  // check-points only where stop_after asks

    auto_encoder<autoencoder_tiny> straight(2);
    const capture_result a = capture_once(cap, photos, estimator, straight, o);
    REQUIRE(a.stages[2].restarts > 1);
    REQUIRE(a.stages[2].steps == 40);
    const std::vector<float> expected = decoder_weights(straight);

    // Stops before, between and after restarts, inside and at the end of the guard's windows.
    int stopped_after_restart = 0;
    for (const int stop : {3, 9, 12, 17, 23, 26, 31, 35}) {
      CAPTURE(stop);
      o.finetune.stop_after = stop;
      o.checkpoint.resume = false;
      auto_encoder<autoencoder_tiny> first(2);
      const capture_result stopped = capture_once(cap, photos, estimator, first, o);
      REQUIRE(stopped.stopped);
      REQUIRE(stopped.stages[2].restarts <= a.stages[2].restarts);
      stopped_after_restart += stopped.stages[2].restarts > 0 && stopped.stages[2].restarts < a.stages[2].restarts;

      // A kill while the check-point was written leaves half-written files under their .next names.
      const fs::path torn = o.checkpoint.folder / "finetune" / "state.next.safetensors";
      std::ofstream(torn) << "half a file";
      o.finetune.stop_after = -1;
      o.checkpoint.resume = true;
      auto_encoder<autoencoder_tiny> second(2);  // a new process: fresh weights, everything else from the check-point
      const capture_result b = capture_once(cap, photos, estimator, second, o);
      CHECK_FALSE(fs::exists(torn));  // the resume drops it
      CHECK(b.stages[2].resumed);
      CHECK(b.stages[2].steps == 40 - stop);
      CHECK(b.stages[2].restarts == a.stages[2].restarts);
      CHECK(decoder_weights(second) == expected);
      CHECK(b.stages[2].loss == a.stages[2].loss);
    }
    CHECK(stopped_after_restart > 0);  // some stop came between two restarts
    fs::remove_all(o.checkpoint.folder);
  }
}

TEST_CASE("fine-tune: a kill between the check-point's two renames is completed on resume, to the uninterrupted run's decoder") {
  capture_options o = finetune_alone(12, "torn_rename");
  const capture cap = random_capture(4, 5);
  const std::vector<image> photos = render(random_maps(32, 32, 4), cap);
  estimation_network<estimator_tiny> estimator(1);
  auto_encoder<autoencoder_tiny> straight(2);
  const capture_result a = capture_once(cap, photos, estimator, straight, o);

  // The state of an earlier save (step 3), then a save at step 7 killed after its first rename:
  // the decoder of step 7 in place, the state of step 3 beside it, step 7's under its .next name.
  const fs::path dir = o.checkpoint.folder / "finetune";
  auto stop_at = [&](int step) {
    o.finetune.stop_after = step;
    o.checkpoint.resume = false;
    auto_encoder<autoencoder_tiny> ae(2);
    REQUIRE(capture_once(cap, photos, estimator, ae, o).stopped);
  };
  stop_at(3);
  const fs::path old_state = o.checkpoint.folder.string() + "_state3";
  fs::copy_file(dir / "state.safetensors", old_state, fs::copy_options::overwrite_existing);
  stop_at(7);
  fs::rename(dir / "state.safetensors", dir / "state.next.safetensors");
  fs::copy_file(old_state, dir / "state.safetensors");

  o.finetune.stop_after = -1;
  o.checkpoint.resume = true;
  auto_encoder<autoencoder_tiny> resumed(2);
  const capture_result b = capture_once(cap, photos, estimator, resumed, o);
  CHECK(b.stages[2].resumed);
  CHECK(b.stages[2].steps == 12 - 7);
  CHECK(decoder_weights(resumed) == decoder_weights(straight));
  CHECK(b.stages[2].loss == a.stages[2].loss);
  CHECK_FALSE(fs::exists(dir / "state.next.safetensors"));

  // A pair whose steps differ with no save to complete is still refused, naming the folder.
  stop_at(7);
  fs::copy_file(old_state, dir / "state.safetensors", fs::copy_options::overwrite_existing);
  o.finetune.stop_after = -1;
  o.checkpoint.resume = true;
  auto_encoder<autoencoder_tiny> refused(2);
  CHECK_THROWS_WITH_AS(capture_once(cap, photos, estimator, refused, o), doctest::Contains("files are of different steps"),
                       std::runtime_error);
  fs::remove_all(o.checkpoint.folder);
  fs::remove(old_state);
}

TEST_CASE("check-points: resuming with other photographs, configurations or options is refused, naming what differs") {
  const material_maps truth = random_maps(32, 32, 5);
  const capture cap = random_capture(4, 6);
  const std::vector<image> photos = render(truth, cap);
  estimation_network<estimator_tiny> estimator(1);
  capture_options o = finetune_alone(6, "fingerprint");
  o.finetune.stop_after = 3;
  {
    auto_encoder<autoencoder_tiny> ae(2);
    REQUIRE(capture_once(cap, photos, estimator, ae, o).stopped);
  }
  o.finetune.stop_after = -1;
  o.checkpoint.resume = true;
  auto resume_error = [&](const capture& c, const std::vector<image>& p, const capture_options& opts) -> std::string {
    auto_encoder<autoencoder_tiny> ae(2);
    try {
      capture_once(c, p, estimator, ae, opts);
    } catch (const std::runtime_error& e) {
      return e.what();
    }
    return "";
  };
  std::vector<image> brighter = photos;
  brighter[2].at(0, 3, 4) *= 1.01f;
  const std::string photo_error = resume_error(cap, brighter, o);
  CHECK(photo_error.find("photographs") != std::string::npos);
  CHECK(photo_error.find(o.checkpoint.folder.string()) != std::string::npos);
  CHECK(photo_error.find("capture (") == std::string::npos);  // only what differs is named

  capture moved = cap;
  moved.images[1].light[0] += 0.01f;
  CHECK(resume_error(moved, photos, o).find("capture (") != std::string::npos);
  capture floored = cap;  // another loss floor is another image loss
  floored.images[3].floor = 0.002f;
  CHECK(resume_error(floored, photos, o).find("capture (") != std::string::npos);

  capture_options faster = o;
  faster.finetune.learning_rate *= 2;
  const std::string rate_error = resume_error(cap, photos, faster);
  CHECK(rate_error.find("finetune.learning_rate") != std::string::npos);
  CHECK(rate_error.find("photographs") == std::string::npos);

  capture_options other_kernel = o;
  other_kernel.kernel = kernel_options::parse("isotropic");
  CHECK(resume_error(cap, photos, other_kernel).find("kernel.features") != std::string::npos);

  // Other weights are another capture too.
  {
    auto_encoder<autoencoder_tiny> other(3);
    CHECK_THROWS_WITH_AS(capture_once(cap, photos, estimator, other, o), doctest::Contains("autoencoder_weights"), std::runtime_error);
  }
  // More steps are the same capture continued; the same inputs resume.
  capture_options longer = o;
  longer.finetune.steps = 9;
  {
    auto_encoder<autoencoder_tiny> ae(2);
    const capture_result r = capture_once(cap, photos, estimator, ae, longer);
    CHECK(r.stages[2].resumed);
    CHECK(r.stages[2].steps == 6);
  }
  // A folder with stages but no fingerprint is refused too.
  fs::remove(o.checkpoint.folder / "fingerprint.txt");
  CHECK(resume_error(cap, photos, o).find("fingerprint") != std::string::npos);
  fs::remove_all(o.checkpoint.folder);
}

TEST_CASE("check-points: a file's step is read from its header, and a file cut short has none") {
  const fs::path file = fresh_folder("checkpoint_step");
  nn::safetensors_file f;
  const std::vector<float> values(64, 1.5f);
  f.add<float>("w", {64}, values.data(), values.size());
  f.metadata.emplace_back("step", "7");
  nn::write_safetensors(file, f);
  CHECK(finetune_detail::checkpoint_step(file) == "7");
  fs::resize_file(file, fs::file_size(file) - 4);  // the data cut short: the header's offsets run past the end
  CHECK(finetune_detail::checkpoint_step(file) == "");
  CHECK(finetune_detail::checkpoint_step(file.string() + ".absent") == "");
  f.metadata.clear();
  nn::write_safetensors(file, f);
  CHECK(finetune_detail::checkpoint_step(file) == "");
  fs::remove(file);
}
