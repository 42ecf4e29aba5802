#pragma once
/// @file
/// The fine-tune stage (docs/method.md section 8.3): Adam on the decoder's weights against the image
/// loss of the photographs, the latent code z fixed and the encoder frozen. Three additions to the
/// paper, each with its own options: a divergence guard (large learning rates), random crops
/// (mini-batches of latent cells) and check-points that resume exactly.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include "anisocap/core/distributed.hpp"
#include "anisocap/core/option_names.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/nn/part_gradients.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/pipeline/encode.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap {

/// The divergence guard: when a step's loss exceeds `factor` times the lowest loss so far (or is
/// not finite), the decoder and Adam go back to their last snapshot (taken every `every` steps)
/// and the learning rate halves. With crops the guard compares the mean crop loss of each `every`
/// steps instead of single steps (one crop's loss says little about the tile), the first snapshot
/// is the start, and the fine-tune ends with the last snapshot's decoder when the whole tile
/// renders better with it. A snapshot costs a copy of the decoder's weights and Adam moments (3x
/// the decoder's size). Large learning rates diverge on some materials after hundreds of good
/// steps; this keeps what those steps gained (docs/results.md "Run time against error").
struct finetune_guard_options {
  double factor = 1.5;  ///< 0: off; else above 1
  int every = 50;       ///< steps between snapshots
};

/// Random crops: each step fine-tunes on `cells` x `cells` latent cells (32 texels each) instead
/// of the whole tile (0: the whole tile, the paper). A step decodes the crop plus a one-cell margin
/// (so the crop's maps equal the whole decode's, exactly) and evaluates the loss on the crop only.
/// Crop starts are uniform over [-(k-1), cells-1] and clipped to the tile, so every texel is in a
/// crop equally often; each crop's gradient is weighted by its share of a full k x k crop.
struct finetune_crop_options {
  int cells = 0;
  std::uint64_t seed = 1;  ///< seed of the crop positions (a resumed run draws the same)
};

/// Check-points of a stage: a folder (empty: none), whether to resume from it, and the time
/// between fine-tune check-points.
struct checkpoint_options {
  std::filesystem::path folder;
  bool resume = false;
  double seconds = 60;
};

/// Options of `finetune`. The defaults are the fast schedule of docs/results.md "Run time against
/// error": 800 steps at 8e-3 after a 200-step linear warm-up reach the error of the paper's 5000
/// steps at 7.5e-4 (`paper()`) in about a fifth of the time.
struct finetune_options {
  int steps = 800;              ///< Adam steps (paper: 5000)
  float learning_rate = 8e-3f;  ///< Adam's rate after the warm-up (paper: 7.5e-4)
  int warmup = 200;             ///< linear learning-rate warm-up in steps (paper: none)
  int half_life = 0;            ///< the rate halves every this many steps (0: constant)
  /// Early stopping: stop when the loss improved by less than this fraction over the last
  /// `patience` steps (0: run every step). With crops the compared loss is the mean over each
  /// window of `patience` steps (one crop's loss is noisy).
  double min_improvement = 0.0;
  int patience = 200;
  /// Early stopping applies from this many steps on: the steps a run takes at least.
  int min_steps = 0;
  finetune_guard_options guard{};
  finetune_crop_options crop{};
  /// Shards: when > 0, each step's window (the whole tile, or the crop) is cut into blocks of this
  /// many latent cells per side, row by row; each block is decoded with its one-cell margin (as a
  /// crop is, so its maps equal the whole decode's), its loss and gradient computed on their own,
  /// and the blocks' gradients are added in ordered_sum's fixed tree (core/distributed.hpp). The
  /// blocks are spread over the ranks of the communicator finetune is given, so a step's work is
  /// shared, and the sum's bits depend on this number but never on the rank count: N ranks give
  /// the single process's decoder. 0: one decode of the whole window per step (one process only;
  /// more ranks take `distributed_shard_cells`). Each block costs its margin again: about
  /// ((s + 2) / s)^2 of the whole decode for blocks of s cells.
  int shard_cells = 0;
  /// The shards finetune takes when it runs on more than one rank and `shard_cells` is 0: 16 cells
  /// (512 texels) a side, a margin of about 27% more decoding.
  static constexpr int distributed_shard_cells = 16;
  /// Residual start (docs/method.md section 8.3): fine-tune D(z) + r instead of D(z), where r, fixed,
  /// takes the decoder's first maps to the estimate (decoder_residual). The stage then starts at the
  /// estimate itself rather than at its reconstruction through the auto-encoder, and the decoder's
  /// updates move the maps from there. capture_material computes r; finetune takes it as an argument.
  bool residual = false;
  int progress_every = 50;
  /// >= 0: return after this many steps with a check-point, as if killed there (tests of resume).
  int stop_after = -1;
  std::function<void(const optimisation_progress&)> progress;
  /// Called at every step with the number of updates done so far, the step's image loss (with
  /// crops, the crop's: noisy) and a function that returns the whole decoded maps at that point
  /// (before the step's update; with crops it decodes the whole tile, so call it only when
  /// needed). For monitoring and for studies that read many step counts off one run.
  std::function<void(int updates, double loss, const std::function<material_maps()>& maps)> observer;

  /// The thorough schedule's fine-tune (capture_options::thorough): the fast one run for 2000
  /// steps. On metals the fine-tune is still descending at 800 (docs/results.md "Run time
  /// against error").
  static finetune_options thorough() {
    finetune_options o;
    o.steps = 2000;
    return o;
  }
  /// The paper's schedule (section 5): 5000 steps at 7.5e-4, no warm-up.
  static finetune_options paper() {
    finetune_options o;
    o.steps = 5000;
    o.learning_rate = 7.5e-4f;
    o.warmup = 0;
    return o;
  }
  /// Calls `f(name, field)` for each field that decides what the fine-tune computes, named as the
  /// library's messages, the check-point fingerprint (capture_fingerprint) and the program's
  /// report name them: the one list of them (`o` a finetune_options, const or not).
  template <class Self, class F>
  static void visit_fields(Self& o, F&& f) {
    f("steps", o.steps);
    f("learning_rate", o.learning_rate), f("warmup", o.warmup), f("half_life", o.half_life);         // the rate's schedule
    f("min_improvement", o.min_improvement), f("patience", o.patience), f("min_steps", o.min_steps);  // early stopping
    f("guard.factor", o.guard.factor), f("guard.every", o.guard.every);
    f("crop.cells", o.crop.cells), f("crop.seed", o.crop.seed);
    f("shard_cells", o.shard_cells);
    f("residual", o.residual);
  }
  /// Throws std::invalid_argument for impossible values.
  void validate() const {
    check_counts_not_negative(*this, "finetune_options");
    if (!(learning_rate > 0) || !std::isfinite(learning_rate))
      throw std::invalid_argument("finetune_options::learning_rate must be positive and finite");
    if (!(min_improvement >= 0 && min_improvement < 1))
      throw std::invalid_argument("finetune_options::min_improvement (the fine-tune's early stopping) must be in [0, 1)");
    if (!(guard.factor >= 0) || !std::isfinite(guard.factor) || (guard.factor > 0 && guard.factor <= 1))
      throw std::invalid_argument("finetune_options::guard.factor must be 0 (off) or above 1");
    if (guard.factor > 0 && guard.every < 1)
      throw std::invalid_argument("finetune_options::guard.every (steps between the guard's snapshots) must be at least 1");
  }
};

/// What `finetune` did.
struct finetune_result {
  material_maps maps;  ///< the decoder's maps after the stage (restricted to the kernel's features)
  int steps = 0;       ///< steps run in this call
  double loss = 0;     ///< image loss of `maps`
  double seconds = 0;
  bool resumed = false;  ///< continued from a check-point
  bool stopped = false;  ///< returned early at `stop_after`, leaving a check-point
  int restarts = 0;      ///< times the divergence guard went back and halved the rate
};

namespace finetune_crops {

/// A window of latent cells: rows [r0, r1) x columns [c0, c1).
struct latent_window {
  int r0 = 0, r1 = 0, c0 = 0, c1 = 0;
};

/// The crop of k_y x k_x cells whose start is (start_y, start_x), clipped to the cells_y x cells_x
/// latent grid; starts range over [-(k-1), cells-1] so that every cell is in exactly k of them
/// per axis.
inline latent_window clipped_window(int cells_y, int cells_x, int k_y, int k_x, int start_y, int start_x) {
  if (start_y <= -k_y || start_y >= cells_y || start_x <= -k_x || start_x >= cells_x)
    throw std::invalid_argument("clipped_window: the crop lies outside the latent grid");
  return {std::max(start_y, 0), std::min(start_y + k_y, cells_y), std::max(start_x, 0), std::min(start_x + k_x, cells_x)};
}

/// The crop of fine-tune step `step`: starts uniform over [-(k-1), cells-1] per axis, drawn from
/// (seed, step) alone, so a resumed run draws the same crops.
inline latent_window random_window(int cells_y, int cells_x, int k_y, int k_x, std::uint64_t seed, std::int64_t step) {
  const int sy = int(hash64(seed, step, 0) % std::uint64_t(cells_y + k_y - 1)) - (k_y - 1);
  const int sx = int(hash64(seed, step, 1) % std::uint64_t(cells_x + k_x - 1)) - (k_x - 1);
  return clipped_window(cells_y, cells_x, k_y, k_x, sy, sx);
}

/// Scratch buffers of crop_step, reused from step to step.
struct scratch {
  loss_targets targets;
  material_maps maps;  ///< the window's decoded maps
  material_maps gradient;
};

/// crop_step with the gradient weighted by the window's texel count over `area` (texels) instead
/// of over a whole crop's: summed over windows that tile a region of `area` texels, the gradient is
/// that of the region's mean loss.
template <brdf_features F, class P>
double window_step(ad::tape& t, auto_encoder<P>& autoencoder, const tensor<auto_encoder<P>::latent_channels, float>& z,
                   const latent_window& win, double area, int width, int height, const capture& cap, const loss_targets& targets,
                   const render_options& render, scratch& scratch, const tensor<parameter_count, float>* residual = nullptr) {
  constexpr int M = auto_encoder<P>::size_multiple;
  const int cells_y = z.height(), cells_x = z.width();
  const int mr = win.r0 > 0 ? 1 : 0, mc = win.c0 > 0 ? 1 : 0;
  const int lr1 = std::min(win.r1 + 1, cells_y), lc1 = std::min(win.c1 + 1, cells_x);
  auto y = autoencoder.decode(t, t.leaf(z.tile(win.r0 - mr, win.c0 - mc, lr1 - (win.r0 - mr), lc1 - (win.c0 - mc)).clone()));
  const int y0 = win.r0 * M, x0 = win.c0 * M;
  const int h = std::min(win.r1 * M, height) - y0, w = std::min(win.c1 * M, width) - x0;
  if (h <= 0 || w <= 0) throw std::invalid_argument("crop_step: the window holds no texel of the material");
  const auto u_view = residual ? network_space::shifted(y.value.tile(mr * M, mc * M, h, w), residual->tile(y0, x0, h, w))
                               : y.value.tile(mr * M, mc * M, h, w);
  material_maps& m = scratch.maps;
  network_space::network_to_maps(u_view, 0, m);
  crop_loss_targets(targets, x0, y0, w, h, scratch.targets);
  if (scratch.gradient.width() != w || scratch.gradient.height() != h) scratch.gradient = material_maps(w, h);
  const double loss = loss_and_gradient<F>(m, cap, scratch.targets, &scratch.gradient, tile_placement{width, height, x0, y0}, render);
  auto g_view = y.grad.tile(mr * M, mc * M, h, w);
  network_space::add_network_gradient(u_view, 0, scratch.gradient, double(h) * w / area, g_view);
  t.backward();
  return loss;
}


/// One fine-tune pass on a crop: decodes the window's latent cells plus a one-cell margin inside
/// the grid (with 4x4 stride-2 transposed convolutions an output texel depends on the latent cells
/// within one cell of its own, so the window's maps equal the whole decode's), evaluates the image
/// loss on the window's texels inside the W x H material, puts its gradient, weighted by the
/// window's share of a whole k_y x k_x crop, on the decoder's parameters (accumulating) and returns
/// the window's loss (the mean over its texels). Summed over every start of clipped_window, the
/// gradients are (W H / 32^2) times the whole tile's.
template <brdf_features F, class P>
double crop_step(ad::tape& t, auto_encoder<P>& autoencoder, const tensor<auto_encoder<P>::latent_channels, float>& z,
                 const latent_window& win, int k_y, int k_x, int width, int height, const capture& cap, const loss_targets& targets,
                 const render_options& render, scratch& scratch, const tensor<parameter_count, float>* residual = nullptr) {
  constexpr int M = auto_encoder<P>::size_multiple;
  return window_step<F>(t, autoencoder, z, win, double(k_y) * k_x * M * M, width, height, cap, targets, render, scratch, residual);
}

/// The blocks of `shard` x `shard` latent cells that cover `win`, row by row (the last of each
/// row and column smaller where the window is not a multiple): finetune_options::shard_cells.
inline std::vector<latent_window> shards_of(const latent_window& win, int shard) {
  if (shard < 1) throw std::invalid_argument("shards_of: the shard size must be at least 1 cell");
  std::vector<latent_window> shards;
  for (int r = win.r0; r < win.r1; r += shard)
    for (int c = win.c0; c < win.c1; c += shard) shards.push_back({r, std::min(r + shard, win.r1), c, std::min(c + shard, win.c1)});
  return shards;
}

/// The number of texels of `win` inside the width x height material.
inline double texels_in(const latent_window& win, int cell, int width, int height) {
  const int h = std::min(win.r1 * cell, height) - win.r0 * cell, w = std::min(win.c1 * cell, width) - win.c0 * cell;
  return h > 0 && w > 0 ? double(h) * w : 0.0;
}
}  // namespace finetune_crops

/// The divergence guard's state (finetune_guard_options): the lowest loss so far, a snapshot of
/// the decoder's weights and Adam's state with its loss, and the learning-rate factor.
class divergence_guard {
 public:
  divergence_guard(const finetune_guard_options& options, const nn::learning_rate_schedule& schedule)
      : options_(options), schedule_(schedule) {}
  double best_loss = std::numeric_limits<double>::infinity();
  double lr_scale = 1.0;
  int restarts = 0;
  nn::adam::snapshot snapshot;
  double snapshot_loss = 0;

  /// True when `loss` (NaN and infinity included) exceeds the guard: the weights and Adam's state
  /// go back to the snapshot and the learning rate halves. Else a new snapshot is taken when
  /// `may_snapshot` and the loss is near the best.
  bool restarts_after(nn::adam& adam, double loss, bool may_snapshot) {
    if (!(loss <= options_.factor * best_loss) && !snapshot.empty()) {
      adam.restore(snapshot);  // back to weights whose loss was near the best, at half the rate
      adam.zero_grad();
      best_loss = snapshot_loss;  // the baseline from here (the best may have fallen since the snapshot)
      lr_scale *= 0.5;
      adam.schedule = schedule_.scaled(lr_scale);
      ++restarts;
      return true;
    }
    best_loss = std::min(best_loss, loss);
    if (may_snapshot && loss <= 1.1 * best_loss) take(adam, loss);
    return false;
  }
  /// Takes a snapshot at `loss`.
  void take(nn::adam& adam, double loss) {
    adam.take_snapshot(snapshot);  // into the previous snapshot's buffers
    snapshot_loss = loss;
  }

 private:
  finetune_guard_options options_;
  nn::learning_rate_schedule schedule_;
};

namespace finetune_detail {

inline std::string exact(double v) {
  char text[40];
  std::snprintf(text, sizeof text, "%.17g", v);
  return text;
}

/// Everything the rest of a fine-tune depends on besides the decoder and Adam: the divergence
/// guard (lowest loss, rate factor, restarts, snapshot), the crop guard's current window of losses
/// and the early-stopping rule's state. Crop positions are drawn from (seed, step) alone.
struct loop_state {
  double window_sum = 0;
  int window_steps = 0;
  nn::early_stopping::state stopping{};
};

/// Writes the fine-tune's check-point into `folder` after `step` steps: the decoder's weights
/// (decoder.safetensors) and in state.safetensors Adam's state (nn/adam.hpp's key scheme, its own
/// step counter included: after a guard restart it lags the loop's), the guard's snapshot of
/// weights and moments, and the guard's and the loop's numbers, doubles written exactly. Both
/// files carry the step, so a pair torn by a kill between the two renames is recognised (and
/// completed on resume: finish_interrupted_save).
template <class P>
void save_checkpoint(const std::filesystem::path& folder, auto_encoder<P>& autoencoder, nn::adam& adam, int step,
                     const divergence_guard& guard, const loop_state& loop) {
  std::filesystem::create_directories(folder);
  // Both files are written whole under other names first, then renamed into place back to back
  // (the decoder first): a kill while writing leaves the previous pair intact, and the pair can be
  // torn only between two renames.
  const std::filesystem::path decoder_next = folder / "decoder.next.safetensors", state_next = folder / "state.next.safetensors";
  nn::save_weights(decoder_next, autoencoder, {{"step", std::to_string(step)}});
  nn::safetensors_file state;  // borrows the moments and the snapshot: written from where they are, nothing copied
  adam.save_state(state);
  for (std::size_t i = 0; i < guard.snapshot.buffers.size(); ++i)
    state.add_view<float>("guard.snapshot." + std::to_string(i), {std::int64_t(guard.snapshot.buffers[i].size())},
                          guard.snapshot.buffers[i].data(), guard.snapshot.buffers[i].size());
  if (!guard.snapshot.empty()) {
    const std::vector<std::int64_t> counts(guard.snapshot.counts.begin(), guard.snapshot.counts.end());
    state.add<std::int64_t>("guard.snapshot.counts", {std::int64_t(counts.size())}, counts.data(), counts.size());
    state.metadata.emplace_back("guard.snapshot.steps", std::to_string(guard.snapshot.steps));
  }
  state.metadata.emplace_back("step", std::to_string(step));
  state.metadata.emplace_back("guard.lr_scale", exact(guard.lr_scale));
  state.metadata.emplace_back("guard.best_loss", exact(guard.best_loss));
  state.metadata.emplace_back("guard.snapshot_loss", exact(guard.snapshot_loss));
  state.metadata.emplace_back("guard.restarts", std::to_string(guard.restarts));
  state.metadata.emplace_back("window_sum", exact(loop.window_sum));
  state.metadata.emplace_back("window_steps", std::to_string(loop.window_steps));
  state.metadata.emplace_back("stopping.best", exact(loop.stopping.best));
  state.metadata.emplace_back("stopping.sum", exact(loop.stopping.sum));
  nn::write_safetensors(state_next, state);
  std::filesystem::rename(decoder_next, folder / "decoder.safetensors");
  std::filesystem::rename(state_next, folder / "state.safetensors");
}

/// The "step" save_checkpoint wrote into `file`'s metadata; "" when the file is unreadable, half
/// written (its header's offsets run past its end) or has none. Reads the header alone.
inline std::string checkpoint_step(const std::filesystem::path& file) {
  try {
    for (const auto& [key, value] : nn::read_safetensors_header(file).metadata)
      if (key == "step") return value;
  } catch (const std::exception&) {
  }
  return "";
}

/// Completes a save that a kill interrupted between save_checkpoint's two renames: the new decoder
/// is in place and the new state, written whole before either rename, is still under its .next
/// name (with the decoder's step). Every other file under a .next name is from a save killed
/// before its renames, so the pair in place is the previous complete one, and it is removed. Safe
/// when several ranks call it at once on one folder: a rename that another rank made first is
/// ignored, and state.next goes before decoder.next, so no rank ever sees a state.next without
/// its decoder.next that is not the interrupted rename's.
inline void finish_interrupted_save(const std::filesystem::path& folder) {
  namespace fs = std::filesystem;
  const fs::path decoder_next = folder / "decoder.next.safetensors", state_next = folder / "state.next.safetensors";
  std::error_code ignored;  // absent in the usual case, or another rank's already
  if (!fs::exists(decoder_next, ignored) && fs::exists(state_next, ignored)) {
    const std::string pending = checkpoint_step(state_next);
    if (!pending.empty() && pending == checkpoint_step(folder / "decoder.safetensors"))
      fs::rename(state_next, folder / "state.safetensors", ignored);
  }
  fs::remove(state_next, ignored);
  fs::remove(decoder_next, ignored);
}

/// Reads back save_checkpoint's files; returns the step to continue from. Throws
/// std::runtime_error naming the file when a value is missing or the two files disagree. A save a
/// kill interrupted is completed where it can be, or dropped (finish_interrupted_save).
template <class P>
int load_checkpoint(const std::filesystem::path& folder, auto_encoder<P>& autoencoder, nn::adam& adam, divergence_guard& guard,
                    loop_state& loop) {
  finish_interrupted_save(folder);
  const std::filesystem::path decoder_file = folder / "decoder.safetensors", state_file = folder / "state.safetensors";
  const auto decoder = nn::read_safetensors(decoder_file);
  const auto state = nn::read_safetensors(state_file);
  auto value = [&](const nn::safetensors_file& f, const std::filesystem::path& name, const std::string& key) -> std::string {
    for (const auto& [k, v] : f.metadata)
      if (k == key) return v;
    throw std::runtime_error(name.string() + ": the fine-tune check-point has no '" + key + "'");
  };
  const std::string step_text = value(state, state_file, "step");
  if (value(decoder, decoder_file, "step") != step_text)
    throw std::runtime_error(folder.string() + ": the fine-tune check-point's files are of different steps (a run was stopped while "
                             "saving); remove the folder to start the fine-tune over");
  try {
    nn::load_weights(decoder_file, autoencoder);
    adam.load_state(state, state_file.string());
    guard.lr_scale = std::stod(value(state, state_file, "guard.lr_scale"));
    guard.best_loss = std::stod(value(state, state_file, "guard.best_loss"));
    guard.snapshot_loss = std::stod(value(state, state_file, "guard.snapshot_loss"));
    guard.restarts = std::stoi(value(state, state_file, "guard.restarts"));
    loop.window_sum = std::stod(value(state, state_file, "window_sum"));
    loop.window_steps = std::stoi(value(state, state_file, "window_steps"));
    loop.stopping = {std::stod(value(state, state_file, "stopping.best")), std::stod(value(state, state_file, "stopping.sum"))};
    guard.snapshot = {};
    if (const auto* counts = state.find("guard.snapshot.counts")) {
      const auto shape = adam.take_snapshot();  // the sizes the snapshot must have
      if (counts->count() != shape.counts.size()) throw std::runtime_error(state_file.string() + ": the guard's snapshot is of other parameters");
      std::vector<std::int64_t> c(counts->count());
      std::memcpy(c.data(), state.bytes(*counts).data(), c.size() * sizeof(std::int64_t));
      guard.snapshot.counts.assign(c.begin(), c.end());
      guard.snapshot.steps = std::stol(value(state, state_file, "guard.snapshot.steps"));
      for (std::size_t i = 0; i < shape.buffers.size(); ++i) {
        const auto* e = state.find("guard.snapshot." + std::to_string(i));
        if (!e || e->dtype != "F32" || e->count() != shape.buffers[i].size())
          throw std::runtime_error(state_file.string() + ": the guard's snapshot is missing or of other parameters");
        std::vector<float> b(e->count());
        std::memcpy(b.data(), state.bytes(*e).data(), b.size() * sizeof(float));
        guard.snapshot.buffers.push_back(std::move(b));
      }
    }
    return std::stoi(step_text);
  } catch (const std::logic_error& e) {  // std::stod and friends on a malformed number
    throw std::runtime_error(state_file.string() + ": malformed fine-tune check-point (" + e.what() + ")");
  }
}

}  // namespace finetune_detail

namespace finetune_detail {

/// One fine-tune (see finetune): its inputs, Adam and the divergence guard, the kinds of step
/// (the whole tile, a crop, shards), the loop and its end.
template <class P>
class run {
 public:
  using latent = tensor<auto_encoder<P>::latent_channels, float>;
  using latent_window = finetune_crops::latent_window;
  run(auto_encoder<P>& autoencoder, const latent& z, int width, int height, const capture& cap, const loss_targets& targets,
      brdf_features features, const render_options& render, const finetune_options& o, const tensor<parameter_count, float>* residual,
      const communicator& comm)
      : ae_(frozen_encoder(autoencoder)), z_(z), W_(width), H_(height), cap_(cap), targets_(targets), features_(features),
        render_(render), o_(o), residual_(residual), comm_(comm),
        schedule_(nn::learning_rate_schedule::warmup_half_life(o.learning_rate, o.warmup, o.half_life)), adam_(schedule_),
        guard_(o.guard, schedule_), grad_(width, height), cells_y_(z.height()), cells_x_(z.width()),
        // Crops: k x k latent cells, only where the tile has more cells than that.
        crop_y_(o.crop.cells > 0 && o.crop.cells < cells_y_ ? o.crop.cells : cells_y_),
        crop_x_(o.crop.cells > 0 && o.crop.cells < cells_x_ ? o.crop.cells : cells_x_), cropping_(crop_y_ < cells_y_ || crop_x_ < cells_x_),
        // Shards: the step's window cut into fixed blocks, spread over the ranks, their gradients
        // added in a fixed tree (ordered_sum), so that any rank count gives the same bits.
        shard_cells_(o.shard_cells > 0 ? o.shard_cells : comm.distributed() ? finetune_options::distributed_shard_cells : 0),
        shard_parts_(nn::trainable_parameters([&](auto&& f) { autoencoder.for_each_decoder_parameter(f); }), comm),
        // The guard checks the whole tile's loss every step; with crops it checks the mean loss of
        // every `guard.every` steps instead (a whole-tile decode would cost as much as the crops).
        guarding_(o.guard.factor > 0) {
    autoencoder.for_each_decoder_parameter([&](nn::parameter& p) { adam_.add(p); });
  }

  /// Runs the steps from the check-point's (when `checkpoint` resumes one) to o.steps, or until
  /// early stopping or o.stop_after; `start_loss` is the image loss before the stage.
  finetune_result operator()(double start_loss, const checkpoint_options& checkpoint) {
    namespace fs = std::filesystem;
    const auto start = std::chrono::steady_clock::now();
    finetune_result result;
    int first = 0;
    const bool checkpoints = !checkpoint.folder.empty();
    // Whether to continue from a check-point: rank 0, which writes them, decides for every rank.
    if (comm_.root_decides([&] { return checkpoints && checkpoint.resume && fs::exists(checkpoint.folder / "state.safetensors"); })) {
      first = load_checkpoint(checkpoint.folder, ae_, adam_, guard_, loop_);
      adam_.schedule = schedule_.scaled(guard_.lr_scale);
      result.resumed = true;
    }
    auto last_checkpoint = std::chrono::steady_clock::now();
    nn::early_stopping stopper(o_.min_improvement, o_.patience, cropping_);  // crop losses are noisy: window means
    stopper.restore(loop_.stopping);
    if (guarding_ && cropping_ && first == 0) {  // the start, at the whole tile's loss, is the first place to come back to
      guard_.take(adam_, start_loss);
      guard_.best_loss = std::min(guard_.best_loss, guard_.snapshot_loss);
    }
    int step = first;
    for (; step < o_.steps; ++step) {
      const double loss = one_step(step);
      if (o_.progress && o_.progress_every > 0 && (step + 1) % o_.progress_every == 0)
        o_.progress(optimisation_progress::at(step + 1, o_.steps, loss, seconds_since(start), first));
      const bool stops = stopper.stop_after(step, loss) && step + 1 >= o_.min_steps;
      const bool killed = o_.stop_after >= 0 && step + 1 >= o_.stop_after && !stops && step + 1 < o_.steps;
      if (checkpoints && comm_.root() && (killed || seconds_since(last_checkpoint) > checkpoint.seconds)) {
        loop_.stopping = stopper.current();
        save_checkpoint(checkpoint.folder, ae_, adam_, step + 1, guard_, loop_);
        last_checkpoint = std::chrono::steady_clock::now();
      }
      if (stops || killed) {
        ++step;
        result.stopped = killed;
        break;
      }
    }
    finish(result);
    result.steps = step - first;
    result.restarts = guard_.restarts;
    result.seconds = seconds_since(start);
    return result;
  }

 private:
  static auto_encoder<P>& frozen_encoder(auto_encoder<P>& autoencoder) {
    autoencoder.freeze_encoder(true);
    return autoencoder;
  }

  /// Step `step` of the kind the options choose, and Adam's update unless the guard restarted.
  /// Returns the step's loss.
  double one_step(int step) {
    t_.clear();
    double loss = 0;
    bool restarted = false;
    if (shard_cells_ > 0) {
      const latent_window win = cropping_ ? random_window(step) : latent_window{0, cells_y_, 0, cells_x_};
      loss = sharded_step(win, !cropping_);
      observe_decoding(step, loss);
      restarted = guard_restarts(step, loss);
      if (!restarted) shard_parts_.apply();
    } else if (!cropping_) {
      auto y = ae_.decode(t_, t_.leaf(z_));
      const auto u_view = residual_ ? network_space::shifted(y.value.tile(0, 0, H_, W_), *residual_) : y.value.tile(0, 0, H_, W_);
      network_space::network_to_maps(u_view, 0, maps_);
      loss = with_features(features_, [&]<brdf_features F>() { return loss_and_gradient<F>(maps_, cap_, targets_, &grad_, {}, render_); });
      if (o_.observer) o_.observer(step, loss, [&]() { return maps_; });
      restarted = guard_restarts(step, loss);
      if (!restarted) {
        auto g_view = y.grad.tile(0, 0, H_, W_);
        network_space::add_network_gradient(u_view, 0, grad_, 1.0, g_view);
        t_.backward();
      }
    } else {
      const latent_window win = random_window(step);
      loss = with_features(features_, [&]<brdf_features F>() {
        return finetune_crops::crop_step<F>(t_, ae_, z_, win, crop_y_, crop_x_, W_, H_, cap_, targets_, render_, scratch_, residual_);
      });
      observe_decoding(step, loss);
      restarted = guard_restarts(step, loss);
    }
    if (!restarted) adam_.step();
    return loss;
  }

  latent_window random_window(int step) const {
    return finetune_crops::random_window(cells_y_, cells_x_, crop_y_, crop_x_, o_.crop.seed, step);
  }

  /// One step on the shards of `win` (crop weights over the crop's cells, or the whole tile's
  /// mean): sums the shards' gradients (shard_parts_.apply() puts them in the decoder's) and
  /// returns the window's loss.
  double sharded_step(const latent_window& win, bool whole) {
    constexpr int M = auto_encoder<P>::size_multiple;
    const std::vector<latent_window> shards = finetune_crops::shards_of(win, shard_cells_);
    shard_parts_.start(int(shards.size()));
    const double window_area = finetune_crops::texels_in(win, M, W_, H_);
    const double area = whole ? window_area : double(crop_y_) * crop_x_ * M * M;
    adam_.zero_grad();  // once: take() leaves the gradients at zero after each shard
    for (int k = shard_parts_.first(); k < shard_parts_.last(); ++k) {
      t_.clear();
      const auto& shard = shards[std::size_t(k)];
      const double shard_loss = with_features(features_, [&]<brdf_features F>() {
        return finetune_crops::window_step<F>(t_, ae_, z_, shard, area, W_, H_, cap_, targets_, render_, scratch_, residual_);
      });
      shard_parts_.loss(k) = shard_loss * (finetune_crops::texels_in(shard, M, W_, H_) / window_area);
      shard_parts_.take(k);  // and zeroes the decoder's gradients
    }
    return shard_parts_.sum();
  }

  /// The observer, for steps that have no whole-tile maps at hand (crops, shards): decodes them
  /// only if it asks (weights not yet updated; the step's tape is no longer needed).
  void observe_decoding(int at, double loss) {
    if (!o_.observer) return;
    std::optional<material_maps> whole;
    o_.observer(at, loss, [&]() {
      if (!whole) whole = decode(ae_, z_, W_, H_, residual_);
      return *whole;
    });
  }

  /// The guard after a step's loss: the whole tile's every step, or with crops the mean of every
  /// `guard.every` steps. True when it restarted from its snapshot.
  bool guard_restarts(int at, double loss) {
    if (!guarding_) return false;
    if (!cropping_) return guard_.restarts_after(adam_, loss, at % o_.guard.every == 0);
    loop_.window_sum += loss;  // crops: the losses of the guard's current window of steps
    if (++loop_.window_steps < o_.guard.every) return false;
    const bool restarts = guard_.restarts_after(adam_, loop_.window_sum / loop_.window_steps, true);
    loop_.window_sum = 0;
    loop_.window_steps = 0;
    return restarts;
  }

  double image_loss(const material_maps& m) const {
    return anisocap::image_loss(m, cap_, targets_, features_, render_);
  }

  /// The decoder's maps (restricted to the kernel's features: what a reduced kernel fitted, as
  /// every renderer sees it) and their image loss. The crop guard watches window means, not the
  /// tile: it keeps the last snapshot's decoder instead when the whole tile renders better with it.
  void finish(finetune_result& result) {
    result.maps = decode(ae_, z_, W_, H_, residual_);
    restrict_to_features(result.maps, features_);
    result.loss = image_loss(result.maps);
    if (!(guarding_ && cropping_ && !guard_.snapshot.empty())) return;
    const auto last = adam_.take_snapshot();
    adam_.restore(guard_.snapshot);
    material_maps snapshot_maps = decode(ae_, z_, W_, H_, residual_);
    restrict_to_features(snapshot_maps, features_);
    const double snapshot_tile_loss = image_loss(snapshot_maps);
    if (snapshot_tile_loss < result.loss) {
      result.maps = std::move(snapshot_maps);
      result.loss = snapshot_tile_loss;
    } else {
      adam_.restore(last);
    }
  }

  auto_encoder<P>& ae_;
  const latent& z_;
  const int W_, H_;
  const capture& cap_;
  const loss_targets& targets_;
  const brdf_features features_;
  const render_options& render_;
  const finetune_options& o_;
  const tensor<parameter_count, float>* const residual_;
  const communicator& comm_;
  const nn::learning_rate_schedule schedule_;
  nn::adam adam_;
  divergence_guard guard_;
  loop_state loop_;
  material_maps maps_, grad_;  // the decoded maps and their gradient, reused from step to step
  ad::tape t_;
  const int cells_y_, cells_x_, crop_y_, crop_x_;
  const bool cropping_;
  finetune_crops::scratch scratch_;
  const int shard_cells_;
  nn::part_gradients<double> shard_parts_;
  const bool guarding_;
};

}  // namespace finetune_detail

/// Fine-tunes the decoder of `autoencoder` from the latent code `z` on the photographs behind
/// `targets` (a `width` x `height` material under `cap`), with the image loss of kernel `features`.
/// `start_loss` is the image loss of the decoder's maps before the stage. The encoder is frozen.
/// `residual` (network space, width x height; null for none) is the fixed shift of the residual
/// start (finetune_options::residual): the stage then fits D(z) + residual. `comm`: the ranks that
/// share the work of each step (finetune_options::shard_cells); every rank calls finetune with the
/// same arguments, ends with the same decoder and result, and only rank 0 writes check-points.
template <class P>
finetune_result finetune(auto_encoder<P>& autoencoder, const tensor<auto_encoder<P>::latent_channels, float>& z, int width,
                         int height, const capture& cap, const loss_targets& targets, brdf_features features,
                         const render_options& render, double start_loss, const finetune_options& o,
                         const checkpoint_options& checkpoint = {}, const tensor<parameter_count, float>* residual = nullptr,
                         const communicator& comm = serial_communicator()) {
  o.validate();
  if (residual && (residual->height() != height || residual->width() != width))
    throw std::invalid_argument("finetune: the residual is " + std::to_string(residual->height()) + "x" + std::to_string(residual->width()) +
                                ", the material " + std::to_string(height) + "x" + std::to_string(width));
  finetune_detail::run<P> stage(autoencoder, z, width, height, cap, targets, features, render, o, residual, comm);
  return stage(start_loss, checkpoint);
}

}  // namespace anisocap
