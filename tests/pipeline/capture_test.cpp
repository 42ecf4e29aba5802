// The four-stage pipeline on tiny networks (untrained: what is tested is the plumbing, that each
// stage runs at any size, lowers or keeps the loss where it optimises, and resumes).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <mutex>
#include <random>

#include "../networks/tiny_presets.hpp"
#include "../render/render_reference.hpp"
#include "../support/capture_options.hpp"
#include "../support/loopback_communicator.hpp"
#include "anisocap/pipeline/capture.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {
struct scene {
  material_maps truth;
  capture cap;
  std::vector<image> photos;
  scene(int w, int h) : truth(random_maps(w, h, 3)), cap(random_capture(5, 4)), photos(render(truth, cap)) {}
};

/// Fine-tunes `s` with `o` (which names a check-point folder) for 8 steps uninterrupted, then again
/// stopped after 5 steps and resumed with fresh networks, as a new process would be; checks that
/// the encoder never moves and that the resumed run does the 3 remaining steps and ends with the
/// uninterrupted run's decoder and loss. `o.finetune.observer` sees the uninterrupted run only.
void check_fine_tune_resumes(const scene& s, capture_options o) {
  REQUIRE_FALSE(o.checkpoint.folder.empty());
  o.checkpoint.seconds = 0;  // check-point after every step
  o.finetune.steps = 8;
  estimation_network<estimator_tiny> estimator(1);
  auto_encoder<autoencoder_tiny> straight(2);
  const auto encoder_before = straight.enc<0>().weight.value;
  const capture_result a = capture_once(s.cap, s.photos, estimator, straight, o);
  for (std::size_t i = 0; i < encoder_before.size(); ++i) REQUIRE(straight.enc<0>().weight.value[i] == encoder_before[i]);
  o.finetune.observer = nullptr;

  std::filesystem::remove_all(o.checkpoint.folder);
  auto_encoder<autoencoder_tiny> first(2);
  o.finetune.steps = 5;
  capture_once(s.cap, s.photos, estimator, first, o);
  auto_encoder<autoencoder_tiny> second(2);
  o.finetune.steps = 8;
  o.checkpoint.resume = true;
  const capture_result b = capture_once(s.cap, s.photos, estimator, second, o);
  CHECK(b.stages[2].resumed);
  CHECK(b.stages[2].steps == 3);
  for (std::size_t i = 0; i < straight.dec<4>().weight.value.size(); ++i)
    REQUIRE(second.dec<4>().weight.value[i] == doctest::Approx(straight.dec<4>().weight.value[i]).epsilon(1e-5));
  CHECK(b.stages[2].loss == doctest::Approx(a.stages[2].loss).epsilon(1e-4));
  std::filesystem::remove_all(o.checkpoint.folder);
}

/// The entries of the check-point fingerprint (of an empty capture, no networks) that `change`,
/// applied to default capture options, alters.
std::vector<std::string> fingerprint_changes(const std::function<void(capture_options&)>& change) {
  const capture cap{{capture_image{}}};
  const std::vector<image> photos{image(4, 4)};
  no_networks none;
  capture_options o;
  const fingerprint before = capture_fingerprint(cap, photos, none, none, o);
  change(o);
  return capture_fingerprint(cap, photos, none, none, o).differences_from(before);
}

}  // namespace

TEST_CASE("pipeline: every stage runs on a non-square size that is not a multiple of 32, maps stay valid") {
  const scene s(45, 37);
  estimation_network<estimator_tiny> estimator(1);
  auto_encoder<autoencoder_tiny> autoencoder(2);
  capture_options o = measured_capture_options();
  o.estimate.window = 64;
  o.estimate.stride = 16;
  o.finetune.steps = 12;
  o.refine.steps = 10;
  int estimate_reports = 0;
  o.finetune.progress_every = 4;
  o.progress = [&](const std::string& stage, const optimisation_progress&) { estimate_reports += stage == "estimate"; };
  const capture_result r = capture_once(s.cap, s.photos, estimator, autoencoder, o);
  REQUIRE(r.stages.size() == 4);
  CHECK(r.stages[0].name == "estimate");
  CHECK(r.stages[2].name == "finetune");
  CHECK(r.stages[2].steps == 12);
  CHECK(estimate_reports == int(window_starts(45, 64, 16).size() * window_starts(37, 64, 16).size()));
  // Fine-tuning and refining optimise the image loss: neither ends above where it started.
  CHECK(r.stages[2].loss <= r.stages[1].loss * 1.001);
  CHECK(r.stages[3].loss <= r.stages[2].loss * 1.001);
  // stage_loss finds a stage's loss by name; a stage that is not in the report has none.
  for (const stage_report& st : r.stages) CHECK(r.stage_loss(st.name) == st.loss);
  CHECK(std::isnan(r.stage_loss("first_guess")));
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
  capture_options o = measured_capture_options();
  o.estimate.window = 64;
  o.stages.estimate = false;  // start from the first guess: the networks' estimate is not needed here
  o.stages.refine = false;
  o.checkpoint.folder = std::filesystem::temp_directory_path() / ("anisocap_pipeline_" + std::to_string(std::random_device{}()));
  check_fine_tune_resumes(s, o);
}

TEST_CASE("fine-tune residual start: the fine-tune starts at the estimate itself, lowers the loss from there, and resumes exactly with crops") {
  const scene s(45, 37);
  estimation_network<estimator_tiny> estimator(1);
  capture_options o = measured_capture_options();
  o.estimate.window = 64;
  o.estimate.stride = 16;
  o.finetune.steps = 10;
  o.stages.refine = false;
  auto_encoder<autoencoder_tiny> plain_ae(2), residual_ae(2);
  const capture_result plain = capture_once(s.cap, s.photos, estimator, plain_ae, o);
  o.finetune.residual = true;
  const capture_result r = capture_once(s.cap, s.photos, estimator, residual_ae, o);
  REQUIRE(r.stages.size() == 3);
  // Without it the (untrained) decoder's maps of z are far from the estimate; with it the encode
  // stage's maps are the estimate: the same image loss.
  CHECK(plain.stages[1].loss != doctest::Approx(plain.stages[0].loss).epsilon(1e-3));
  CHECK(r.stages[1].loss == doctest::Approx(r.stages[0].loss).epsilon(1e-4));
  CHECK(r.stages[0].loss == doctest::Approx(plain.stages[0].loss).epsilon(1e-6));
  CHECK(r.stages[2].loss <= r.stages[1].loss * 1.001);
  CHECK(r.stages[2].loss < r.stages[1].loss);
  // A mismatched residual is refused.
  const auto z = encode(residual_ae, s.truth);
  tensor<parameter_count, float> wrong(1, 10, 10);
  CHECK_THROWS_AS(finetune(residual_ae, z, 45, 37, s.cap, make_loss_targets(s.photos), all_features, {}, 1.0, o.finetune, {}, &wrong),
                  std::invalid_argument);
  // Stopped and resumed (the residual is computed again from the check-pointed estimate), with crops.
  o.stages.estimate = false;
  o.finetune.crop.cells = 1;
  o.checkpoint.folder = std::filesystem::temp_directory_path() / ("anisocap_residual_" + std::to_string(std::random_device{}()));
  check_fine_tune_resumes(s, o);
}

TEST_CASE_TEMPLATE("fine-tune crops: every window's maps are the whole decode's; summed over all windows, losses and gradients are the whole tile's",
                   P, autoencoder_tiny, autoencoder_tiny_four_levels) {
  // 100 x 70 texels pad to 128 x 96 (4 x 3 latent cells of 32) with five levels, to 112 x 80 (7 x 5
  // cells of 16) with four; crops of 2 x 2 cells (one-cell margins where the grid goes on), clipped
  // at the borders and at the material's edge.
  const scene s(100, 70);
  const loss_targets targets = make_loss_targets(s.photos);
  auto_encoder<P> ae(3);
  constexpr int M = auto_encoder<P>::size_multiple;
  const auto z = encode(ae, s.truth);
  ae.freeze_encoder(true);
  const int cy = (70 + M - 1) / M, cx = (100 + M - 1) / M;
  REQUIRE(z.height() == cy);
  REQUIRE(z.width() == cx);
  CHECK(cy == (M == 32 ? 3 : 5));
  std::vector<nn::parameter*> params;
  ae.for_each_decoder_parameter([&](nn::parameter& p) { params.push_back(&p); });
  auto gradients = [&]() {
    std::vector<double> g;
    for (auto* p : params)
      for (float v : p->grad) g.push_back(v);
    return g;
  };
  auto zero = [&]() { for (auto* p : params) p->zero_grad(); };

  // The whole tile, as the fine-tune's uncropped step computes it.
  zero();
  ad::tape t;
  auto y = ae.decode(t, t.leaf(z));
  const auto u_view = y.value.tile(0, 0, 70, 100);
  const material_maps whole = network_space::network_to_maps(u_view, 0);
  material_maps grad(100, 70);
  const double whole_loss = loss_and_gradient(whole, s.cap, targets, &grad);
  auto g_view = y.grad.tile(0, 0, 70, 100);
  network_space::add_network_gradient(u_view, 0, grad, 1.0, g_view);
  t.backward();
  const std::vector<double> whole_grad = gradients();

  // Every window, gradients accumulated.
  zero();
  double loss_sum = 0;
  int windows = 0;
  finetune_crops::scratch scratch;
  const int k = 2;
  for (int sy = -(k - 1); sy < cy; ++sy)
    for (int sx = -(k - 1); sx < cx; ++sx) {
      const auto win = finetune_crops::clipped_window(cy, cx, k, k, sy, sx);
      // The window's decode equals the whole decode on its texels.
      {
        ad::tape tw;
        ad::tape::no_grad_guard guard(tw);
        const int mr = win.r0 > 0, mc = win.c0 > 0;
        const int lr1 = std::min(win.r1 + 1, cy), lc1 = std::min(win.c1 + 1, cx);
        auto yw = ae.decode(tw, tw.leaf(z.tile(win.r0 - mr, win.c0 - mc, lr1 - (win.r0 - mr), lc1 - (win.c0 - mc)).clone()));
        const int h = std::min(win.r1 * M, 70) - win.r0 * M, w = std::min(win.c1 * M, 100) - win.c0 * M;
        for (int yy = 0; yy < h; ++yy)
          for (int xx = 0; xx < w; ++xx)
            for (int c = 0; c < parameter_count; ++c)
              REQUIRE(yw.value(0, mr * M + yy, mc * M + xx, c) ==
                      doctest::Approx(y.value(0, win.r0 * M + yy, win.c0 * M + xx, c)).epsilon(1e-5));
      }
      ad::tape tc;
      const double l = finetune_crops::crop_step<all_features>(tc, ae, z, win, k, k, 100, 70, s.cap, targets, {}, scratch);
      const int h = std::min(win.r1 * M, 70) - win.r0 * M, w = std::min(win.c1 * M, 100) - win.c0 * M;
      loss_sum += l * h * w / double(k * k * M * M);
      ++windows;
    }
  CHECK(windows == (cy + k - 1) * (cx + k - 1));
  const double factor = 100.0 * 70.0 / (M * M);
  CHECK(loss_sum == doctest::Approx(factor * whole_loss).epsilon(1e-5));
  const std::vector<double> crop_grad = gradients();
  REQUIRE(crop_grad.size() == whole_grad.size());
  double norm = 0, diff = 0;
  for (std::size_t i = 0; i < crop_grad.size(); ++i) {
    norm += whole_grad[i] * whole_grad[i] * factor * factor;
    diff += (crop_grad[i] - factor * whole_grad[i]) * (crop_grad[i] - factor * whole_grad[i]);
  }
  CHECK(norm > 0);
  CHECK(std::sqrt(diff / norm) < 1e-4);
}

TEST_CASE("fine-tune shards: the same decoder bit for bit on 1, 2 and 3 ranks, and the whole tile's up to rounding") {
  const scene s(45, 37);
  const loss_targets targets = make_loss_targets(s.photos);
  auto_encoder<autoencoder_tiny> start(2);
  const auto z = encode(start, s.truth);
  // The decoder's last weights and the result of a fine-tune of 4 steps from the same start.
  auto run = [&](const finetune_options& o, const communicator& comm) {
    auto_encoder<autoencoder_tiny> ae(2);
    const finetune_result r = finetune(ae, z, 45, 37, s.cap, targets, all_features, {}, 1.0, o, {}, nullptr, comm);
    return std::pair{std::vector<float>(ae.dec<4>().weight.value.begin(), ae.dec<4>().weight.value.end()), r};
  };
  finetune_options whole_tile = measured_capture_options().finetune;
  whole_tile.steps = 4;
  for (const int crop : {0, 2}) {
    CAPTURE(crop);
    whole_tile.crop.cells = crop;
    finetune_options sharded = whole_tile;
    sharded.shard_cells = 1;  // a block per latent cell: more blocks than ranks, some ranks with more than one
    const auto alone = run(sharded, serial_communicator());
    REQUIRE(alone.second.steps == 4);
    const auto whole = run(whole_tile, serial_communicator());
    CHECK(alone.second.loss == doctest::Approx(whole.second.loss).epsilon(1e-4));
    for (std::size_t i = 0; i < alone.first.size(); ++i) REQUIRE(alone.first[i] == doctest::Approx(whole.first[i]).epsilon(1e-4));
    for (const int ranks : {2, 3}) {
      std::mutex m;
      run_on_loopback_ranks(ranks, [&](const communicator& comm) {
        const auto spread = run(sharded, comm);
        std::lock_guard lock(m);
        CHECK(spread.first == alone.first);
        CHECK(spread.second.loss == alone.second.loss);
      });
    }
  }
}

TEST_CASE("fine-tune crops: random windows cover every cell, and a cropped fine-tune resumes exactly") {
  // Coverage: over many steps each latent cell is in a crop about k / (cells + k - 1) of the time.
  std::vector<int> count(5 * 7, 0);
  const int steps = 20000;
  for (int step = 0; step < steps; ++step) {
    const auto w = finetune_crops::random_window(5, 7, 3, 3, 9, step);
    REQUIRE(w.r0 < w.r1);
    REQUIRE(w.c0 < w.c1);
    for (int r = w.r0; r < w.r1; ++r)
      for (int c = w.c0; c < w.c1; ++c) ++count[std::size_t(r * 7 + c)];
  }
  const double expected = steps * (3.0 / 7.0) * (3.0 / 9.0);
  for (int v : count) CHECK(std::abs(v - expected) < 0.06 * expected);

  const scene s(96, 64);
  capture_options o = measured_capture_options();
  o.stages.estimate = false;
  o.stages.refine = false;
  o.finetune.crop.cells = 1;
  o.finetune.warmup = 3;
  o.checkpoint.folder = std::filesystem::temp_directory_path() / ("anisocap_crop_" + std::to_string(std::random_device{}()));
  int observed = 0;
  o.finetune.observer = [&](int, double, const std::function<material_maps()>&) { ++observed; };
  check_fine_tune_resumes(s, o);
  CHECK(observed == 8);
}

TEST_CASE("fine-tune divergence guard: a learning rate far too large is halved back to a loss near the best, whole tiles and crops") {
  const scene s(64, 64);
  estimation_network<estimator_tiny> estimator(1);
  for (const int crop : {0, 1}) {  // crop 1: one of the 2 x 2 latent cells a step; the guard watches 5-step means
    CAPTURE(crop);
    capture_options o = measured_capture_options();
    o.stages.estimate = false;
    o.stages.refine = false;
    o.finetune.steps = 40;
    o.finetune.crop.cells = crop;
    o.finetune.learning_rate = 0.5f;  // Adam at 0.5 throws the decoder's weights about
    o.finetune.guard.every = 5;
    o.normalise_exposure = false;  // stage losses then are losses on these photographs
    const loss_targets targets = make_loss_targets(s.photos);
    std::vector<double> unguarded_losses;
    o.finetune.guard.factor = 0;
    o.finetune.observer = [&](int, double, const std::function<material_maps()>& maps) {
      unguarded_losses.push_back(loss_and_gradient<all_features>(maps(), s.cap, targets, nullptr));  // the whole tile's, crops or not
    };
    auto_encoder<autoencoder_tiny> a(2);
    const capture_result wild = capture_once(s.cap, s.photos, estimator, a, o);
    CHECK(wild.stages[2].restarts == 0);
    o.finetune.observer = nullptr;
    o.finetune.guard.factor = 1.5;
    auto_encoder<autoencoder_tiny> b(2);
    const capture_result guarded = capture_once(s.cap, s.photos, estimator, b, o);
    CHECK(guarded.stages[2].restarts > 0);
    CHECK(guarded.stages[2].restarts < 10);  // each restart resumes from the snapshot's loss: no endless going back
    CHECK(guarded.stages[2].steps == 40);
    // Without the guard the loss leaves its best far behind; with it, it ends near the best.
    const double best = *std::min_element(unguarded_losses.begin(), unguarded_losses.end());
    CHECK(wild.stages[2].loss > 1.5 * best);
    CHECK(guarded.stages[2].loss < wild.stages[2].loss);
    // Whole tiles: every step is checked, so the result stays within the guard of the start. Crops:
    // the guard sees 5-step means of one cell's loss, a weaker promise (only "better than unguarded").
    if (crop == 0) CHECK(guarded.stages[2].loss <= 1.5 * guarded.stages[1].loss);
    CHECK_THROWS_AS([&] {
      o.finetune.guard.factor = 0.9;
      auto_encoder<autoencoder_tiny> c(2);
      capture_once(s.cap, s.photos, estimator, c, o);
    }(), std::invalid_argument);
  }
}

TEST_CASE("fine-tune early stopping: at a patience check where the loss fell too little, from min_steps on") {
  const scene s(32, 32);
  estimation_network<estimator_tiny> estimator(1);
  capture_options o = measured_capture_options();
  o.stages.estimate = false;
  o.stages.refine = false;
  o.finetune.steps = 60;
  o.finetune.learning_rate = 1e-6f;  // the loss barely moves: every check asks to stop
  o.finetune.min_improvement = 0.5;
  o.finetune.patience = 10;
  auto steps_taken = [&](int min_steps) {
    o.finetune.min_steps = min_steps;
    auto_encoder<autoencoder_tiny> a(2);
    return capture_once(s.cap, s.photos, estimator, a, o).stages[2].steps;
  };
  CHECK(steps_taken(0) == 20);   // the first check only records the loss; the second stops
  CHECK(steps_taken(25) == 30);  // the first check at or past 25 steps
  CHECK(steps_taken(60) == 60);  // never before the end
  o.finetune.min_steps = -1;
  CHECK_THROWS_AS(o.finetune.validate(), std::invalid_argument);
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

TEST_CASE("every fine-tune field but the step count is in the check-point fingerprint, and negative counts are refused by name") {
  int fields = 0;
  const finetune_options defaults;
  finetune_options::visit_fields(defaults, [&](const std::string& name, const auto&) {
    ++fields;
    const std::vector<std::string> differences = fingerprint_changes([&](capture_options& o) {
      finetune_options::visit_fields(o.finetune, [&](const std::string& other, auto& value) {
        if (other != name) return;
        if constexpr (std::is_same_v<std::decay_t<decltype(value)>, bool>) value = !value;
        else value = value * 2 + 1;
      });
    });
    INFO(name);
    if (name == "steps") {
      CHECK(differences.empty());  // a check-point after k steps serves any total
    } else {
      REQUIRE(differences.size() == 1);
      CHECK(differences[0].rfind("finetune." + name + " ", 0) == 0);
    }
  });
  CHECK(fields == 13);
  auto refuses_negative = [](auto options, const std::string& type) {
    using options_type = decltype(options);
    options_type::visit_fields(options, [&](const std::string& name, const auto& value) {
      if constexpr (std::is_same_v<std::decay_t<decltype(value)>, int>) {
        options_type o = options;
        options_type::visit_fields(o, [&](const std::string& other, auto& v) {
          if constexpr (std::is_same_v<std::decay_t<decltype(v)>, int>)
            if (other == name) v = -1;
        });
        INFO(name);
        CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains((type + "::" + name + " must not be negative").c_str()), std::invalid_argument);
      }
    });
  };
  refuses_negative(finetune_options{}, "finetune_options");
  refuses_negative(refine_options{}, "refine_options");
}

TEST_CASE("both estimate fields are in the check-point fingerprint, and a bad window is refused by its fields' names") {
  int fields = 0;
  const estimate_options defaults;
  estimate_options::visit_fields(defaults, [&](const std::string& name, int) {
    ++fields;
    const std::vector<std::string> differences = fingerprint_changes([&](capture_options& o) {
      estimate_options::visit_fields(o.estimate, [&](const std::string& other, int& value) {
        if (other == name) value /= 2;
      });
    });
    INFO(name);
    REQUIRE(differences.size() == 1);
    CHECK(differences[0].rfind("estimate." + name + " ", 0) == 0);
  });
  CHECK(fields == 2);
  estimate_options e;
  e.stride = e.window + 1;
  CHECK_THROWS_WITH_AS(e.validate(), doctest::Contains("estimate_options::stride (257) is larger than estimate_options::window (256)"),
                       std::invalid_argument);
  e.stride = 0;
  CHECK_THROWS_WITH_AS(e.validate(), doctest::Contains("must be positive"), std::invalid_argument);
}
