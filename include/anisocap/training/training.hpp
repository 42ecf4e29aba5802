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
///
/// The parts: samples.hpp (the materials), losses.hpp, options.hpp (train_options, the batches),
/// validation.hpp, checkpoint.hpp (the run's files), steps.hpp (one optimiser step, whole or
/// data-parallel); this file holds the training loop and the two trainers.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <omp.h>

#include "anisocap/core/distributed.hpp"
#include "anisocap/core/text.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/training/checkpoint.hpp"
#include "anisocap/training/losses.hpp"
#include "anisocap/training/options.hpp"
#include "anisocap/training/prefetch.hpp"
#include "anisocap/training/samples.hpp"
#include "anisocap/training/steps.hpp"
#include "anisocap/training/validation.hpp"

namespace anisocap::training {

namespace detail {

/// The saved learning-rate decay of a run's options: [from, to, end].
inline json decay_setting(const train_options& t) { return json::array({t.lr_decay_from, t.lr_decay_to, t.lr_end}); }
/// The saved learning-rate re-warm-up of a run's options: [from, steps].
inline json rewarmup_setting(const train_options& t) { return json::array({t.lr_rewarmup_from, t.lr_rewarmup}); }

/// What checkpoint.json records of a run of network `kind` (preset `preset`) at base rate `rate`:
/// the settings a resume must repeat (check_resume_settings) and the schedule it may change.
inline json run_description(const train_options& o, const std::string& kind, const char* preset, double rate) {
  json info = json::object();
  info["network"] = kind;
  info["preset"] = preset;
  info["seed"] = double(o.seed);
  info["size"] = o.size;
  info["batch"] = o.batch;
  info["learning_rate"] = rate;  // the base rate, not a warm-up's first step's
  info["materials"] = material_mix_name(o.mix);
  info["render_weight"] = o.render_weight;
  info["lobe_weight"] = o.lobe_weight;
  info["sigma_weight"] = o.sigma_weight;
  info["mse_weight"] = o.mse_weight;
  info["diffuse_weight"] = o.diffuse_weight;
  info["normal_weight"] = o.normal_weight;
  std::string emphasis;
  for (material_kind k : o.emphasis) {
    if (!emphasis.empty()) emphasis += ',';
    emphasis += material_kind_name(k);
  }
  info["emphasis"] = emphasis;
  info["emphasis_share"] = o.emphasis.empty() ? 0.0 : o.emphasis_share;
  info["shot_noise"] = o.input_noise.shot;
  info["read_noise"] = o.input_noise.read;
  info["trainable"] = o.encoder_only ? "encoder" : "all";
  info["inputs"] = o.inputs_are_estimates ? "estimates" : "truth";
  info["lr_warmup"] = o.lr_warmup;
  if (o.lr_decay_to > 0) info["lr_decay"] = decay_setting(o);
  if (o.lr_rewarmup > 0) info["lr_rewarmup"] = rewarmup_setting(o);
  if (o.precision != nn::precision::fp32) info["precision"] = nn::to_string(o.precision);  // absent: fp32
  return info;
}

/// Resumes a run from o.out_dir's check-point into `net` and `opt` after checking that it is the
/// run `info` describes; takes the saved learning rate, decay and re-warm-up unless o names others
/// (recorded in `info`, logged). Returns the step to continue from.
template <class Net>
long resume_run(const train_options& o, const std::string& kind, Net& net, nn::adam& opt, json& info,
                const std::function<void(const std::string&)>& log) {
  const auto description = o.out_dir / "checkpoint.json";
  const json saved = read_checkpoint_description(o.out_dir);
  check_resume_settings(saved, info, description);
  if (saved.contains("learning_rate_changes")) info["learning_rate_changes"] = saved.at("learning_rate_changes");
  const long step = load_checkpoint(o.out_dir, saved, net, opt);
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
    const json decay = resumed_schedule_part(saved, "lr_decay", 3, 2, o.lr_decay_to > 0 ? decay_setting(o) : json(), description, change, log);
    if (!decay.is_null()) {
      scheduled.lr_decay_from = decay[0].get<long>();
      scheduled.lr_decay_to = decay[1].get<long>();
      scheduled.lr_end = decay[2].get<double>();
    }
    std::snprintf(change, sizeof change, "%s: learning rate warms up again from step %ld over %ld steps", kind.c_str(),
                  o.lr_rewarmup_from, o.lr_rewarmup);
    const json rewarmup =
        resumed_schedule_part(saved, "lr_rewarmup", 2, 2, o.lr_rewarmup > 0 ? rewarmup_setting(o) : json(), description, change, log);
    if (!rewarmup.is_null()) {
      scheduled.lr_rewarmup_from = rewarmup[0].get<long>();
      scheduled.lr_rewarmup = rewarmup[1].get<long>();
    }
    scheduled.validate();
    opt.schedule = training_schedule(scheduled.learning_rate, scheduled);
    info["learning_rate"] = scheduled.learning_rate;
    if (scheduled.lr_decay_to > 0) info["lr_decay"] = decay_setting(scheduled);
    if (scheduled.lr_rewarmup > 0) info["lr_rewarmup"] = rewarmup_setting(scheduled);
  }
  return step;
}

/// Starts a fresh run's `net` from o.init_weights where given (the file must hold `kind` weights;
/// tensors it lacks keep their initialisation, and are logged).
template <class Net>
void start_from_init(const train_options& o, const std::string& kind, Net& net, const std::function<void(const std::string&)>& log) {
  if (!o.init_weights.empty()) {
    // Both networks name their encoder layers alike: the file's "network" entry (save_network's)
    // keeps an auto-encoder's weights out of an estimator and the reverse.
    for (const auto& [key, value] : nn::read_safetensors_header(o.init_weights).metadata)
      if (key == "network" && value != kind)
        throw std::runtime_error(o.init_weights.string() + ": holds " + value + " weights, not " + kind + " weights (train_options::init_weights)");
    const std::vector<std::string> fresh = nn::load_matching_weights(o.init_weights, net);
    log(kind + ": starting from the weights in " + o.init_weights.string() +
        (fresh.empty() ? "" : " (not in the file with this shape, initialised afresh: " + join_names(fresh, ", ") + ")"));
    if constexpr (requires { start_doubled_angle_head(o.init_weights, net); })
      if (!fresh.empty() && start_doubled_angle_head(o.init_weights, net))
        log(kind + ": the doubled-angle head starts from the file's tanh head (normals as they were, alpha to first order)");
  }
}

/// A run's first step: a resumed run's (resume_run; rank 0 cuts validation.csv back to it), or 0
/// for a fresh one (start_from_init; rank 0 creates out_dir and starts validation.csv afresh).
template <class Net>
long begin_run(const train_options& o, const std::string& kind, Net& net, nn::adam& opt, json& info,
               const std::function<void(const std::string&)>& log, bool root, const std::filesystem::path& csv) {
  if (o.resume) {
    const long step = resume_run(o, kind, net, opt, info, log);
    if (root) {
      truncate_csv(csv, step);
      log(kind + ": resumed at step " + std::to_string(step));
    }
    return step;
  }
  start_from_init(o, kind, net, log);
  if (root) {
    std::filesystem::create_directories(o.out_dir);
    std::filesystem::remove(csv);
  }
  return 0;
}

/// The training loop's loss sums: over the progress line's window of steps, and since the last
/// validation (the CSV's train_loss).
struct loss_tally {
  double window = 0, since_validation = 0;
  long window_count = 0, since_validation_count = 0;
  void add(double loss) {
    window += loss;
    ++window_count;
    since_validation += loss;
    ++since_validation_count;
  }
  /// The window's mean loss; starts the next window.
  double take_window() {
    const double mean = window / double(window_count);
    window = 0;
    window_count = 0;
    return mean;
  }
  /// The mean loss since the last validation; starts the next span.
  double take_since_validation() {
    const double mean = since_validation / double(since_validation_count);
    since_validation = 0;
    since_validation_count = 0;
    return mean;
  }
};

/// The progress line after `step` of `steps` at `rate` steps per second.
inline std::string progress_line(const std::string& kind, long step, long steps, double loss, double rate, int batch) {
  char line[256];
  std::snprintf(line, sizeof line, "%s: step %ld/%ld  loss %.4f  %.3f steps/s  %.2f samples/s  %.0f s left", kind.c_str(), step, steps, loss,
                rate, rate * batch, double(steps - step) / rate);
  return line;
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
  const nn::precision_scope precision(o.precision);
  const auto csv = o.out_dir / "validation.csv";
  json info = run_description(o, kind, Net::preset::name, opt.schedule.base_rate());
  long step = begin_run(o, kind, net, opt, info, log, root, csv);
  using clock = std::chrono::steady_clock;
  const auto start = clock::now();
  auto last_checkpoint = start, last_progress = start;
  const long first = step;
  loss_tally tally;
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
  const auto share = steps_data_parallel(o, comm) ? part_range(o.batch, comm.size(), comm.rank()) : std::pair{0, o.batch};
  prefetcher<std::vector<sample>> batches([&](long s) { return make_batch(o, s, with_photos, share.first, share.second); }, end,
                                          o.prefetch, omp_get_max_threads());
  while (step < o.steps) {
    tally.add(step_fn(step, batches.take(step)));
    ++step;
    const auto now = clock::now();
    if (root && (std::chrono::duration<double>(now - last_progress).count() >= o.progress_seconds || step == o.steps)) {
      const double rate = double(step - first) / std::max(std::chrono::duration<double>(now - start).count(), 1e-9);
      log(progress_line(kind, step, o.steps, tally.take_window(), rate, o.batch));
      last_progress = now;
    }
    if (root && ((o.validate_every > 0 && step % o.validate_every == 0) || step == o.steps)) {
      // The CSV's train_loss: mean over the steps since the previous validation (or the resume).
      const validation_result v = validate_fn();
      append_validation(csv, step, tally.take_since_validation(), v);
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

/// Trains the estimator (docs/method.md section 7): per step, `batch` procedural materials with their 5 training
/// inputs; loss = L1 (network space) + render loss; Adam (default rate 5e-5, the paper's).
/// `comm`: the ranks the run is spread over (train_options::data_parallel); every rank calls it
/// with the same options and the same starting weights.
template <class Preset>
void train_estimator(const train_options& o, estimation_network<Preset>& net, const communicator& comm = serial_communicator()) {
  if (o.size <= 0 || o.size % 64 != 0) throw std::invalid_argument("train-estimator: train_options::size must be a positive multiple of 64");
  o.validate();  // before the schedule is built from the options
  nn::adam opt(training_schedule(o.learning_rate > 0 ? o.learning_rate : 5e-5, o));
  opt.add_parameters(net);
  ad::tape t;
  const bool parts = steps_data_parallel(o, comm);
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
    throw std::invalid_argument("train-autoencoder: with estimates as inputs (train_options::inputs_are_estimates) train_options::size must be a positive multiple of 64 (the estimator's)");
  constexpr int cell = auto_encoder<Preset>::size_multiple;  // texels per latent cell along each side
  if (o.size <= 0 || o.size % cell != 0)
    throw std::invalid_argument("train-autoencoder: train_options::size must be a positive multiple of " + std::to_string(cell) +
                                " (one latent cell of this preset)");
  if (o.batch < 2 && o.size <= cell) throw std::invalid_argument("train-autoencoder: batch norm needs more than one latent value");
  o.validate();  // before the schedule is built from the options
  if (o.encoder_only && o.init_weights.empty() && !o.resume)
    throw std::invalid_argument("train-autoencoder: train_options::encoder_only trains against the decoder of the weights it starts from: "
                                "give them with train_options::init_weights (or train_options::resume such a run)");
  nn::adam opt(training_schedule(o.learning_rate > 0 ? o.learning_rate : 1e-3, o));
  opt.add_parameters(net);
  net.freeze_decoder(o.encoder_only);
  ad::tape t;
  const bool parts = steps_data_parallel(o, comm);
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
