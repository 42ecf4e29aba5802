#pragma once
/// @file
/// Training of the estimation network and the auto-encoder on procedural materials generated on
/// the fly (docs/method.md section 5-7): samples from seeds, the losses (L1 in network space + render loss, equal
/// weights; the auto-encoder adds latent smoothness), Adam, checkpoints that resume exactly, and
/// validation logged to CSV.
///
/// Randomness: every random choice is a pure function of (run seed, step, batch entry), so the
/// step number IS the random-number state: a checkpoint stores weights, Adam's moments and step
/// counts, batch-norm running statistics and the step, and a resumed run is bit-identical to an
/// uninterrupted one (tests/training/training_test.cpp). For the same reason the next step's
/// samples can be built on a second thread while the current step trains (prefetch.hpp).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <span>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include <omp.h>

#include "anisocap/nn/precision.hpp"
#include "anisocap/core/distributed.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/data/family_errors.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"
#include "anisocap/training/prefetch.hpp"

namespace anisocap::training {

/// Material seeds of training samples are below 2^62, validation seeds at or above: disjoint.
inline constexpr std::uint64_t validation_seed_base = std::uint64_t(1) << 62;

/// Material seed of batch entry b at step `step` of a run seeded `seed` (below 2^62).
inline std::uint64_t training_seed(std::uint64_t seed, long step, int b) { return hash64(seed, step, b) >> 2; }
/// Material seed of validation material i (the same for every run).
inline std::uint64_t validation_seed(int i) { return validation_seed_base + std::uint64_t(i); }

/// One training example: true maps (and in network space), the 5 input photographs of the
/// training set (docs/method.md section 6) when asked for, and the render-loss targets under the 4 render-loss
/// configurations (eq. 8).
struct sample {
  material_maps truth;                 ///< the procedural material
  tensor<parameter_count> truth_net;   ///< truth in network space (1 x H x W x 12)
  std::vector<image> photos;           ///< the 5 training inputs (empty for the auto-encoder)
  capture loss_configurations;         ///< render_loss_set
  loss_targets targets;                ///< log renders of the truth under loss_configurations
};

/// The procedural options of training and validation materials drawn from `mix`: original (the
/// eight original kinds, what every earlier run used) or training (the extended mix without
/// held_out_kinds). Throws std::invalid_argument for the extended mix, which would train on the
/// held-out families.
inline procedural_options training_material_options(material_mix mix) {
  if (mix == material_mix::extended)
    throw std::invalid_argument(
        "training: the extended mix includes the held-out families (leather, printed); train on the training mix");
  procedural_options options;
  options.mix = mix;
  return options;
}

/// The sample of material seed `seed` at size x size drawn with `options` (configurations seeded
/// from the seed too). Evaluations use it to force a family, held-out ones included.
inline sample make_sample(std::uint64_t seed, int size, bool with_photos, const procedural_options& options) {
  sample s;
  s.truth = generate_material(seed, size, size, options);
  s.truth_net = tensor<parameter_count>(1, size, size);
  network_space::maps_to_network(s.truth, s.truth_net, 0);
  if (with_photos) s.photos = render(s.truth, training_set(hash64(seed ^ 0x696e70757473ULL), size, size));
  s.loss_configurations = render_loss_set(hash64(seed ^ 0x6c6f7373ULL), size, size);
  s.targets = make_loss_targets(render(s.truth, s.loss_configurations));
  return s;
}

/// The training or validation sample of material seed `seed`, its kind drawn from `mix`
/// (training_material_options: never a held-out family).
inline sample make_sample(std::uint64_t seed, int size, bool with_photos, material_mix mix = material_mix::original) {
  return make_sample(seed, size, with_photos, training_material_options(mix));
}

/// The parts of a loss, each averaged over the batch.
struct loss_terms {
  double total = 0;       ///< what is minimised
  double l1 = 0;          ///< mean |u - u_true| in network space (unweighted)
  double lobe = 0;        ///< the lobe widths' and rotation's part of l1 (lobe_l1's, unweighted)
  double sigma = 0;       ///< mean squared error of the lobe widths in the original range (lobe_width_squared_error; unweighted)
  double mse = 0;         ///< squared error of a_d, a'_s, F0 and the normal's x, y in the original ranges (map_squared_error; unweighted)
  double diffuse = 0;     ///< a_d's part of l1 (unweighted)
  double normal = 0;      ///< the normal's part of l1 (unweighted)
  double mse_diffuse = 0; ///< a_d's part of mse (unweighted)
  double mse_normal = 0;  ///< the normal's part of mse (unweighted)
  double render = 0;      ///< render loss (sum over the 4 configurations of the mean log-image difference)
  double smoothness = 0;  ///< auto-encoder only: mean |D(z) - D(z + delta)| (unweighted)
};

/// Network-space width of the rotation weight's ramp: |u_x - u_y| (log lobe widths in network
/// space) at which the truth's lobe ratio sigma_x / sigma_y reaches 1.25, the threshold at which
/// compare_maps counts a texel as anisotropic.
inline const double rotation_ramp = 2 * std::log(1.25) / (-network_space::log_min_lobe);

/// The L1 distance of one texel's lobe parameters (network space: p predicted, q true, each indexed
/// by parameter_index) that respects the lobe's symmetries (docs/method.md section 1): the
/// rotation difference is taken modulo pi (2 in network space), (sigma_x, sigma_y, alpha) is
/// compared with both of the truth's equivalent forms and the nearer one counts, and the rotation
/// term is weighted by the truth's anisotropy, min(1, |q_x - q_y| / rotation_ramp): an isotropic
/// lobe has no rotation to learn. When g is given, adds `step` times the gradient with respect to
/// p[lobe_x], p[lobe_y] and p[rotation] into g (indexed the same way). When `form` is given, it
/// receives the truth's form that counted: 0 as is, 1 swapped.
inline double lobe_l1(const float* p, const float* q, float* g, float step, int* form = nullptr) {
  auto wrap = [](double d) { return d - 2 * std::nearbyint(d / 2); };  // into [-1, 1]: alpha modulo pi
  auto sign = [](double d) { return d > 0 ? 1.0 : (d < 0 ? -1.0 : 0.0); };
  const double w = std::min(1.0, std::abs(double(q[lobe_x]) - q[lobe_y]) / rotation_ramp);
  // Form 0: (q_x, q_y, q_a); form 1: (q_y, q_x, q_a + 1), the same lobe.
  const double dx[2] = {double(p[lobe_x]) - q[lobe_x], double(p[lobe_x]) - q[lobe_y]};
  const double dy[2] = {double(p[lobe_y]) - q[lobe_y], double(p[lobe_y]) - q[lobe_x]};
  const double da[2] = {wrap(double(p[rotation]) - q[rotation]), wrap(double(p[rotation]) - q[rotation] - 1)};
  double cost[2];
  for (int f = 0; f < 2; ++f) cost[f] = std::abs(dx[f]) + std::abs(dy[f]) + w * std::abs(da[f]);
  const int f = cost[1] < cost[0] ? 1 : 0;
  if (form) *form = f;
  if (g) {
    g[lobe_x] += float(step * sign(dx[f]));
    g[lobe_y] += float(step * sign(dy[f]));
    g[rotation] += float(step * w * sign(da[f]));
  }
  return cost[f];
}

/// The squared error of one texel's lobe widths in the original range, (sigma_x - s_x)^2 +
/// (sigma_y - s_y)^2 with sigma = network_space::from_network of p's lobe channels and s the truth's
/// form `form` (lobe_l1's: 0 as is, 1 swapped). This is what compare_maps measures (there the form
/// is chosen by the squared errors of the widths and the rotation), unlike the L1 of log widths,
/// which lets broad lobes be far off. When g is given, adds `step` times the gradient with respect
/// to p[lobe_x] and p[lobe_y] into g.
inline double lobe_width_squared_error(const float* p, const float* q, int form, float* g, float step) {
  const double sx = network_space::from_network(lobe_x, p[lobe_x]), sy = network_space::from_network(lobe_y, p[lobe_y]);
  const double tx = network_space::from_network(lobe_x, q[form == 0 ? lobe_x : lobe_y]);
  const double ty = network_space::from_network(lobe_y, q[form == 0 ? lobe_y : lobe_x]);
  if (g) {  // d sigma / du = sigma (-log_min_lobe) / 2
    const double c = -network_space::log_min_lobe;
    g[lobe_x] += float(step * 2 * (sx - tx) * sx * c / 2);
    g[lobe_y] += float(step * 2 * (sy - ty) * sy * c / 2);
  }
  return (sx - tx) * (sx - tx) + (sy - ty) * (sy - ty);
}

/// Whether parameter k is one of a_d's channels (loss_weights::diffuse weighs them).
constexpr bool is_diffuse_channel(int k) { return k == diffuse_r || k == diffuse_g || k == diffuse_b; }
/// Whether parameter k is one of the shading normal's channels (loss_weights::normal weighs them).
constexpr bool is_normal_channel(int k) { return k == normal_x || k == normal_y; }

/// map_squared_error's result: the total and the parts of it that a_d's and the normal's planes make
/// (all unscaled).
struct map_squared_errors {
  double total = 0;    ///< a_d, a'_s, F0 and the normal's x, y
  double diffuse = 0;  ///< a_d's part of total (compare_maps' diffuse error)
  double normal = 0;   ///< the normal's part of total (compare_maps' normal error without its z term)
};

/// The squared error of a_d, a'_s, F0 and the shading normal's x and y in the original ranges,
/// each map's mean as compare_maps takes it: compare_maps' diffuse + specular + fresnel errors plus
/// its normal error without the z component's term (what evaluations measure of these maps, the
/// lobe widths having lobe_width_squared_error and the rotation lobe_l1), with a_d's and the
/// normal's parts. When g is given (the maps' size), adds `scale` times the gradient with respect to
/// `estimate` into g, a_d's planes' part times `diffuse_scale` and the normal's times `normal_scale`.
inline map_squared_errors map_squared_error(const material_maps& estimate, const material_maps& truth, material_maps* g,
                                            double scale, double diffuse_scale = 1, double normal_scale = 1) {
  const std::size_t n = truth.texel_count();
  // Each plane's weight in the sum: 1 / (3n) for the RGB albedos and the normal (compare_maps
  // averages over 3 components), 1 / n for F0.
  static constexpr int planes[] = {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, normal_x, normal_y, fresnel_f0};
  map_squared_errors errors;
  for (int k : planes) {
    const bool is_diffuse = is_diffuse_channel(k), is_normal = is_normal_channel(k);
    const double weight = (k == fresnel_f0 ? 1.0 : 1.0 / 3) / double(n);
    const double step = scale * weight * 2 * (is_diffuse ? diffuse_scale : is_normal ? normal_scale : 1.0);
    const float *e = estimate.plane(k), *t = truth.plane(k);
    float* gk = g ? g->plane(k) : nullptr;
    double sum = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double d = double(e[i]) - t[i];
      sum += d * d;
      if (gk) gk[i] += float(step * d);
    }
    errors.total += weight * sum;
    if (is_diffuse) errors.diffuse += weight * sum;
    if (is_normal) errors.normal += weight * sum;
  }
  return errors;
}

/// The weights of map_losses' terms in the training loss (train_options::loss()).
struct loss_weights {
  double render = 1.0;  ///< the render loss, against the L1 term (docs/method.md section 5: 1)
  double lobe = 1.0;    ///< the lobe widths' and rotation's L1 (lobe_l1) against the other channels'
  double sigma = 0.0;   ///< the lobe widths' squared error in the original range (lobe_width_squared_error)
  double mse = 0.0;     ///< the other maps' squared error in the original ranges (map_squared_error)
  double diffuse = 1.0; ///< a_d's terms (its L1 and its part of the squared error) against the other maps'
  double normal = 1.0;  ///< the normal's terms (its L1 and its part of the squared error) against the other maps'
};

/// L1 in network space plus `w.render` times the render loss (docs/method.md section 5: equal
/// weights, w.render 1), of network outputs u (one entry per sample); when grad is given, adds
/// d(loss)/du (the loss is the batch mean). The L1 of the lobe widths and the rotation is
/// lobe_l1's, which respects the lobe's symmetries, weighted by `w.lobe` in the total and the
/// gradient; the other channels take |u - u_true|, a_d's weighted by `w.diffuse` and the normal's by
/// `w.normal`. With w.sigma > 0 the total adds w.sigma times the mean over texels and the two widths
/// of lobe_width_squared_error (terms.sigma), with w.mse > 0 w.mse times map_squared_error
/// (terms.mse), its a_d and normal parts weighted by w.diffuse and w.normal. The terms are
/// unweighted; terms.total = l1 + (w.lobe - 1) lobe + (w.diffuse - 1) diffuse + (w.normal - 1)
/// normal + w.sigma sigma + w.mse (mse + (w.diffuse - 1) mse_diffuse + (w.normal - 1) mse_normal) +
/// w.render render.
///
/// `batch_size` > 0: the loss and gradient are this entry's share of a mean over `batch_size`
/// materials (data-parallel training computes each material of a batch alone, train_options::
/// data_parallel); 0: the mean over u's batch.
inline loss_terms map_losses(const tensor<parameter_count>& u, std::span<const sample> samples, tensor<parameter_count>* grad,
                             const loss_weights& w = {}, int batch_size = 0) {
  loss_terms terms;
  const int entries = u.batch(), B = batch_size > 0 ? batch_size : entries;
  if (entries != int(samples.size())) throw std::invalid_argument("map_losses: batch and sample count differ");
  const std::size_t n = std::size_t(u.height()) * u.width() * parameter_count;
  // Each channel's weight in the L1 term (the lobe channels go through lobe_l1 and w.lobe).
  float channel_weight[parameter_count];
  for (int k = 0; k < parameter_count; ++k)
    channel_weight[k] = float(is_diffuse_channel(k) ? w.diffuse : is_normal_channel(k) ? w.normal : 1.0);
  for (int b = 0; b < entries; ++b) {
    const sample& s = samples[std::size_t(b)];
    double l1 = 0, lobe = 0, sigma = 0, diffuse = 0, normal = 0;
    const double texels = double(u.height()) * u.width();
    const float step = float(1.0 / (double(n) * B)), lobe_step = float(w.lobe / (double(n) * B)),
                sigma_step = float(w.sigma / (2 * texels * B));
    for (int y = 0; y < u.height(); ++y)
      for (int x = 0; x < u.width(); ++x) {
        const float* p = u.pixel(b, y, x);
        const float* q = s.truth_net.pixel(0, y, x);
        float* g = grad ? grad->pixel(b, y, x) : nullptr;
        for (int k = 0; k < parameter_count; ++k) {
          if (k == lobe_x || k == lobe_y || k == rotation) continue;
          const float d = p[k] - q[k];
          l1 += std::abs(d);
          if (is_diffuse_channel(k)) diffuse += std::abs(d);
          if (is_normal_channel(k)) normal += std::abs(d);
          const float channel_step = step * channel_weight[k];
          if (g) g[k] += d > 0 ? channel_step : (d < 0 ? -channel_step : 0.0f);
        }
        int form = 0;
        lobe += lobe_l1(p, q, g, lobe_step, &form);
        sigma += lobe_width_squared_error(p, q, form, w.sigma > 0 ? g : nullptr, sigma_step);
      }
    terms.l1 += (l1 + lobe) / double(n) / B;
    terms.lobe += lobe / double(n) / B;
    terms.diffuse += diffuse / double(n) / B;
    terms.normal += normal / double(n) / B;
    terms.sigma += sigma / (2 * texels) / B;
    const material_maps maps = network_space::network_to_maps(u, b);
    material_maps grad_maps;
    if (grad) grad_maps = material_maps(maps.width(), maps.height());
    const double r = loss_and_gradient(maps, s.loss_configurations, s.targets, grad ? &grad_maps : nullptr);
    terms.render += r / B;
    if (grad) network_space::add_network_gradient(u, b, grad_maps, w.render / B, *grad);
    const bool mse_gradient = grad && w.mse > 0;
    material_maps grad_mse;
    if (mse_gradient) grad_mse = material_maps(maps.width(), maps.height());
    const map_squared_errors mse = map_squared_error(maps, s.truth, mse_gradient ? &grad_mse : nullptr, 1.0, w.diffuse, w.normal);
    terms.mse += mse.total / B;
    terms.mse_diffuse += mse.diffuse / B;
    terms.mse_normal += mse.normal / B;
    if (mse_gradient) network_space::add_network_gradient(u, b, grad_mse, w.mse / B, *grad);
  }
  terms.total = terms.l1 + (w.lobe - 1) * terms.lobe + (w.diffuse - 1) * terms.diffuse + (w.normal - 1) * terms.normal +
                w.sigma * terms.sigma + w.mse * (terms.mse + (w.diffuse - 1) * terms.mse_diffuse + (w.normal - 1) * terms.mse_normal) +
                w.render * terms.render;
  return terms;
}

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

  /// Throws std::invalid_argument for impossible values (before a run creates anything).
  void validate() const {
    if (steps < 1) throw std::invalid_argument("training steps (--steps) must be at least 1, got " + std::to_string(steps));
    nn::require_available(precision, "--network-precision");
    if (batch < 1) throw std::invalid_argument("the batch (--batch) must hold at least 1 material, got " + std::to_string(batch));
    if (!(learning_rate >= 0) || !std::isfinite(learning_rate))
      throw std::invalid_argument("the learning rate (--lr) must be finite and not negative (0: the paper's)");
    if (!(checkpoint_minutes > 0) || validate_every < 1 || validation_count < 1)
      throw std::invalid_argument("--checkpoint-minutes, --validate-every and --validation-count must be positive");
    if (!(smoothness_weight >= 0) || !std::isfinite(smoothness_weight) || !(latent_noise >= 0) || !std::isfinite(latent_noise))
      throw std::invalid_argument("--smoothness and --latent-noise must be finite and not negative");
    if (!(render_weight >= 0) || !std::isfinite(render_weight))
      throw std::invalid_argument("the render-loss weight (--render-weight) must be finite and not negative");
    if (!(lobe_weight > 0) || !std::isfinite(lobe_weight))
      throw std::invalid_argument("the lobe L1 weight (--lobe-weight) must be finite and positive");
    if (!(sigma_weight >= 0) || !std::isfinite(sigma_weight))
      throw std::invalid_argument("the lobe-width squared-error weight (--sigma-weight) must be finite and not negative");
    if (!(mse_weight >= 0) || !std::isfinite(mse_weight))
      throw std::invalid_argument("the maps' squared-error weight (--mse-weight) must be finite and not negative");
    if (!(diffuse_weight > 0) || !std::isfinite(diffuse_weight))
      throw std::invalid_argument("a_d's loss weight (--diffuse-weight) must be finite and positive");
    if (!(normal_weight > 0) || !std::isfinite(normal_weight))
      throw std::invalid_argument("the normal's loss weight (--normal-weight) must be finite and positive");
    if (lr_decay_to != 0 || lr_decay_from != 0) {
      if (!(lr_decay_from >= 0 && lr_decay_to > lr_decay_from))
        throw std::invalid_argument("the learning-rate decay must end after it starts (0 <= --lr-decay-from < --lr-decay-to), got " +
                                    std::to_string(lr_decay_from) + " and " + std::to_string(lr_decay_to));
      if (!(lr_end >= 0 && lr_end <= 1))
        throw std::invalid_argument("the final learning-rate fraction (--lr-end) must be between 0 and 1");
    }
    if (lr_warmup < 0)
      throw std::invalid_argument("the learning-rate warm-up (--lr-warmup) must not be negative, got " + std::to_string(lr_warmup));
    if (lr_rewarmup < 0)
      throw std::invalid_argument("the learning-rate re-warm-up (--lr-rewarmup) must not be negative, got " + std::to_string(lr_rewarmup));
    if (lr_rewarmup > 0 && lr_rewarmup_from < 0)
      throw std::invalid_argument("a learning-rate re-warm-up (--lr-rewarmup) needs its first step (--lr-rewarmup-from)");
    if (!(emphasis_share >= 0 && emphasis_share <= 1))
      throw std::invalid_argument("the emphasis share (--emphasis-share) must be between 0 and 1");
    if (!(input_noise.shot >= 0 && std::isfinite(input_noise.shot)) || !(input_noise.read >= 0 && std::isfinite(input_noise.read)))
      throw std::invalid_argument("the training inputs' sensor noise (--shot-noise, --read-noise) must be finite and not negative");
    for (material_kind k : emphasis)
      if (is_held_out(k))
        throw std::invalid_argument(std::string("training: --emphasis names the held-out family '") + material_kind_name(k) +
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

/// Weights of the network alone (what is shipped), with metadata.
template <class Net>
void save_network(const std::filesystem::path& file, Net& net, const std::string& kind) {
  nn::save_weights(file, net, {{"network", kind}, {"preset", Net::preset::name}});
}

/// Writes a checkpoint: weights, buffers, Adam moments and step counts in one safetensors file
/// (written to a temporary name and renamed), then checkpoint.json naming it (same), then removes
/// the previous checkpoint file. A crash at any point leaves a complete earlier checkpoint.
template <class Net>
void save_checkpoint(const std::filesystem::path& dir, Net& net, nn::adam& opt, long step, json info) {
  nn::safetensors_file contents;
  nn::detail::visit_weights(net, [&](auto& p) {
    contents.add<float>(p.name, std::vector<std::int64_t>(p.shape.begin(), p.shape.end()), p.value.data(), p.size());
  });
  opt.save_state(contents);
  const std::string file = "checkpoint-" + std::to_string(step) + ".safetensors";
  nn::write_safetensors(dir / file, contents);
  std::string previous;
  if (std::filesystem::exists(dir / "checkpoint.json")) {
    try {
      std::ifstream in(dir / "checkpoint.json");
      std::stringstream text;
      text << in.rdbuf();
      previous = parse_json(text.str(), (dir / "checkpoint.json").string()).at("file").get<std::string>();
    } catch (const std::exception&) {
    }
  }
  info["step"] = step;
  info["optimizer_steps"] = opt.steps();
  info["file"] = file;
  info["rng"] = "all randomness is a function of (seed, step): the step is the RNG state";
  const auto temporary = dir / "checkpoint.json.tmp";
  {
    std::ofstream out(temporary);
    out << info.dump(2) << "\n";
    if (!out) throw std::runtime_error((dir / "checkpoint.json").string() + ": cannot write the checkpoint description");
  }
  std::filesystem::rename(temporary, dir / "checkpoint.json");
  if (!previous.empty() && previous != file) std::filesystem::remove(dir / previous);
}

/// The contents of dir/checkpoint.json (written by save_checkpoint). Throws std::runtime_error
/// naming the file when it is missing, malformed or lacks "file", "step" or "optimizer_steps".
inline json read_checkpoint_description(const std::filesystem::path& dir) {
  const auto description = dir / "checkpoint.json";
  std::ifstream in(description);
  if (!in) throw std::runtime_error(description.string() + ": no checkpoint to resume from");
  std::stringstream text;
  text << in.rdbuf();
  json object = parse_json(text.str(), description.string());
  if (!object.is_object()) throw std::runtime_error(description.string() + ": not a checkpoint description (a JSON object)");
  for (const char* key : {"file", "step", "optimizer_steps"})
    if (!object.contains(key) || (std::string_view(key) == "file" ? !object.at(key).is_string() : !object.at(key).is_number()))
      throw std::runtime_error(description.string() + ": missing or malformed \"" + key + "\"");
  return object;
}

/// Restores the checkpoint that `object` (dir/checkpoint.json, read_checkpoint_description)
/// describes; returns its step. Throws std::runtime_error naming the file when it is missing,
/// malformed or does not match the network.
template <class Net>
long load_checkpoint(const std::filesystem::path& dir, const json& object, Net& net, nn::adam& opt) {
  const auto file = dir / object.at("file").get<std::string>();
  nn::load_weights(file, net);
  const nn::safetensors_file contents = nn::read_safetensors(file);
  opt.load_state(contents, file.string());
  opt.set_steps(object.at("optimizer_steps").get<long>());
  return object.at("step").get<long>();
}

/// Validation summary: mean losses and per-parameter errors (compare_maps, original ranges;
/// rotation_anisotropic is the mean over the materials that have anisotropic texels).
struct validation_result {
  loss_terms loss;          ///< mean over the validation materials
  parameter_errors errors;  ///< mean over the validation materials
};

/// The estimator's network-space maps for one sample (no gradients). The inference tape is kept
/// per thread across calls (training and validation samples share one size), so that every call
/// after the first reuses its memory instead of faulting in fresh pages.
template <class Net>
tensor<parameter_count> estimator_output(Net& net, const sample& s) {
  static thread_local ad::retained_tape scratch;
  ad::tape& t = scratch.fresh();
  ad::tape::no_grad_guard guard(t);
  const int H = s.truth.height(), W = s.truth.width();
  auto x = t.make_variable<Net::inputs>(int(s.photos.size()), H, W, false);
  for (std::size_t i = 0; i < s.photos.size(); ++i) network_space::photo_to_network(s.photos[i], x.value, int(i));
  auto y = net.forward(t, x, int(s.photos.size()));
  tensor<parameter_count> out(1, H, W);
  std::copy_n(y.value.data(), out.size(), out.data());
  return out;
}

/// The auto-encoder's reconstruction of one sample (running batch-norm statistics, no gradients):
/// D(E(m)) of the true maps, or of `input` (network space, the sample's size) when given.
/// Its inference tape is kept per thread across calls, as estimator_output's.
template <class Net>
tensor<parameter_count> autoencoder_output(Net& net, const sample& s, const tensor<parameter_count>* input = nullptr) {
  static thread_local ad::retained_tape scratch;
  ad::tape& t = scratch.fresh();
  ad::tape::no_grad_guard guard(t);
  net.set_training(false);
  auto x = t.leaf(input ? *input : s.truth_net);
  auto y = net.decode(t, net.encode(t, x));
  net.set_training(true);
  tensor<parameter_count> out(1, s.truth.height(), s.truth.width());
  std::copy_n(y.value.data(), out.size(), out.data());
  return out;
}

/// Validation of either network on a run's o.validation_count validation materials of
/// o.size x o.size, drawn as its training materials are (material_options_for_seed).
template <class Net, class Output>
validation_result validate(Net& net, const train_options& o, bool with_photos, Output output) {
  const int count = o.validation_count;
  validation_result r;
  std::vector<material_errors> errors;
  for (int i = 0; i < count; ++i) {
    std::vector<sample> one;
    const std::uint64_t seed = validation_seed(i);
    one.push_back(make_sample(seed, o.size, with_photos, material_options_for_seed(o, seed)));
    const auto u = output(net, one[0]);
    const loss_terms l = map_losses(u, one, nullptr);
    r.loss.total += l.total / count;
    r.loss.l1 += l.l1 / count;
    r.loss.render += l.render / count;
    material_errors m;
    m.errors = compare_maps(network_space::network_to_maps(u, 0), one[0].truth);
    errors.push_back(m);
  }
  r.errors = average_errors(errors).mean;
  return r;
}

namespace detail {

/// Keeps the rows of a CSV whose first field (a step) is at most `step` (a resumed run rewrites
/// the validations a killed run made after its last checkpoint).
inline void truncate_csv(const std::filesystem::path& file, long step) {
  std::ifstream in(file);
  if (!in) return;
  std::string line, kept;
  bool header = true;
  while (std::getline(in, line)) {
    if (header || (!line.empty() && std::stol(line.substr(0, line.find(','))) <= step)) kept += line + "\n";
    header = false;
  }
  in.close();
  std::ofstream(file) << kept;
}

/// Appends one validation row (writing the header first when the file is new).
inline void append_validation(const std::filesystem::path& file, long step, double train_loss, const validation_result& v) {
  const bool fresh = !std::filesystem::exists(file);
  std::ofstream out(file, std::ios::app);
  if (fresh)
    out << "step,train_loss,val_loss,val_l1,val_render,mse_diffuse,mse_specular,mse_normal,mse_lobes,mse_rotation,"
           "mse_fresnel,mse_rotation_anisotropic\n";
  char row[512];
  std::snprintf(row, sizeof row, "%ld,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g\n", step, train_loss, v.loss.total,
                v.loss.l1, v.loss.render, v.errors.diffuse, v.errors.specular, v.errors.normal, v.errors.lobes,
                v.errors.rotation, v.errors.fresnel, v.errors.rotation_anisotropic);
  out << row;
}

/// A setting as a checkpoint writes it: strings as they are, whole numbers without a fraction.
inline std::string setting_text(const json& value) {
  if (value.is_string()) return value.get<std::string>();
  if (value.is_number()) {
    const double v = value.get<double>();
    char text[64];
    if (v == std::nearbyint(v) && std::abs(v) < 1e18) std::snprintf(text, sizeof text, "%lld", static_cast<long long>(v));
    else std::snprintf(text, sizeof text, "%g", v);
    return text;
  }
  return value.dump();
}

/// One optional part of a resumed run's learning-rate schedule, saved in checkpoint.json (`file`) as
/// `key`: an array of `size` numbers whose first `integers` are step numbers. Without a `given` one
/// (null) the saved one goes on: it is returned after a check of its shape (null when there is none).
/// A given one that differs from the saved one is logged as `change` (the caller records it), and
/// null is returned.
inline json resumed_schedule_part(const json& saved, const std::string& key, std::size_t size, std::size_t integers, const json& given,
                                  const std::filesystem::path& file, const std::string& change,
                                  const std::function<void(const std::string&)>& log) {
  if (!given.is_null()) {
    if (!saved.contains(key) || saved.at(key) != given) log(change);
    return nullptr;
  }
  if (!saved.contains(key)) return nullptr;
  const json& part = saved.at(key);
  bool ok = part.is_array() && part.size() == size;
  for (std::size_t i = 0; ok && i < size; ++i) ok = i < integers ? part[i].is_number_integer() : part[i].is_number();
  if (!ok) throw std::runtime_error(file.string() + ": malformed \"" + key + "\"");
  return part;
}

/// Throws std::runtime_error naming `file` when the settings a resumed run was given (`given`,
/// checkpoint.json's entries for this run) differ from those its checkpoint was trained with
/// (`saved`) in the network, preset, seed, size, batch, materials, a loss weight, emphasis or input
/// noise or the learning-rate warm-up: such a run would silently continue as another one. Older
/// checkpoints lack "materials" (the original mix), "render_weight", "lobe_weight", "diffuse_weight"
/// and "normal_weight" (1), "sigma_weight" and "mse_weight" (0), "emphasis" ("": none),
/// "emphasis_share" (0), "trainable" ("all"), "inputs" ("truth"), "shot_noise", "read_noise" and
/// "lr_warmup" (0); other entries a checkpoint lacks are not compared.
inline void check_resume_settings(const json& saved, const json& given, const std::filesystem::path& file) {
  if (saved.contains("network") && setting_text(saved.at("network")) != setting_text(given.at("network")))
    throw std::runtime_error(file.string() + ": the run in this folder trains the " + setting_text(saved.at("network")) + ", not the " +
                             setting_text(given.at("network")) + "; resume it with train-" + setting_text(saved.at("network")));
  static const std::pair<const char*, const char*> options[] = {
      {"preset", "--preset"}, {"seed", "--seed"},       {"size", "--size"},
      {"batch", "--batch"},   {"materials", "--materials"}, {"render_weight", "--render-weight"},
      {"lobe_weight", "--lobe-weight"}, {"sigma_weight", "--sigma-weight"}, {"mse_weight", "--mse-weight"},
      {"diffuse_weight", "--diffuse-weight"}, {"normal_weight", "--normal-weight"},
      {"emphasis", "--emphasis"}, {"emphasis_share", "--emphasis-share"}, {"trainable", "--trainable"}, {"inputs", "--inputs"},
      {"shot_noise", "--shot-noise"}, {"read_noise", "--read-noise"}, {"lr_warmup", "--lr-warmup"}};
  // What a description that lacks an entry meant: older versions wrote no materials, loss weights or emphasis.
  auto entry = [](const json& description, std::string_view key) {
    if (description.contains(std::string(key))) return description.at(std::string(key));
    if (key == "materials") return json("original");
    if (key == "render_weight" || key == "lobe_weight" || key == "diffuse_weight" || key == "normal_weight") return json(1.0);
    if (key == "sigma_weight" || key == "mse_weight") return json(0.0);
    if (key == "emphasis") return json("");
    if (key == "emphasis_share" || key == "shot_noise" || key == "read_noise" || key == "lr_warmup") return json(0.0);
    if (key == "trainable") return json("all");
    if (key == "inputs") return json("truth");
    return json();
  };
  for (const auto& [key, option] : options) {
    const json value = entry(saved, key), now = entry(given, key);
    if (value.is_null()) continue;
    if (value.is_number() != now.is_number() || (!value.is_number() && !value.is_string()))
      throw std::runtime_error(file.string() + ": malformed \"" + key + "\"");
    const bool same = value.is_number() ? value.get<double>() == now.get<double>() : value == now;
    if (!same) {
      auto shown = [](const json& v) { return v == "" ? std::string("(none)") : setting_text(v); };
      throw std::runtime_error(file.string() + ": the run was trained with " + key + " " + shown(value) + ", not " + shown(now) +
                               "; resume it " +
                               (value == "" ? std::string("without ") + option : std::string("with ") + option + " " + setting_text(value)));
    }
  }
}

/// The loop shared by both trainers: `step_fn(step, samples)` runs one optimiser step on the step's
/// batch (make_batch; prefetched on a second thread with o.prefetch) and returns its loss;
/// `validate_fn()` the validation. Handles resume, progress, checkpoints and the CSV.
///
/// `comm`: the ranks the run is spread over. With o.data_parallel (always over more than one rank)
/// step_fn gets this rank's share of the batch (part_range) and sums the gradients over the ranks;
/// rank 0 alone validates, logs and writes files, every rank reads a check-point it resumes from.
///
/// A resumed run must be the run its checkpoint.json describes (check_resume_settings). Only the
/// learning rate may change on resume (a step-down schedule): without --lr (o.learning_rate 0) the
/// run keeps its saved rate; with another rate the change is logged and recorded in
/// checkpoint.json ("learning_rate", and "learning_rate_changes" with the step of each change).
/// Nothing is created before the run is known to start: a refused resume leaves no folder.
template <class Net, class StepFn, class ValidateFn>
void run(const train_options& o, const std::string& kind, Net& net, nn::adam& opt, bool with_photos, StepFn step_fn,
         ValidateFn validate_fn, const communicator& comm = serial_communicator()) {
  o.validate();
  const bool root = comm.root();
  const std::function<void(const std::string&)> log = [&](const std::string& line) {
    if (root) o.log(line);
  };
  training_material_options(o.mix);  // reject the extended mix before touching out_dir
  long step = 0;
  json info = json::object();
  info["network"] = kind;
  info["preset"] = Net::preset::name;
  info["seed"] = double(o.seed);
  info["size"] = o.size;
  info["batch"] = o.batch;
  info["learning_rate"] = opt.schedule.base_rate();  // the base rate, not a warm-up's first step's
  info["materials"] = material_mix_name(o.mix);
  info["render_weight"] = o.render_weight;
  info["lobe_weight"] = o.lobe_weight;
  info["sigma_weight"] = o.sigma_weight;
  info["mse_weight"] = o.mse_weight;
  info["diffuse_weight"] = o.diffuse_weight;
  info["normal_weight"] = o.normal_weight;
  std::string emphasis;
  for (material_kind k : o.emphasis) emphasis += (emphasis.empty() ? "" : ",") + std::string(material_kind_name(k));
  info["emphasis"] = emphasis;
  info["emphasis_share"] = o.emphasis.empty() ? 0.0 : o.emphasis_share;
  info["shot_noise"] = o.input_noise.shot;
  info["read_noise"] = o.input_noise.read;
  info["trainable"] = o.encoder_only ? "encoder" : "all";
  info["inputs"] = o.inputs_are_estimates ? "estimates" : "truth";
  info["lr_warmup"] = o.lr_warmup;
  auto decay_of = [](const train_options& t) { return json::array({t.lr_decay_from, t.lr_decay_to, t.lr_end}); };
  if (o.lr_decay_to > 0) info["lr_decay"] = decay_of(o);
  auto rewarmup_of = [](const train_options& t) { return json::array({t.lr_rewarmup_from, t.lr_rewarmup}); };
  if (o.lr_rewarmup > 0) info["lr_rewarmup"] = rewarmup_of(o);
  if (o.precision != nn::precision::fp32) info["precision"] = nn::to_string(o.precision);  // absent: fp32
  const nn::precision_scope precision(o.precision);
  const auto csv = o.out_dir / "validation.csv";
  if (o.resume) {
    const auto description = o.out_dir / "checkpoint.json";
    const json saved = read_checkpoint_description(o.out_dir);
    check_resume_settings(saved, info, description);
    if (saved.contains("learning_rate_changes")) info["learning_rate_changes"] = saved.at("learning_rate_changes");
    step = load_checkpoint(o.out_dir, saved, net, opt);
    if (saved.contains("learning_rate")) {
      if (!saved.at("learning_rate").is_number() || !(saved.at("learning_rate").get<double>() > 0))
        throw std::runtime_error(description.string() + ": malformed \"learning_rate\"");
      const double before = saved.at("learning_rate").get<double>();
      if (o.learning_rate != 0 && std::abs(o.learning_rate - before) > 1e-12 * before) {
        char line[160];
        std::snprintf(line, sizeof line, "%s: learning rate %g -> %g from step %ld", kind.c_str(), before, o.learning_rate, step);
        log(line);
        if (!info.contains("learning_rate_changes")) info["learning_rate_changes"] = json::array();
        info["learning_rate_changes"].push_back({{"step", step}, {"from", before}, {"to", o.learning_rate}});
      }
      // The base rate, the decay and the re-warm-up: each the saved one unless another is given.
      train_options scheduled = o;
      scheduled.learning_rate = o.learning_rate == 0 ? before : o.learning_rate;
      char change[200];
      std::snprintf(change, sizeof change, "%s: learning rate decays from step %ld to %.3g of itself at step %ld (from step %ld on)",
                    kind.c_str(), o.lr_decay_from, o.lr_end, o.lr_decay_to, step);
      const json decay = resumed_schedule_part(saved, "lr_decay", 3, 2, o.lr_decay_to > 0 ? decay_of(o) : json(), description, change, log);
      if (!decay.is_null()) {
        scheduled.lr_decay_from = decay[0].get<long>();
        scheduled.lr_decay_to = decay[1].get<long>();
        scheduled.lr_end = decay[2].get<double>();
      }
      std::snprintf(change, sizeof change, "%s: learning rate warms up again from step %ld over %ld steps", kind.c_str(),
                    o.lr_rewarmup_from, o.lr_rewarmup);
      const json rewarmup =
          resumed_schedule_part(saved, "lr_rewarmup", 2, 2, o.lr_rewarmup > 0 ? rewarmup_of(o) : json(), description, change, log);
      if (!rewarmup.is_null()) {
        scheduled.lr_rewarmup_from = rewarmup[0].get<long>();
        scheduled.lr_rewarmup = rewarmup[1].get<long>();
      }
      scheduled.validate();
      opt.schedule = training_schedule(scheduled.learning_rate, scheduled);
      info["learning_rate"] = scheduled.learning_rate;
      if (scheduled.lr_decay_to > 0) info["lr_decay"] = decay_of(scheduled);
      if (scheduled.lr_rewarmup > 0) info["lr_rewarmup"] = rewarmup_of(scheduled);
    }
    if (root) {
      truncate_csv(csv, step);
      log(kind + ": resumed at step " + std::to_string(step));
    }
  } else {
    if (!o.init_weights.empty()) {
      // Both networks name their encoder layers alike: the file's "network" entry (save_network's)
      // keeps an auto-encoder's weights out of an estimator and the reverse.
      for (const auto& [key, value] : nn::read_safetensors_header(o.init_weights).metadata)
        if (key == "network" && value != kind)
          throw std::runtime_error(o.init_weights.string() + ": holds " + value + " weights, not " + kind + " weights (--init)");
      const std::vector<std::string> fresh = nn::load_matching_weights(o.init_weights, net);
      std::string note;
      for (const auto& name : fresh) note += (note.empty() ? "" : ", ") + name;
      log(kind + ": starting from the weights in " + o.init_weights.string() +
            (fresh.empty() ? "" : " (not in the file with this shape, initialised afresh: " + note + ")"));
      if constexpr (requires { start_doubled_angle_head(o.init_weights, net); })
        if (!fresh.empty() && start_doubled_angle_head(o.init_weights, net))
          log(kind + ": the doubled-angle head starts from the file's tanh head (normals as they were, alpha to first order)");
    }
    if (root) {
      std::filesystem::create_directories(o.out_dir);
      std::filesystem::remove(csv);
    }
  }
  using clock = std::chrono::steady_clock;
  const auto start = clock::now();
  auto last_checkpoint = start, last_progress = start;
  const long first = step;
  double window = 0, since_validation = 0;  // loss sums for the progress line and the CSV row
  long window_count = 0, since_validation_count = 0;
  auto checkpoint = [&] {
    if (!root) return;
    save_checkpoint(o.out_dir, net, opt, step, info);
    save_network(o.out_dir / (kind + ".safetensors"), net, kind);
  };
  // The last step this call runs (stop_after returns after the step that reaches it).
  const long end = o.stop_after >= 0 ? std::min(o.steps, std::max(o.stop_after, first + 1)) : o.steps;
  // The next step's batch is built with as many OpenMP threads as the step uses (faster on 2 cores
  // than one thread, bench/README.md "Training throughput").
  // Over several ranks (or data-parallel) each rank builds its own share of each batch.
  const auto share = o.data_parallel || comm.distributed() ? part_range(o.batch, comm.size(), comm.rank()) : std::pair{0, o.batch};
  prefetcher<std::vector<sample>> batches([&](long s) { return make_batch(o, s, with_photos, share.first, share.second); }, end,
                                          o.prefetch, omp_get_max_threads());
  while (step < o.steps) {
    const double loss = step_fn(step, batches.take(step));
    ++step;
    window += loss;
    ++window_count;
    since_validation += loss;
    ++since_validation_count;
    const auto now = clock::now();
    const double elapsed = std::chrono::duration<double>(now - start).count();
    if (root && (std::chrono::duration<double>(now - last_progress).count() >= o.progress_seconds || step == o.steps)) {
      const double rate = double(step - first) / std::max(elapsed, 1e-9);
      char line[256];
      std::snprintf(line, sizeof line, "%s: step %ld/%ld  loss %.4f  %.3f steps/s  %.2f samples/s  %.0f s left",
                    kind.c_str(), step, o.steps, window / double(window_count), rate, rate * o.batch, double(o.steps - step) / rate);
      log(line);
      window = 0;
      window_count = 0;
      last_progress = now;
    }
    if (root && ((o.validate_every > 0 && step % o.validate_every == 0) || step == o.steps)) {
      // The CSV's train_loss: mean over the steps since the previous validation (or the resume).
      const validation_result v = validate_fn();
      append_validation(csv, step, since_validation / double(since_validation_count), v);
      since_validation = 0;
      since_validation_count = 0;
      char line[256];
      std::snprintf(line, sizeof line, "%s: validation at step %ld: loss %.4f (L1 %.4f, render %.4f)", kind.c_str(), step,
                    v.loss.total, v.loss.l1, v.loss.render);
      log(line);
    }
    const bool timed = std::chrono::duration<double>(clock::now() - last_checkpoint).count() >= 60 * o.checkpoint_minutes;
    if (timed || step == o.steps || (o.checkpoint_every > 0 && step % o.checkpoint_every == 0)) {
      checkpoint();
      last_checkpoint = clock::now();
    }
    if (o.stop_after >= 0 && step >= o.stop_after) return;
  }
}

}  // namespace detail

namespace detail {

/// The latent smoothness term's |D(z) - D(z + delta)| (`y`, `y2`): adds +-step to the gradients
/// `gy` and -+step to `gy2` per value and returns the sum of the absolute differences.
inline double add_smoothness(const tensor<parameter_count>& y, const tensor<parameter_count>& y2, tensor<parameter_count>& gy,
                             tensor<parameter_count>& gy2, float step) {
  double s = 0;
  for (std::size_t i = 0; i < y.size(); ++i) {
    const float d = y.data()[i] - y2.data()[i];
    s += std::abs(d);
    const float sg = d > 0 ? step : (d < 0 ? -step : 0.0f);
    gy.data()[i] += sg;
    gy2.data()[i] -= sg;
  }
  return s;
}

}  // namespace detail

/// The estimator's gradient on a batch (make_batch with photos; docs/method.md section 7): the
/// samples' 5 inputs in network space, the forward pass, map_losses with weights `w` (L1 +
/// w.render x render loss by default) and its gradient, backward. The gradients are added to the
/// parameters' (zero them first). `t` is cleared first (reuse it across steps to keep its memory).
/// `batch_size`: as map_losses's (a data-parallel part's share of a larger batch). Returns the
/// batch's loss terms.
template <class Preset>
loss_terms estimator_gradient(ad::tape& t, estimation_network<Preset>& net, std::span<const sample> samples, const loss_weights& w = {},
                              int batch_size = 0) {
  const int B = int(samples.size()), N = int(samples[0].photos.size());
  const int H = samples[0].truth.height(), W = samples[0].truth.width();
  t.clear();
  auto x = t.make_variable<estimation_network<Preset>::inputs>(B * N, H, W, false);
  for (int b = 0; b < B; ++b)
    for (int i = 0; i < N; ++i) network_space::photo_to_network(samples[std::size_t(b)].photos[i], x.value, b * N + i);
  auto y = net.forward(t, x, N);
  const loss_terms l = map_losses(y.value, samples, &y.grad, w, batch_size);
  t.backward();
  return l;
}

/// One optimiser step of the estimator on a batch: estimator_gradient, then one Adam step.
/// Returns the batch's loss terms before the step.
template <class Preset>
loss_terms estimator_step(ad::tape& t, estimation_network<Preset>& net, nn::adam& opt, const std::vector<sample>& samples,
                          const loss_weights& w = {}) {
  const loss_terms l = estimator_gradient(t, net, samples, w);
  opt.step();
  return l;
}

/// The auto-encoder's gradient on a batch (make_batch without photos; docs/method.md section 7):
/// D(E(m)) of the samples' true maps in training mode, map_losses with o.loss()'s weights, and with
/// o.smoothness_weight > 0 the latent smoothness term o.smoothness_weight * mean |D(z) - D(z +
/// delta)|, delta ~ N(0, o.latent_noise^2) per latent value drawn from (o.seed, step); backward.
/// The gradients are added to the parameters'. `t` is cleared first. Returns the batch's loss
/// terms. With `inputs` (one network-space map set per sample, e.g. the estimator's estimates) the
/// encoder reads those instead of the true maps; the loss still compares with the truth.
template <class Preset>
loss_terms autoencoder_gradient(ad::tape& t, auto_encoder<Preset>& net, const std::vector<sample>& samples, const train_options& o,
                                long step, const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  constexpr int Z = auto_encoder<Preset>::latent_channels;
  const int B = int(samples.size()), H = samples[0].truth_net.height(), W = samples[0].truth_net.width();
  if (inputs && int(inputs->size()) != B) throw std::invalid_argument("autoencoder_step: one input per sample");
  t.clear();
  auto x = t.make_variable<parameter_count>(B, H, W, false);
  for (int b = 0; b < B; ++b) {
    const tensor<parameter_count>& in = inputs ? (*inputs)[std::size_t(b)] : samples[b].truth_net;
    if (in.height() != H || in.width() != W) throw std::invalid_argument("autoencoder_step: an input's size differs from its sample's");
    std::copy_n(in.data(), in.size(), x.value.pixel(b, 0, 0));
  }
  net.set_training(true);
  auto z = net.encode(t, x);
  auto y = net.decode(t, z);
  loss_terms l = map_losses(y.value, samples, &y.grad, o.loss());
  if (o.smoothness_weight > 0) {
    auto delta = t.make_variable<Z>(z.value.batch(), z.value.height(), z.value.width(), false);
    nn::random_generator rng(hash64(o.seed ^ 0x736d6f6f7468ULL, step, 0));
    for (std::size_t i = 0; i < delta.value.size(); ++i) delta.value.data()[i] = float(o.latent_noise * rng.normal());
    auto y2 = net.decode(t, nn::add(t, z, delta));
    const double values = double(y.value.size());
    l.smoothness = detail::add_smoothness(y.value, y2.value, y.grad, y2.grad, float(o.smoothness_weight / values)) / values;
    l.total += o.smoothness_weight * l.smoothness;
  }
  t.backward();
  return l;
}

/// One optimiser step of the auto-encoder on a batch: autoencoder_gradient, then one Adam step.
/// Returns the batch's loss terms before the step.
template <class Preset>
loss_terms autoencoder_step(ad::tape& t, auto_encoder<Preset>& net, nn::adam& opt, const std::vector<sample>& samples,
                            const train_options& o, long step, const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  const loss_terms l = autoencoder_gradient(t, net, samples, o, step, inputs);
  opt.step();
  return l;
}

/// The gradients of a data-parallel step (train_options::data_parallel): one part per material of
/// the batch, each rank holding the parts part_range deals it, summed in ordered_sum's fixed tree.
class part_gradients {
 public:
  /// The trainable parameters of `net` (for_each_parameter's order, frozen ones left out) and this
  /// rank's share of a batch of `batch` parts.
  template <class Net>
  part_gradients(Net& net, const communicator& comm, int batch) : comm_(comm), batch_(batch) {
    net.for_each_parameter([&](nn::parameter& p) {
      if (p.trainable()) trained_.push_back(&p);
    });
    for (const nn::parameter* p : trained_) size_ += p->size();
    const auto range = part_range(batch, comm.size(), comm.rank());
    first_ = range.first;
    last_ = range.second;
    gradients_.assign(std::size_t(last_ - first_) * size_, 0.0f);
    losses_.assign(std::size_t(last_ - first_) * loss_count, 0.0);
  }
  /// This rank's parts: [first(), last()) of the batch.
  int first() const noexcept { return first_; }
  int last() const noexcept { return last_; }
  /// Adds the parameters' gradients to part k's (a batch index this rank holds) and zeroes them.
  void take(int k) {
    float* out = part(k);
    for (nn::parameter* p : trained_) {
      for (std::size_t i = 0; i < p->size(); ++i) out[i] += p->grad[i];
      std::fill(p->grad.begin(), p->grad.end(), 0.0f);
      out += p->size();
    }
  }
  /// Adds `l` to part k's loss terms.
  void add_loss(int k, const loss_terms& l) {
    double* out = losses_.data() + std::size_t(k - first_) * loss_count;
    const double* in = reinterpret_cast<const double*>(&l);
    for (std::size_t i = 0; i < loss_count; ++i) out[i] += in[i];
  }
  /// Every rank: the sum of all parts' gradients into the parameters' gradients; returns the sum of
  /// the parts' loss terms (the batch's).
  loss_terms finish() {
    std::vector<float> sum(size_);
    ordered_sum<float>(comm_, batch_, size_, gradients_, sum);
    const float* in = sum.data();
    for (nn::parameter* p : trained_) {
      std::copy(in, in + p->size(), p->grad.begin());
      in += p->size();
    }
    loss_terms total;
    ordered_sum<double>(comm_, batch_, loss_count, losses_, std::span<double>(reinterpret_cast<double*>(&total), loss_count));
    return total;
  }

 private:
  static constexpr std::size_t loss_count = sizeof(loss_terms) / sizeof(double);
  static_assert(sizeof(loss_terms) == loss_count * sizeof(double), "loss_terms holds doubles only");
  float* part(int k) {
    if (k < first_ || k >= last_) throw std::logic_error("part_gradients: part " + std::to_string(k) + " is not this rank's");
    return gradients_.data() + std::size_t(k - first_) * size_;
  }
  const communicator& comm_;
  int batch_;
  int first_ = 0, last_ = 0;
  std::vector<nn::parameter*> trained_;
  std::size_t size_ = 0;
  std::vector<float> gradients_;
  std::vector<double> losses_;
};

/// The estimator's gradient on a batch of `batch` materials, data-parallel
/// (train_options::data_parallel): `local` holds this rank's materials (part_range's share), each
/// one's gradient is computed alone (estimator_gradient with the batch's normalisation) and the
/// parts are summed over the ranks in ordered_sum's tree. Every rank calls it; on return every
/// rank's parameters hold the batch's gradient. Returns the batch's loss terms.
template <class Preset>
loss_terms estimator_gradient_parts(ad::tape& t, estimation_network<Preset>& net, std::span<const sample> local, int batch,
                                    const loss_weights& w, const communicator& comm) {
  part_gradients parts(net, comm, batch);
  if (int(local.size()) != parts.last() - parts.first())
    throw std::invalid_argument("estimator_gradient_parts: this rank's materials are not its share of the batch");
  for (int k = parts.first(); k < parts.last(); ++k) {
    parts.add_loss(k, estimator_gradient(t, net, local.subspan(std::size_t(k - parts.first()), 1), w, batch));
    parts.take(k);
  }
  return parts.finish();
}

/// The auto-encoder's gradient on a batch of `batch` materials, data-parallel: `local` (and
/// `inputs`, when given) hold this rank's materials. Each material's encoder, decoder and loss
/// (smoothness included, its delta the whole batch's slice) run alone; the batch norm that ends
/// the encoder normalises with the statistics of the whole batch, summed over the materials in
/// ordered_sum's tree (a synchronised batch norm: its mean, then its centred variance, and in the
/// backward pass the sums of dL/dz and dL/dz * z_hat), and updates the running statistics as
/// batch_norm does. The result equals autoencoder_gradient's up to rounding, on any rank count the
/// same bits. Every rank calls it. Returns the batch's loss terms.
template <class Preset>
loss_terms autoencoder_gradient_parts(ad::tape& t, auto_encoder<Preset>& net, std::span<const sample> local, int batch,
                                      const train_options& o, long step, const communicator& comm,
                                      const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  constexpr int Z = auto_encoder<Preset>::latent_channels;
  part_gradients parts(net, comm, batch);
  const int first = parts.first(), count = parts.last() - parts.first();
  if (int(local.size()) != count || (inputs && int(inputs->size()) != count))
    throw std::invalid_argument("autoencoder_gradient_parts: this rank's materials are not its share of the batch");
  net.set_training(true);
  nn::batch_norm<Z>& norm = net.latent_norm;
  // The encoders, each on a tape of its own (kept for the backward pass after the statistics).
  std::vector<std::unique_ptr<ad::tape>> tapes;
  std::vector<ad::variable<Z>> features;
  int h = 0, w = 0;
  for (int k = 0; k < count; ++k) {
    const tensor<parameter_count>& in = inputs ? (*inputs)[std::size_t(k)] : local[std::size_t(k)].truth_net;
    tapes.push_back(std::make_unique<ad::tape>());
    auto x = tapes.back()->make_variable<parameter_count>(1, in.height(), in.width(), false);
    std::copy_n(in.data(), in.size(), x.value.data());
    features.push_back(net.encode_features(*tapes.back(), x));
    h = features.back().value.height();
    w = features.back().value.width();
  }
  // The batch's shape, the same on every rank (a rank may hold no material).
  {
    const int one = count > 0 ? 1 : 0;
    int shape[2] = {h * one, w * one};
    std::vector<int> all;
    comm.all_gather(std::span<const int>(shape, 2), all, std::vector<std::size_t>(std::size_t(comm.size()), 2));
    for (std::size_t r = 0; r < all.size(); r += 2)
      if (all[r] > 0) {
        h = all[r];
        w = all[r + 1];
      }
  }
  const double n = double(batch) * h * w;
  if (n < 2) throw std::invalid_argument("nn::batch_norm: training needs more than one value per channel");
  const std::size_t cell = std::size_t(h) * w;
  // Per-channel sums of each material, added over the batch in the tree.
  auto channel_sums = [&](auto per_value) {
    std::vector<double> local_sums(std::size_t(count) * Z, 0.0), total(Z);
    for (int k = 0; k < count; ++k)
      for (std::size_t i = 0; i < cell; ++i)
        for (int c = 0; c < Z; ++c) local_sums[std::size_t(k) * Z + std::size_t(c)] += per_value(k, i, c);
    ordered_sum<double>(comm, batch, Z, local_sums, total);
    return std::pair{local_sums, total};
  };
  const auto [unused_mean_parts, sum] = channel_sums([&](int k, std::size_t i, int c) { return double(features[std::size_t(k)].value.data()[i * Z + c]); });
  (void)unused_mean_parts;
  std::vector<double> mean(Z);
  for (int c = 0; c < Z; ++c) mean[std::size_t(c)] = sum[std::size_t(c)] / n;
  const auto [unused_variance_parts, squares] = channel_sums([&](int k, std::size_t i, int c) {
    const double d = double(features[std::size_t(k)].value.data()[i * Z + c]) - mean[std::size_t(c)];
    return d * d;
  });
  (void)unused_variance_parts;
  std::vector<float> mean_f(Z), rstd(Z);
  for (int c = 0; c < Z; ++c) {
    const double variance = squares[std::size_t(c)] / n;
    norm.running_mean.value[c] = (1 - norm.momentum) * norm.running_mean.value[c] + norm.momentum * float(mean[std::size_t(c)]);
    norm.running_var.value[c] = (1 - norm.momentum) * norm.running_var.value[c] + norm.momentum * float(variance * n / (n - 1));
    mean_f[std::size_t(c)] = float(mean[std::size_t(c)]);
    rstd[std::size_t(c)] = float(1 / std::sqrt(variance + double(norm.epsilon)));
  }
  auto z_hat = [&](int k, std::size_t i, int c) { return (features[std::size_t(k)].value.data()[i * Z + c] - mean_f[std::size_t(c)]) * rstd[std::size_t(c)]; };
  // The batch's smoothness deltas, drawn as autoencoder_gradient draws them; material k's slice.
  std::vector<float> deltas;
  if (o.smoothness_weight > 0) {
    deltas.resize(std::size_t(batch) * cell * Z);
    nn::random_generator rng(hash64(o.seed ^ 0x736d6f6f7468ULL, step, 0));
    for (float& d : deltas) d = float(o.latent_noise * rng.normal());
  }
  // Each material's decoder, loss and backward pass to z; dL/dz kept for the encoder's.
  std::vector<std::vector<float>> dz(static_cast<std::size_t>(count));
  for (int k = 0; k < count; ++k) {
    t.clear();
    auto z = t.make_variable<Z>(1, h, w, true);
    for (std::size_t i = 0; i < cell; ++i)
      for (int c = 0; c < Z; ++c) z.value.data()[i * Z + c] = z_hat(k, i, c) * norm.weight.value[c] + norm.bias.value[c];
    auto y = net.decode(t, z);
    loss_terms l = map_losses(y.value, local.subspan(std::size_t(k), 1), &y.grad, o.loss(), batch);
    if (o.smoothness_weight > 0) {
      auto delta = t.make_variable<Z>(1, h, w, false);
      std::copy_n(deltas.data() + std::size_t(first + k) * cell * Z, cell * Z, delta.value.data());
      auto y2 = net.decode(t, nn::add(t, z, delta));
      const double values = double(y.value.size()) * batch;  // the batch's
      l.smoothness = detail::add_smoothness(y.value, y2.value, y.grad, y2.grad, float(o.smoothness_weight / values)) / values;
      l.total += o.smoothness_weight * l.smoothness;
    }
    t.backward();
    dz[std::size_t(k)].assign(z.grad.data(), z.grad.data() + z.grad.size());
    parts.add_loss(first + k, l);
    parts.take(first + k);  // the decoder's gradient of this material
  }
  // The batch norm's backward pass: its scale's and shift's gradients per material, and the sums
  // over the batch that dL/d(features) needs.
  const auto [scale_parts, scale_sum] = channel_sums([&](int k, std::size_t i, int c) { return double(dz[std::size_t(k)][i * Z + c]) * z_hat(k, i, c); });
  const auto [shift_parts, shift_sum] = channel_sums([&](int k, std::size_t i, int c) { return double(dz[std::size_t(k)][i * Z + c]); });
  for (int k = 0; k < count; ++k) {
    if (norm.weight.trainable())
      for (int c = 0; c < Z; ++c) norm.weight.grad[c] += float(scale_parts[std::size_t(k) * Z + std::size_t(c)]);
    if (norm.bias.trainable())
      for (int c = 0; c < Z; ++c) norm.bias.grad[c] += float(shift_parts[std::size_t(k) * Z + std::size_t(c)]);
    auto& f = features[std::size_t(k)];
    if (f.requires_grad) {
      for (std::size_t i = 0; i < cell; ++i)
        for (int c = 0; c < Z; ++c) {
          const double g = dz[std::size_t(k)][i * Z + c] - shift_sum[std::size_t(c)] / n - z_hat(k, i, c) * scale_sum[std::size_t(c)] / n;
          f.grad.data()[i * Z + c] = float(double(norm.weight.value[c]) * rstd[std::size_t(c)] * g);
        }
      tapes[std::size_t(k)]->backward();
    }
    parts.take(first + k);
  }
  return parts.finish();
}

/// Trains the estimator (docs/method.md section 7): per step, `batch` procedural materials with their 5 training
/// inputs; loss = L1 (network space) + render loss; Adam (default rate 5e-5, the paper's).
/// `comm`: the ranks the run is spread over (train_options::data_parallel); every rank calls it
/// with the same options and the same starting weights.
template <class Preset>
void train_estimator(const train_options& o, estimation_network<Preset>& net, const communicator& comm = serial_communicator()) {
  if (o.size <= 0 || o.size % 64 != 0) throw std::invalid_argument("train-estimator: --size must be a positive multiple of 64");
  o.validate();  // before the schedule is built from the options
  nn::adam opt(training_schedule(o.learning_rate > 0 ? o.learning_rate : 5e-5, o));
  opt.add_parameters(net);
  ad::tape t;
  const bool parts = o.data_parallel || comm.distributed();
  auto step_fn = [&](long, const std::vector<sample>& samples) {
    if (!parts) return estimator_step(t, net, opt, samples, o.loss()).total;
    const double loss = estimator_gradient_parts(t, net, samples, o.batch, o.loss(), comm).total;
    opt.step();
    return loss;
  };
  auto validate_fn = [&] {
    return validate(net, o, true, [](auto& n, const sample& s) { return estimator_output(n, s); });
  };
  detail::run(o, "estimator", net, opt, true, step_fn, validate_fn, comm);
}

namespace detail {

/// The body of both train_autoencoder overloads: the encoder reads the true maps when Estimator is
/// void, else `estimator`'s estimates of each sample's 5 training photos.
template <class Preset, class Estimator>
void train_autoencoder_on(const train_options& options, auto_encoder<Preset>& net, Estimator* estimator, const communicator& comm) {
  constexpr bool from_estimates = !std::is_void_v<Estimator>;
  train_options o = options;
  o.inputs_are_estimates = from_estimates;
  if (from_estimates && (o.size <= 0 || o.size % 64 != 0))
    throw std::invalid_argument("train-autoencoder: with estimates as inputs --size must be a positive multiple of 64 (the estimator's)");
  constexpr int cell = auto_encoder<Preset>::size_multiple;  // texels per latent cell along each side
  if (o.size <= 0 || o.size % cell != 0)
    throw std::invalid_argument("train-autoencoder: --size must be a positive multiple of " + std::to_string(cell) +
                                " (one latent cell of this preset)");
  if (o.batch < 2 && o.size <= cell) throw std::invalid_argument("train-autoencoder: batch norm needs more than one latent value");
  o.validate();  // before the schedule is built from the options
  if (o.encoder_only && o.init_weights.empty() && !o.resume)
    throw std::invalid_argument("train-autoencoder: --trainable encoder trains against the decoder of the weights it starts from: "
                                "give them with --init (or --resume such a run)");
  nn::adam opt(training_schedule(o.learning_rate > 0 ? o.learning_rate : 1e-3, o));
  opt.add_parameters(net);
  net.freeze_decoder(o.encoder_only);
  ad::tape t;
  const bool parts = o.data_parallel || comm.distributed();
  auto step_fn = [&](long step, const std::vector<sample>& samples) {
    std::vector<tensor<parameter_count>> estimates;
    if constexpr (from_estimates)
      for (const sample& x : samples) estimates.push_back(estimator_output(*estimator, x));
    const std::vector<tensor<parameter_count>>* inputs = from_estimates ? &estimates : nullptr;
    if (!parts) return autoencoder_step(t, net, opt, samples, o, step, inputs).total;
    const double loss = autoencoder_gradient_parts(t, net, samples, o.batch, o, step, comm, inputs).total;
    opt.step();
    return loss;
  };
  auto validate_fn = [&] {
    return validate(net, o, from_estimates, [&](auto& n, const sample& s) {
      if constexpr (from_estimates) {
        const tensor<parameter_count> e = estimator_output(*estimator, s);
        return autoencoder_output(n, s, &e);
      } else {
        return autoencoder_output(n, s);
      }
    });
  };
  run(o, "autoencoder", net, opt, from_estimates, step_fn, validate_fn, comm);
}

}  // namespace detail

/// Trains the auto-encoder (docs/method.md section 7): per step, `batch` procedural map sets; loss = L1 + render
/// loss of D(E(m)) + smoothness_weight * mean |D(z) - D(z + delta)| with delta ~ N(0, latent_noise^2)
/// per latent value (Gao 2019's smoothness); Adam (default rate 1e-3, the paper's). With
/// o.encoder_only the decoder is frozen (auto_encoder::freeze_decoder) and keeps the weights the run
/// started from.
/// `comm`: as train_estimator's.
template <class Preset>
void train_autoencoder(const train_options& o, auto_encoder<Preset>& net, const communicator& comm = serial_communicator()) {
  detail::train_autoencoder_on<Preset, void>(o, net, nullptr, comm);
}

/// Trains the auto-encoder as train_autoencoder does, with the encoder reading `estimator`'s
/// estimates of each material's 5 training photos (the maps the pipeline encodes, docs/method.md
/// section 8.2) instead of the true maps, and the loss comparing D(E(estimate)) with the truth.
/// The estimator is not trained. Validation measures the same: D(E(estimate)) against the truth.
/// With o.encoder_only the decoder keeps its --init weights: the encoder learns the latent code
/// from which the decoder the pipeline fine-tunes starts nearest the truth. Sizes must be
/// multiples of 64 (the estimator's).
template <class Preset, class EstimatorPreset>
void train_autoencoder(const train_options& o, auto_encoder<Preset>& net, estimation_network<EstimatorPreset>& estimator,
                       const communicator& comm = serial_communicator()) {
  detail::train_autoencoder_on(o, net, &estimator, comm);
}

}  // namespace anisocap::training
