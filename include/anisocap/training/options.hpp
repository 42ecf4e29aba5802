#pragma once
/// @file
/// The settings of a training run (train_options), its learning-rate schedule and the batch of
/// materials each step draws (make_batch).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/distributed.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/nn/precision.hpp"
#include "anisocap/render/sensor_noise.hpp"
#include "anisocap/training/losses.hpp"

namespace anisocap::training {

/// Settings of a training run.
struct train_options {
  std::filesystem::path out_dir;      ///< checkpoints, weights, validation.csv
  long steps = 2000;                  ///< total optimiser steps (a resumed run continues to this)
  int size = 128;                     ///< material size (square, a multiple of 64)
  int batch = 2;                      ///< materials per step
  double learning_rate = 0;           ///< 0: the paper's (estimator 5e-5, auto-encoder 1e-3)
  std::uint64_t seed = 1;             ///< run seed: initial weights and training materials
  double checkpoint_minutes = 5;      ///< wall time between checkpoints (and one at the end)
  long checkpoint_every = 0;          ///< > 0: also a checkpoint every so many steps (tests)
  long validate_every = 250;          ///< steps between validations (and one at the end)
  int validation_count = 8;           ///< validation materials
  bool resume = false;                ///< continue from out_dir/checkpoint.json
  std::filesystem::path init_weights; ///< non-empty: a fresh run starts from these weights (nn::load_matching_weights: tensors the file lacks in this shape stay as initialised, and are logged)
  double smoothness_weight = 0.1;     ///< auto-encoder: weight of the latent smoothness term
  /// Weight of the render loss against the L1 term in the training loss (map_losses); validation
  /// losses always use 1, so runs with different weights compare row for row.
  double render_weight = 1.0;
  /// Weight of the lobe widths' and rotation's L1 (lobe_l1) against the other channels' in the
  /// training loss (map_losses; `--lobe-weight`); validation losses always use 1.
  double lobe_weight = 1.0;
  /// Weight of the lobe widths' squared error in the original range (lobe_width_squared_error) in
  /// the training loss (map_losses; `--sigma-weight`, default 0: none); validation losses use 0.
  double sigma_weight = 0.0;
  /// Weight of the other maps' squared error in the original ranges (map_squared_error: a_d, a'_s,
  /// F0, the normal) in the training loss (map_losses; `--mse-weight`, default 0: none); validation
  /// losses use 0.
  double mse_weight = 0.0;
  /// Weight of a_d's terms in the training loss against the other maps' (map_losses: its L1 and,
  /// with mse_weight, its part of the squared error; `--diffuse-weight`); validation losses use 1.
  double diffuse_weight = 1.0;
  /// Weight of the shading normal's terms in the training loss against the other maps' (map_losses:
  /// its L1 and, with mse_weight, its part of the squared error; `--normal-weight`); validation
  /// losses use 1.
  double normal_weight = 1.0;
  double latent_noise = 0.1;          ///< auto-encoder: standard deviation of delta
  /// Auto-encoder: train the encoder (and its batch norm) only, against the decoder of the weights
  /// the run starts from (`--trainable encoder`): the decoder, which the pipeline fine-tunes, keeps
  /// the weights it fine-tunes well from (docs/method.md section 7). Needs init_weights or resume.
  bool encoder_only = false;
  /// Auto-encoder: set by train_autoencoder's estimator overload (`--inputs estimates`): true when
  /// the encoder reads the estimator's estimates of the materials' photos instead of the true maps.
  /// Recorded in checkpoint.json ("inputs") and kept on resume.
  bool inputs_are_estimates = false;
  long stop_after = -1;               ///< >= 0: return after this step as if killed (tests)
  double progress_seconds = 10;       ///< wall time between progress lines
  material_mix mix = material_mix::original;  ///< families of the training and validation materials (not extended)
  /// Families drawn more often than `mix` draws them (a curriculum, `--emphasis`): a share
  /// `emphasis_share` of the training and validation materials is drawn from these kinds, uniformly,
  /// the rest from `mix` (material_options_for_seed). Empty: `mix` alone. Never a held-out family.
  std::vector<material_kind> emphasis;
  double emphasis_share = 0.5;  ///< fraction of the materials drawn from `emphasis`, in [0, 1]
  /// Sensor noise on the training photographs (`--shot-noise`, `--read-noise`; render/sensor_noise.hpp):
  /// each training material's photographs get noise at a fraction of these levels drawn uniformly
  /// in [0, 1] per material (training_input_noise), so that a run sees exact renders and noisy
  /// ones alike. Validation photographs stay exact, so runs compare row for row. None: exact renders.
  sensor_noise input_noise;
  /// A cosine decay of the learning rate at the end of a run (`--lr-decay-from/--lr-decay-to/--lr-end`):
  /// with lr_decay_to > 0 the rate is constant up to optimiser step lr_decay_from, then falls along half
  /// a cosine to lr_end times itself at step lr_decay_to, and stays there
  /// (nn::learning_rate_schedule::cosine_decay). 0, 0: a constant rate. A resume keeps the saved
  /// decay unless it is given another one (logged and recorded in checkpoint.json).
  long lr_decay_from = 0;
  long lr_decay_to = 0;               ///< last step of the decay; 0: no decay
  double lr_end = 0.05;               ///< the rate after the decay, as a fraction of the learning rate
  /// A linear warm-up of the learning rate (`--lr-warmup`): optimiser step s < lr_warmup runs at
  /// (s + 1) / lr_warmup of its scheduled rate (nn::learning_rate_schedule::with_warmup). A run that
  /// starts from trained weights (init_weights) starts Adam's moments at zero, and its first steps at
  /// the full rate move every weight by about the rate: the validation loss jumps and takes thousands
  /// of steps to come back. 0: none. Recorded in checkpoint.json; a resume must give the same value.
  long lr_warmup = 0;
  /// A second linear warm-up (`--lr-rewarmup N --lr-rewarmup-from S`): optimiser step s in [S, S + N)
  /// runs at (s - S + 1) / N of its scheduled rate (nn::learning_rate_schedule::with_rewarmup). For a
  /// run resumed with its optimiser state and a new decay: without it, the first step after the
  /// resume jumps from the rate the last decay ended at (--lr-end of it) to the full rate. Like the
  /// decay it is a function of the step, recorded in checkpoint.json and kept by a resume that does
  /// not name another. 0: none.
  long lr_rewarmup = 0;
  long lr_rewarmup_from = -1;  ///< the re-warm-up's first step; required with lr_rewarmup > 0
  bool prefetch = true;               ///< build the next step's samples on a second thread during each step (same results)
  /// Data-parallel steps: each material of a step's batch is a part whose gradient is computed
  /// alone (the auto-encoder's batch norm with the whole batch's statistics, summed over the parts),
  /// and the parts' gradients and losses are added in ordered_sum's fixed tree (core/distributed.hpp).
  /// The parts are dealt out over the ranks of the communicator the run is given, and every rank
  /// count, one process included, gives the same weights bit for bit. Always on over more than one
  /// rank. Off: the whole batch runs as one pass (the weights then differ from a data-parallel
  /// run's in rounding only). On by default: the estimator trains 1.3-2.5x faster material by
  /// material (a batch's photographs in one pass leave the caches); off in autoencoder(), whose
  /// small latent makes one pass per material 18% slower (docs/scaling.md).
  bool data_parallel = true;
  /// Operand precision of the networks' convolutions (nn/precision.hpp): fp32, or bf16 with FP32
  /// accumulation and FP32 master weights in Adam (builds for CPUs with AVX-512 BF16). Recorded in
  /// checkpoint.json when bf16; a run may resume in the other precision, as the weights stay FP32.
  nn::precision precision = nn::precision::fp32;
  std::function<void(const std::string&)> log = [](const std::string& s) { std::fprintf(stderr, "%s\n", s.c_str()); };

  /// Throws std::invalid_argument for impossible values (before a run creates anything), naming the
  /// fields as train_options::<field> (the program maps them to its flags).
  void validate() const {
    if (steps < 1) throw std::invalid_argument("train_options::steps must be at least 1, got " + std::to_string(steps));
    nn::require_available(precision, "train_options::precision");
    if (batch < 1) throw std::invalid_argument("train_options::batch (materials per step) must be at least 1, got " + std::to_string(batch));
    if (!(learning_rate >= 0) || !std::isfinite(learning_rate))
      throw std::invalid_argument("train_options::learning_rate must be finite and not negative (0: the paper's)");
    if (!(checkpoint_minutes > 0) || validate_every < 1 || validation_count < 1)
      throw std::invalid_argument("train_options::checkpoint_minutes, train_options::validate_every and train_options::validation_count must be positive");
    if (!(smoothness_weight >= 0) || !std::isfinite(smoothness_weight) || !(latent_noise >= 0) || !std::isfinite(latent_noise))
      throw std::invalid_argument("train_options::smoothness_weight and train_options::latent_noise must be finite and not negative");
    if (!(render_weight >= 0) || !std::isfinite(render_weight))
      throw std::invalid_argument("the render-loss weight (train_options::render_weight) must be finite and not negative");
    if (!(lobe_weight > 0) || !std::isfinite(lobe_weight))
      throw std::invalid_argument("the lobe L1 weight (train_options::lobe_weight) must be finite and positive");
    if (!(sigma_weight >= 0) || !std::isfinite(sigma_weight))
      throw std::invalid_argument("the lobe-width squared-error weight (train_options::sigma_weight) must be finite and not negative");
    if (!(mse_weight >= 0) || !std::isfinite(mse_weight))
      throw std::invalid_argument("the maps' squared-error weight (train_options::mse_weight) must be finite and not negative");
    if (!(diffuse_weight > 0) || !std::isfinite(diffuse_weight))
      throw std::invalid_argument("a_d's loss weight (train_options::diffuse_weight) must be finite and positive");
    if (!(normal_weight > 0) || !std::isfinite(normal_weight))
      throw std::invalid_argument("the normal's loss weight (train_options::normal_weight) must be finite and positive");
    if (lr_decay_to != 0 || lr_decay_from != 0) {
      if (!(lr_decay_from >= 0 && lr_decay_to > lr_decay_from))
        throw std::invalid_argument("the learning-rate decay must end after it starts (0 <= train_options::lr_decay_from < train_options::lr_decay_to), got " +
                                    std::to_string(lr_decay_from) + " and " + std::to_string(lr_decay_to));
      if (!(lr_end >= 0 && lr_end <= 1))
        throw std::invalid_argument("the final learning-rate fraction (train_options::lr_end) must be between 0 and 1");
    }
    if (lr_warmup < 0)
      throw std::invalid_argument("the learning-rate warm-up (train_options::lr_warmup) must not be negative, got " + std::to_string(lr_warmup));
    if (lr_rewarmup < 0)
      throw std::invalid_argument("the learning-rate re-warm-up (train_options::lr_rewarmup) must not be negative, got " + std::to_string(lr_rewarmup));
    if (lr_rewarmup > 0 && lr_rewarmup_from < 0)
      throw std::invalid_argument("a learning-rate re-warm-up (train_options::lr_rewarmup) needs its first step (train_options::lr_rewarmup_from)");
    if (!(emphasis_share >= 0 && emphasis_share <= 1))
      throw std::invalid_argument("the emphasis share (train_options::emphasis_share) must be between 0 and 1");
    if (!(input_noise.shot >= 0 && std::isfinite(input_noise.shot)) || !(input_noise.read >= 0 && std::isfinite(input_noise.read)))
      throw std::invalid_argument("the training inputs' sensor noise (train_options::input_noise.shot, train_options::input_noise.read) must be finite and not negative");
    for (material_kind k : emphasis)
      if (is_held_out(k))
        throw std::invalid_argument(std::string("training: train_options::emphasis names the held-out family '") + material_kind_name(k) +
                                    "', which training never draws");
  }

  /// The training loss's weights (map_losses).
  loss_weights loss() const { return {render_weight, lobe_weight, sigma_weight, mse_weight, diffuse_weight, normal_weight}; }

  /// The auto-encoder's defaults: 4 materials per step (its steps are cheaper than the estimator's),
  /// the whole batch in one pass (data_parallel off).
  static train_options autoencoder() {
    train_options o;
    o.batch = 4;
    o.data_parallel = false;
    return o;
  }
};

/// The learning-rate schedule of a run at base rate `rate`: constant, or with o's cosine decay,
/// after o's warm-up.
inline nn::learning_rate_schedule training_schedule(double rate, const train_options& o) {
  return (o.lr_decay_to > 0 ? nn::learning_rate_schedule::cosine_decay(rate, o.lr_decay_from, o.lr_decay_to, o.lr_end)
                            : nn::learning_rate_schedule::constant(rate))
      .with_warmup(o.lr_warmup)
      .with_rewarmup(o.lr_rewarmup > 0 ? o.lr_rewarmup_from : 0, o.lr_rewarmup);
}

/// The procedural options of the training or validation material of seed `seed` under o.mix and
/// o.emphasis: with an emphasis, hash64(seed ^ salt) picks whether the material is one of the
/// emphasised kinds (probability o.emphasis_share) and which one (uniformly); otherwise, and for the
/// other materials, the kind is drawn from o.mix as without an emphasis.
inline procedural_options material_options_for_seed(const train_options& o, std::uint64_t seed) {
  procedural_options options = training_material_options(o.mix);
  if (o.emphasis.empty()) return options;
  const std::uint64_t h = hash64(seed ^ 0x656d706861736973ULL);
  if (double(h >> 11) * 0x1.0p-53 < o.emphasis_share) options.kind = o.emphasis[hash64(h) % o.emphasis.size()];
  return options;
}

/// The sensor noise training material `seed`'s photographs get: o.input_noise scaled by a fraction
/// drawn uniformly in [0, 1) from the seed (none when o.input_noise is none).
inline sensor_noise training_input_noise(const train_options& o, std::uint64_t seed) {
  const double f = double(hash64(seed ^ 0x6e6f6973656c766cULL) >> 11) * 0x1.0p-53;
  return {o.input_noise.shot * f, o.input_noise.read * f};
}

/// Whether a run over `comm` takes data-parallel steps: with o.data_parallel, and always over more
/// than one rank.
inline bool steps_data_parallel(const train_options& o, const communicator& comm) { return o.data_parallel || comm.distributed(); }

/// The samples of training step `step`: entry b is the sample of training_seed(o.seed, step, b),
/// its photographs with training_input_noise.
/// The entries are built in turn; each one's renders run on every OpenMP thread (building the
/// entries side by side instead was slower on 2 cores, bench/README.md "Training throughput").
/// With `first` and `last`, only entries [first, last) (a rank's share of a data-parallel step).
inline std::vector<sample> make_batch(const train_options& o, long step, bool with_photos, int first = 0, int last = -1) {
  std::vector<sample> samples;
  if (last < 0) last = o.batch;
  for (int b = first; b < last; ++b) {
    const std::uint64_t seed = training_seed(o.seed, step, b);
    samples.push_back(make_sample(seed, o.size, with_photos, material_options_for_seed(o, seed)));
    if (with_photos) add_sensor_noise(samples.back().photos, training_input_noise(o, seed), hash64(seed ^ 0x6e6f697365ULL));
  }
  return samples;
}

}  // namespace anisocap::training
