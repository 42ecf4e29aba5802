#pragma once
/// @file
/// The capture pipeline of MODEL.md 8 at any resolution: estimate (sliding windows of the
/// estimation network), encode (the auto-encoder's encoder), fine-tune (the decoder's weights on the
/// image loss against the photographs, z fixed, encoder frozen), refine (per texel). Each stage can
/// be skipped; stages check-point into a folder so that a killed run resumes.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/network_space.hpp"
#include "anisocap/pipeline/networks.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/pipeline/windows.hpp"
#include "anisocap/render/analysis.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap {

/// Which stages run.
struct pipeline_stages {
  bool estimate = true;  ///< estimation network over sliding windows (else: first guess from the photographs)
  bool encode = true;    ///< encode + fine-tune the decoder need the estimate (or the first guess)
  bool finetune = true;  ///< fine-tune the decoder's weights on the photographs
  bool refine = true;    ///< per-texel refinement

  /// Parses "estimate,encode,finetune,refine" (any subset, comma separated; "all").
  static pipeline_stages parse(const std::string& text) {
    pipeline_stages s{false, false, false, false};
    std::size_t start = 0;
    while (start <= text.size()) {
      const std::size_t end = std::min(text.find(',', start), text.size());
      const std::string name = text.substr(start, end - start);
      if (name == "estimate") s.estimate = true;
      else if (name == "encode") s.encode = true;
      else if (name == "finetune" || name == "fine-tune") s.finetune = true;
      else if (name == "refine") s.refine = true;
      else if (name == "all") s = pipeline_stages{};
      else throw std::invalid_argument("unknown stage '" + name + "' in --stages (estimate, encode, finetune, refine, all)");
      start = end + 1;
    }
    if (s.finetune && !s.encode) throw std::invalid_argument("--stages: finetune needs encode");
    return s;
  }
};

/// The fine-tune's early-stopping rule: every `patience` steps the loss (the step's own, or with
/// `window_mean` the mean over the last `patience` steps) is compared with the lowest such value
/// so far; the run stops when it improved by less than `tolerance` (0: never stops).
/// bench/sweep.cpp replays recorded loss curves with the same rule.
class early_stopping {
 public:
  early_stopping(double tolerance, int patience, bool window_mean)
      : tolerance_(tolerance), patience_(patience), window_mean_(window_mean) {}
  /// Feeds the loss of step `step` (counted from 0 over the whole run); true: stop after it.
  bool stop_after(int step, double loss) {
    sum_ += loss;
    if (tolerance_ <= 0 || patience_ <= 0 || (step + 1) % patience_ != 0) return false;
    const double compared = window_mean_ ? sum_ / patience_ : loss;
    sum_ = 0;
    if (compared > best_ * (1.0 - tolerance_)) return true;
    best_ = std::min(best_, compared);
    return false;
  }

 private:
  double tolerance_;
  int patience_;
  bool window_mean_;
  double best_ = 1e300, sum_ = 0;
};

/// Options of the pipeline (paper defaults where the paper gives them, MODEL.md 8).
struct pipeline_options {
  pipeline_stages stages{};
  int window = 256;                 ///< estimation window (the estimator's training size)
  int stride = 64;                  ///< window step (overlap 192)
  int finetune_steps = 5000;        ///< paper: 5000
  float finetune_learning_rate = 7.5e-4f;  ///< paper: Adam 7.5e-4
  refine_options refine{};          ///< per-texel stage (steps, learning rate, ...)
  render_options render{};          ///< culling, double precision etc. for every image loss
  /// BRDF terms the fine-tune and refine losses evaluate (the full kernel by default).
  brdf_features features = all_features;
  /// When > 0: after the estimate, pick the cheapest kernel that renders the estimate within this
  /// relative tolerance (render/analysis.hpp analyse_kernel), replacing `features`.
  double auto_kernel_tolerance = 0.0;
  /// Rescale photographs and intensities to the synthetic captures' exposure first (exposure.hpp),
  /// so that the maps do not depend on the photographs' units.
  bool normalise_exposure = true;
  /// Fine-tune early stopping: stop when the loss improved by less than this fraction over the
  /// last `finetune_patience` steps (0: run every step). With crops the compared loss is the mean
  /// over each window of `finetune_patience` steps (one crop's loss is noisy).
  double finetune_min_improvement = 0.0;
  int finetune_patience = 200;
  /// Fine-tune learning-rate warm-up: the rate ramps up linearly over this many steps (0: none).
  int finetune_warmup = 0;
  /// Fine-tune learning-rate decay: the rate halves every this many steps (0: constant).
  int finetune_half_life = 0;
  /// Fine-tune on random crops (mini-batches) of this many latent cells (32 texels each) per side
  /// instead of the whole tile (0: whole tile, the paper). Each step decodes the crop plus a
  /// one-cell margin (so the crop's maps equal the whole decode's, exactly) and evaluates the loss
  /// on the crop only. Crop starts are uniform over [-(k-1), cells-1] and clipped to the tile, so
  /// every texel is in a crop equally often; each crop's gradient is weighted by its share of a
  /// full k x k crop, so clipped crops count per texel as much as whole ones.
  int finetune_crop = 0;
  std::uint64_t finetune_seed = 1;  ///< seed of the crop positions (a resumed run draws the same)
  /// Fine-tune divergence guard: when a step's loss exceeds this factor times the lowest loss so
  /// far, the decoder and Adam go back to their last snapshot (taken every `finetune_guard_every`
  /// steps) and the learning rate halves; so does a NaN or infinite loss. With crops the guard
  /// compares the mean crop loss of each `finetune_guard_every` steps instead of single steps
  /// (one crop's loss says little about the tile), the first snapshot is the start, and the
  /// fine-tune ends with the last snapshot's decoder when the whole tile renders better with it.
  /// The snapshot costs a copy of the decoder's weights and Adam moments (3x the decoder's size)
  /// every `finetune_guard_every` steps. Large learning rates diverge on
  /// some materials after hundreds of good steps; this keeps what those steps gained. 0: off.
  double finetune_guard = 1.5;
  int finetune_guard_every = 50;   ///< steps between the guard's snapshots
  /// Check-point folder (empty: none). With `resume`, completed stages are read back and the
  /// fine-tune continues from its last saved step.
  std::filesystem::path checkpoint_dir;
  bool resume = false;
  double checkpoint_seconds = 60;   ///< time between fine-tune check-points
  std::function<void(const std::string& stage, const optimisation_progress&)> progress;
  int progress_every = 50;
  /// Called at every fine-tune step with the number of updates done so far, the step's image loss
  /// (with `finetune_crop`, the crop's: noisy) and a function that returns the
  /// whole decoded maps at that point (before the step's update; with crops it decodes the whole
  /// tile, so call it only when needed). For monitoring and for studies that read many step counts
  /// off one run (bench/sweep.cpp). Null: nothing is called.
  std::function<void(int updates, double loss, const std::function<material_maps()>& maps)> finetune_observer;
};

/// What one stage did.
struct stage_report {
  std::string name;
  bool ran = false;
  bool resumed = false;   ///< read back from a check-point instead of computed
  int steps = 0;
  double loss = 0;        ///< image loss against the photographs after the stage
  double seconds = 0;
  double evaluated_fraction = 1.0;  ///< refine: fraction of texel-steps evaluated (freezing)
  int restarts = 0;                 ///< fine-tune: times the divergence guard went back and halved the rate
};

/// The result: the map set and a report per stage.
struct pipeline_result {
  material_maps maps;
  std::vector<stage_report> stages;
  /// The maps after the fine-tune stage (before refine), when that stage ran: the paper's Table 1
  /// reports both.
  std::optional<material_maps> after_finetune;
  /// The kernel the fine-tune and refine losses used (options.features, or the automatic choice).
  brdf_features features = all_features;
  /// The factor photographs and intensities were multiplied by (1 without normalisation).
  double exposure_scale = 1.0;
};

namespace pipeline_detail {

/// `maps` mirrored out to `width` x `height` (at the right and bottom).
inline material_maps pad_maps(const material_maps& maps, int width, int height) {
  material_maps out(width, height);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < height; ++y) {
      const int sy = mirror_index(y, maps.height());
      for (int x = 0; x < width; ++x) out.at(k, x, y) = maps.at(k, mirror_index(x, maps.width()), sy);
    }
  return out;
}

/// The auto-encoder's latent code of `maps` (MODEL.md 8.2): the maps mirrored out to a multiple of
/// the network's size multiple, taken to network space and encoded in inference mode without
/// gradients. Leaves the auto-encoder in inference mode.
template <class P>
tensor<AutoEncoder<P>::latent_channels, float> encode_maps(AutoEncoder<P>& autoencoder, const material_maps& maps) {
  constexpr int M = AutoEncoder<P>::size_multiple;
  const int Wp = (maps.width() + M - 1) / M * M, Hp = (maps.height() + M - 1) / M * M;
  tensor<parameter_count, float> u(1, Hp, Wp);
  network_space::maps_to_network(pad_maps(maps, Wp, Hp), u, 0);
  autoencoder.set_training(false);
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  return autoencoder.encode(t, t.leaf(u)).value.clone();
}

/// A window of latent cells: rows [r0, r1) x columns [c0, c1).
struct latent_window {
  int r0 = 0, r1 = 0, c0 = 0, c1 = 0;
};

/// The fine-tune crop of k_y x k_x cells whose start is (start_y, start_x), clipped to the
/// cells_y x cells_x latent grid; starts range over [-(k-1), cells-1] so that every cell is in
/// exactly k of them per axis.
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

/// Scratch buffers of decoder_crop_step, reused from step to step.
struct crop_scratch {
  loss_targets targets;
  material_maps gradient;
};

/// One fine-tune pass on a crop: decodes the window's latent cells plus a one-cell margin inside
/// the grid (with 4x4 stride-2 transposed convolutions an output texel depends on the latent cells
/// within one cell of its own, so the window's maps equal the whole decode's), evaluates the image
/// loss on the window's texels inside the W x H material, puts its gradient, weighted by the
/// window's share of a whole k_y x k_x crop, on the decoder's parameters (accumulating) and returns
/// the window's loss (the mean over its texels). Summed over every start of clipped_window, the
/// gradients are (W H / 32^2) times the whole tile's.
template <brdf_features F, class P>
double decoder_crop_step(ad::tape& t, AutoEncoder<P>& autoencoder,
                         const tensor<AutoEncoder<P>::latent_channels, float>& z, const latent_window& win, int k_y, int k_x,
                         int width, int height, const capture& cap, const loss_targets& targets, const render_options& render,
                         crop_scratch& scratch) {
  constexpr int M = AutoEncoder<P>::size_multiple;
  const int cells_y = z.height(), cells_x = z.width();
  const int mr = win.r0 > 0 ? 1 : 0, mc = win.c0 > 0 ? 1 : 0;
  const int lr1 = std::min(win.r1 + 1, cells_y), lc1 = std::min(win.c1 + 1, cells_x);
  auto y = autoencoder.decode(t, t.leaf(z.tile(win.r0 - mr, win.c0 - mc, lr1 - (win.r0 - mr), lc1 - (win.c0 - mc)).clone()));
  const int y0 = win.r0 * M, x0 = win.c0 * M;
  const int h = std::min(win.r1 * M, height) - y0, w = std::min(win.c1 * M, width) - x0;
  if (h <= 0 || w <= 0) throw std::invalid_argument("decoder_crop_step: the window holds no texel of the material");
  const auto u_view = y.value.tile(mr * M, mc * M, h, w);
  const material_maps m = network_space::network_to_maps(u_view, 0);
  crop_loss_targets(targets, x0, y0, w, h, scratch.targets);
  if (scratch.gradient.width() != w || scratch.gradient.height() != h) scratch.gradient = material_maps(w, h);
  const double loss = loss_and_gradient<F>(m, cap, scratch.targets, &scratch.gradient, tile_placement{width, height, x0, y0}, render);
  auto g_view = y.grad.tile(mr * M, mc * M, h, w);
  network_space::add_network_gradient(u_view, 0, scratch.gradient, double(h) * w / (double(k_y) * k_x * M * M), g_view);
  t.backward();
  return loss;
}

}  // namespace pipeline_detail

/// Runs the pipeline on one capture. `estimator` and `autoencoder` must hold trained weights for
/// the stages that use them. `masks` (optional, one 1-channel image per photograph, 0 = left out,
/// e.g. clipped pixels: data/photo_io.hpp) keep pixels out of every image loss (fine-tune, refine,
/// the stages' reported losses); the estimator still sees whole photographs.
template <class EstimatorPreset, class AutoEncoderPreset>
pipeline_result run_pipeline(const capture& cap, const std::vector<image>& photos, EstimationNet<EstimatorPreset>& estimator,
                             AutoEncoder<AutoEncoderPreset>& autoencoder, const pipeline_options& o,
                             const std::vector<image>& masks = {}) {
  namespace fs = std::filesystem;
  using clock = std::chrono::steady_clock;
  if (photos.empty() || photos.size() != cap.images.size())
    throw std::invalid_argument("run_pipeline: need one photograph per configuration");
  if (o.normalise_exposure) {
    capture scaled_cap = cap;
    std::vector<image> scaled_photos = photos;
    const double s = exposure_scale(cap);
    apply_exposure(scaled_cap, scaled_photos, s);
    pipeline_options so = o;
    so.normalise_exposure = false;
    pipeline_result r = run_pipeline(scaled_cap, scaled_photos, estimator, autoencoder, so, masks);
    r.exposure_scale = s;
    return r;
  }
  const int W = photos[0].width(), H = photos[0].height();
  const loss_targets targets = make_loss_targets(photos, masks);
  brdf_features features = o.features;
  auto image_loss = [&](const material_maps& m) {
    return with_features(features, [&]<brdf_features F>() { return loss_and_gradient<F>(m, cap, targets, nullptr, {}, o.render); });
  };
  const bool checkpoints = !o.checkpoint_dir.empty();
  if (checkpoints) fs::create_directories(o.checkpoint_dir);
  auto stage_dir = [&](const char* name) { return o.checkpoint_dir / name; };
  auto saved = [&](const char* name) { return checkpoints && o.resume && fs::exists(stage_dir(name) / "diffuse.exr"); };
  pipeline_result result;

  // 1. Estimate (MODEL.md 8.1).
  material_maps maps;
  {
    stage_report r{"estimate"};
    const auto t0 = clock::now();
    if (saved("estimate")) {
      maps = read_maps(stage_dir("estimate"));
      r.resumed = true;
    } else if (o.stages.estimate) {
      maps = estimate_by_windows(photos, o.window, o.stride, [&](const std::vector<image>& crops) { return estimator.estimate(crops); },
                                 [&](int done, int total) {
                                   if (!o.progress) return;
                                   optimisation_progress p;
                                   p.step = done;
                                   p.steps = total;
                                   p.seconds = seconds_since(t0);
                                   p.steps_per_second = done / std::max(p.seconds, 1e-9);
                                   p.seconds_left = (total - done) / std::max(p.steps_per_second, 1e-9);
                                   o.progress("estimate", p);
                                 });
      if (checkpoints) write_maps(maps, stage_dir("estimate"), false);
    } else {
      maps = initial_guess(cap, photos, {}, masks);
    }
    r.ran = o.stages.estimate;
    if (o.auto_kernel_tolerance > 0) features = analyse_kernel(maps, cap, o.auto_kernel_tolerance).features;
    r.loss = image_loss(maps);
    r.seconds = seconds_since(t0);
    result.stages.push_back(r);
  }

  // 2. Encode (8.2) and 3. fine-tune the decoder (8.3).
  if (o.stages.encode) {
    stage_report enc{"encode"}, fine{"finetune"};
    const auto t0 = clock::now();
    const auto z = pipeline_detail::encode_maps(autoencoder, maps);
    enc.ran = true;
    enc.seconds = seconds_since(t0);
    auto decode_maps = [&](ad::tape& t) {
      auto y = autoencoder.decode(t, t.leaf(z));
      return y;
    };
    // The decoder's maps of the whole tile, without gradients (cropped to the material).
    auto whole_maps = [&]() {
      ad::tape t;
      ad::tape::no_grad_guard guard(t);
      return network_space::network_to_maps(decode_maps(t).value.tile(0, 0, H, W), 0);
    };
    maps = whole_maps();
    enc.loss = image_loss(maps);
    result.stages.push_back(enc);

    if (o.stages.finetune) {
      const auto t1 = clock::now();
      autoencoder.freeze_encoder(true);
      if (o.finetune_warmup < 0 || o.finetune_half_life < 0 || o.finetune_crop < 0)
        throw std::invalid_argument("run_pipeline: fine-tune warm-up, half-life and crop must not be negative");
      if (o.finetune_guard < 0 || (o.finetune_guard > 0 && (o.finetune_guard <= 1 || o.finetune_guard_every < 1)))
        throw std::invalid_argument("run_pipeline: finetune_guard must be 0 (off) or above 1, with finetune_guard_every >= 1");
      const auto schedule = (o.finetune_half_life > 0
                                 ? nn::learning_rate_schedule::exponential_decay(o.finetune_learning_rate, 0.5, o.finetune_half_life)
                                 : nn::learning_rate_schedule::constant(o.finetune_learning_rate))
                                .with_warmup(o.finetune_warmup);
      nn::adam adam(schedule);
      autoencoder.for_each_decoder_parameter([&](nn::parameter& p) { adam.add(p); });
      const fs::path ft_dir = checkpoints ? stage_dir("finetune") : fs::path();
      int first = 0;
      double lr_scale = 1.0, best_loss = std::numeric_limits<double>::infinity();  // divergence guard
      if (checkpoints && o.resume && fs::exists(ft_dir / "decoder.safetensors")) {
        nn::load_weights(ft_dir / "decoder.safetensors", autoencoder);
        const fs::path state_file = ft_dir / "adam.safetensors";
        const auto state = nn::read_safetensors(state_file);
        adam.for_each_state([&](nn::parameter& p, aligned_buffer<float>& m, aligned_buffer<float>& v, long& count) {
          for (auto* buf : {&m, &v}) {
            const std::string name = p.name + (buf == &m ? ".m" : ".v");
            const auto* entry = state.find(name);
            if (!entry || entry->count() != buf->size() || entry->dtype != "F32")
              throw std::runtime_error(state_file.string() + ": missing or mismatched Adam state '" + name + "'");
            std::memcpy(static_cast<void*>(buf->data()), state.bytes(*entry).data(), buf->size() * sizeof(float));
          }
          count = 0;
        });
        for (const auto& [key, value] : state.metadata) {
          if (key == "step") first = std::stoi(value);
          if (key == "lr_scale") lr_scale = std::stod(value);
          if (key == "best_loss") best_loss = std::stod(value);
        }
        adam.schedule = schedule.scaled(lr_scale);
        adam.for_each_state([&](nn::parameter&, aligned_buffer<float>&, aligned_buffer<float>&, long& count) { count = first; });
        adam.set_steps(first);
        fine.resumed = true;
      }
      material_maps grad(W, H);
      auto last_checkpoint = clock::now();
      int step = first;
      ad::tape t;
      // Crops: k x k latent cells (k = finetune_crop), only where the tile has more cells than that.
      const int cells_y = z.height(), cells_x = z.width();
      const int crop_y = o.finetune_crop > 0 && o.finetune_crop < cells_y ? o.finetune_crop : cells_y;
      const int crop_x = o.finetune_crop > 0 && o.finetune_crop < cells_x ? o.finetune_crop : cells_x;
      const bool cropping = crop_y < cells_y || crop_x < cells_x;
      early_stopping stopper(o.finetune_min_improvement, o.finetune_patience, cropping);  // crop losses are noisy: window means
      pipeline_detail::crop_scratch scratch;
      // Divergence guard: a snapshot of the decoder's weights and Adam's state, and its loss. The
      // whole tile's loss is checked every step; crop losses are noisy (each is one window's), so
      // with crops the guard checks the mean loss of every finetune_guard_every steps instead (a
      // whole-tile decode would cost as much as the crops on large materials).
      const bool guarding = o.finetune_guard > 0;
      nn::adam::snapshot snapshot;
      double snapshot_loss = 0;
      // Returns true when `guard_loss` (NaN and infinity included) exceeds the guard: the weights
      // and Adam's state go back to the snapshot and the learning rate halves.
      auto guard_restarts = [&](double guard_loss, bool may_snapshot) {
        if (!(guard_loss <= o.finetune_guard * best_loss) && !snapshot.empty()) {
          adam.restore(snapshot);  // back to weights whose loss was near the best, at half the rate
          adam.zero_grad();
          best_loss = snapshot_loss;  // the baseline from here (the best may have fallen since the snapshot)
          lr_scale *= 0.5;
          adam.schedule = schedule.scaled(lr_scale);
          ++fine.restarts;
          return true;
        }
        best_loss = std::min(best_loss, guard_loss);
        if (may_snapshot && guard_loss <= 1.1 * best_loss) {
          snapshot = adam.take_snapshot();
          snapshot_loss = guard_loss;
        }
        return false;
      };
      double window_sum = 0;  // crops: the losses of the guard's current window of steps
      int window_steps = 0;
      if (guarding && cropping) {  // the start, at the whole tile's loss, is the first place to come back to
        snapshot = adam.take_snapshot();
        snapshot_loss = first == 0 ? enc.loss : best_loss;
        best_loss = std::min(best_loss, snapshot_loss);
      }
      for (; step < o.finetune_steps; ++step) {
        t.clear();
        double loss = 0;
        bool restarted = false;
        if (!cropping) {
          auto y = decode_maps(t);
          const auto u_view = y.value.tile(0, 0, H, W);
          const material_maps m = network_space::network_to_maps(u_view, 0);
          loss = with_features(features, [&]<brdf_features F>() {
            return loss_and_gradient<F>(m, cap, targets, &grad, {}, o.render);
          });
          if (o.finetune_observer) o.finetune_observer(step, loss, [&]() { return m; });
          if (guarding) restarted = guard_restarts(loss, (step - first) % o.finetune_guard_every == 0);
          if (!restarted) {
            auto g_view = y.grad.tile(0, 0, H, W);
            network_space::add_network_gradient(u_view, 0, grad, 1.0, g_view);
            t.backward();
          }
        } else {
          const auto win = pipeline_detail::random_window(cells_y, cells_x, crop_y, crop_x, o.finetune_seed, step);
          loss = with_features(features, [&]<brdf_features F>() {
            return pipeline_detail::decoder_crop_step<F>(t, autoencoder, z, win, crop_y, crop_x, W, H, cap, targets, o.render, scratch);
          });
          if (o.finetune_observer) {  // weights not yet updated; the tape is no longer needed
            std::optional<material_maps> whole;
            o.finetune_observer(step, loss, [&]() {
              if (!whole) whole = whole_maps();
              return *whole;
            });
          }
          if (guarding) {
            window_sum += loss;
            if (++window_steps == o.finetune_guard_every) {
              restarted = guard_restarts(window_sum / window_steps, true);
              window_sum = 0;
              window_steps = 0;
            }
          }
        }
        if (!restarted) adam.step();
        if (o.progress && o.progress_every > 0 && (step + 1) % o.progress_every == 0) {
          const double s = seconds_since(t1);
          const double rate = (step + 1 - first) / std::max(s, 1e-9);
          optimisation_progress p;
          p.step = step + 1;
          p.steps = o.finetune_steps;
          p.loss = loss;
          p.seconds = s;
          p.steps_per_second = rate;
          p.seconds_left = (o.finetune_steps - step - 1) / std::max(rate, 1e-9);
          o.progress("finetune", p);
        }
        if (checkpoints && seconds_since(last_checkpoint) > o.checkpoint_seconds) {
          fs::create_directories(ft_dir);
          nn::save_weights(ft_dir / "decoder.safetensors", autoencoder);
          nn::safetensors_file state;
          adam.for_each_state([&](nn::parameter& p, aligned_buffer<float>& m1, aligned_buffer<float>& v1, long&) {
            state.add<float>(p.name + ".m", {std::int64_t(m1.size())}, m1.data(), m1.size());
            state.add<float>(p.name + ".v", {std::int64_t(v1.size())}, v1.data(), v1.size());
          });
          state.metadata.emplace_back("step", std::to_string(step + 1));
          auto exact = [](double v) {
            char text[40];
            std::snprintf(text, sizeof text, "%.17g", v);
            return std::string(text);
          };
          state.metadata.emplace_back("lr_scale", exact(lr_scale));
          state.metadata.emplace_back("best_loss", exact(best_loss));
          nn::write_safetensors(ft_dir / "adam.safetensors", state);
          last_checkpoint = clock::now();
        }
        if (stopper.stop_after(step, loss)) { ++step; break; }
      }
      maps = whole_maps();
      restrict_to_features(maps, features);  // what a reduced kernel fitted, as every renderer sees it
      fine.loss = image_loss(maps);
      if (guarding && cropping && !snapshot.empty()) {
        // The crop guard watches window means, not the tile: keep the last snapshot's decoder
        // when the whole tile renders better with it than with the last weights.
        const auto last = adam.take_snapshot();
        adam.restore(snapshot);
        material_maps snapshot_maps = whole_maps();
        restrict_to_features(snapshot_maps, features);
        const double snapshot_tile_loss = image_loss(snapshot_maps);
        if (snapshot_tile_loss < fine.loss) {
          maps = std::move(snapshot_maps);
          fine.loss = snapshot_tile_loss;
        } else {
          adam.restore(last);
        }
      }
      result.after_finetune = maps;
      fine.ran = true;
      fine.steps = step - first;
      fine.seconds = seconds_since(t1);
      result.stages.push_back(fine);
    }
  }

  // 4. Refine per texel (8.4).
  if (o.stages.refine) {
    stage_report r{"refine"};
    refine_options ro = o.refine;
    ro.render = o.render;
    if (o.progress) {
      ro.progress = [&](const optimisation_progress& p) { o.progress("refine", p); };
      if (ro.progress_every <= 0) ro.progress_every = o.progress_every;
    }
    const refine_result rr = with_features(features, [&]<brdf_features F>() { return refine<F>(maps, cap, targets, ro); });
    r.ran = true;
    r.steps = rr.steps;
    r.loss = rr.final_loss;
    r.seconds = rr.seconds;
    r.evaluated_fraction = rr.evaluated_fraction;
    result.stages.push_back(r);
  }
  result.maps = std::move(maps);
  result.features = features;
  return result;
}

}  // namespace anisocap
