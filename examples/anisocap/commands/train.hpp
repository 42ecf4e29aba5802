#pragma once
// Training subcommands of the `anisocap` program (train-estimator, train-autoencoder) and the
// networks' evaluation (eval-networks); docs/model-card.md.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "anisocap/training/training.hpp"
#include "common.hpp"
#include "ranks.hpp"

namespace anisocap::commands {

namespace train_detail {


/// A training run: the network preset and the library's options.
struct train_settings {
  std::string preset = "compact";
  training::train_options options;
  std::string inputs = "truth";  ///< auto-encoder: what the encoder reads, truth or estimates
  /// Auto-encoder with estimates as inputs: the estimator weights that make them.
  std::string input_estimator = shipped_weights_file("estimator.safetensors").string();
};

/// The --preset choices of a trainer: the compact presets' names (networks/presets.hpp), the paper's
/// second where this build trains it (program_has_paper_preset).
template <class Paper, class Compact>
std::vector<std::string> preset_choices() {
  std::vector<std::string> names = Compact::names();
  if (program_has_paper_preset) names.insert(names.begin() + 1, Paper::name);
  return names;
}

/// --preset, with the presets of the network the command trains.
inline void add_preset_option(CLI::App* cmd, train_settings& s, bool autoencoder) {
  if (autoencoder)
    cmd->add_option("--preset", s.preset, "network widths: compact, compact-fine-512 (the second prior: a 512-wide latent, 6 map values "
                   "per latent value; 22 MB as floats, 11 MB with convert-weights --half), and in a build with "
                   "-DANISOCAP_EXPERIMENTAL_PRESETS=ON paper and the experimental compact-wide (twice the compact latent), "
                   "compact-fine (a latent cell per 16 x 16 texels instead of 32 x 32), compact-fine-wide (compact-fine with a "
                   "256-wide latent: the paper's 12 map values per latent value), compact-fine-wider (compact-fine-wide with "
                   "the levels above the latent twice as wide) and compact-fine-widest (compact-fine-wider with a 384-wide latent: 8 "
                   "map values per latent value)")
        ->check(preset_validator(preset_choices<autoencoder_paper, program_autoencoder_presets>()));
  else
    cmd->add_option("--preset", s.preset,
                    "network widths: compact, compact-orientation-doubled-angle (the shipped one: each photo's structure-tensor "
                    "orientation as 3 more input channels, the rotation read from a doubled-angle vector), and in a build with "
                    "-DANISOCAP_EXPERIMENTAL_PRESETS=ON paper and the experimental compact-doubled-angle (the doubled-angle "
                    "rotation alone) and compact-orientation (the orientation channels alone)")
        ->check(preset_validator(preset_choices<estimator_paper, program_estimator_presets>()));
}

/// The learning rate and its schedule: --lr, its decay, warm-up and re-warm-up.
inline void add_learning_rate_options(CLI::App* cmd, training::train_options& o) {
  cmd->add_option("--lr", o.learning_rate, "Adam learning rate (0: the paper's, 5e-5 estimator / 1e-3 auto-encoder; on --resume, the run's saved rate, "
                  "and another rate is logged and recorded in checkpoint.json)");
  cmd->add_option("--lr-decay-from", o.lr_decay_from,
                  "optimiser step at which the learning rate starts to decay along half a cosine (with --lr-decay-to)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--lr-decay-to", o.lr_decay_to,
                  "optimiser step at which the decay reaches --lr-end times the rate, kept after it (0: a constant rate; "
                  "on --resume, the run's saved decay, and another one is logged and recorded in checkpoint.json)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--lr-end", o.lr_end, "the learning rate after the decay, as a fraction of --lr")->check(CLI::Range(0.0, 1.0));
  cmd->add_option("--lr-warmup", o.lr_warmup,
                  "optimiser steps over which the learning rate rises linearly to its schedule (0: none; a run that starts "
                  "from trained weights with --init wants some: Adam's first steps at the full rate knock it off its minimum; "
                  "a resume must give the run's own value)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--lr-rewarmup", o.lr_rewarmup,
                  "optimiser steps over which the learning rate rises linearly again from --lr-rewarmup-from on (0: none; "
                  "for a --resume with a new decay, which otherwise jumps from the last decay's end rate to the full rate; "
                  "kept by a later resume that does not name another)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--lr-rewarmup-from", o.lr_rewarmup_from, "the optimiser step at which --lr-rewarmup starts (with it)")
      ->check(CLI::NonNegativeNumber)
      ->default_str("");  // unset (-1) until given
}

/// The training loss's weights: --render-weight, --lobe-weight, --sigma-weight, --mse-weight,
/// --diffuse-weight, --normal-weight.
inline void add_loss_weight_options(CLI::App* cmd, training::train_options& o) {
  cmd->add_option("--render-weight", o.render_weight,
                  "weight of the render loss against the L1 term in the training loss (validation always uses 1)");
  cmd->add_option("--lobe-weight", o.lobe_weight,
                  "weight of the lobe widths' and rotation's L1 against the other maps' in the training loss (validation always uses 1)");
  cmd->add_option("--sigma-weight", o.sigma_weight,
                  "weight of the lobe widths' squared error in the original range (what evaluations measure) added to the training loss "
                  "(0: none; validation always uses 0)");
  cmd->add_option("--mse-weight", o.mse_weight,
                  "weight of a_d's, a'_s', F0's and the normal's squared error in the original ranges (what evaluations measure) added "
                  "to the training loss (0: none; validation always uses 0)");
  cmd->add_option("--diffuse-weight", o.diffuse_weight,
                  "weight of a_d's L1 and squared error against the other maps' in the training loss (validation always uses 1)");
  cmd->add_option("--normal-weight", o.normal_weight,
                  "weight of the normal's L1 and squared error against the other maps' in the training loss (validation always "
                  "uses 1)");
}

/// train-autoencoder's own options: the smoothness term, the trainable part and the encoder's inputs.
inline void add_autoencoder_options(CLI::App* cmd, train_settings& s) {
  training::train_options& o = s.options;
  cmd->add_option("--smoothness", o.smoothness_weight, "weight of the latent smoothness term");
  cmd->add_option("--latent-noise", o.latent_noise, "standard deviation of the latent step delta");
  cmd->add_option_function<std::string>(
         "--trainable", [&o](const std::string& part) { o.encoder_only = part == "encoder"; },
         "what the run trains: all (default) or encoder (the decoder of the --init weights stays as it is, "
         "for the pipeline's fine-tune)")
      ->check(CLI::IsMember({"all", "encoder"}));
  cmd->add_option("--inputs", s.inputs,
                  "what the encoder reads: truth (the true maps, default) or estimates (the --input-estimator's estimates "
                  "of the materials' photos, which is what the pipeline encodes); the loss compares with the truth either way")
      ->check(CLI::IsMember({"truth", "estimates"}));
  cmd->add_option("--input-estimator", s.input_estimator, "estimator weights for --inputs estimates (default: the shipped ones)")
      ->check(CLI::ExistingFile);
}

/// train-estimator's own options: the training photographs' sensor noise.
inline void add_estimator_options(CLI::App* cmd, training::train_options& o) {
  cmd->add_option("--shot-noise", o.input_noise.shot,
                  "sensor shot noise on the training photographs: each material's get noise at a fraction, uniform in [0, 1], "
                  "of this level (relative standard deviation at pixel value 1; validation photographs stay exact)")
      ->check(finite_number(false));
  cmd->add_option("--read-noise", o.input_noise.read,
                  "sensor read noise on the training photographs, scaled by the same fraction as --shot-noise")
      ->check(finite_number(false));
}

/// The options both trainers share (and each one's own).
inline void add_common(CLI::App* cmd, train_settings& s, bool autoencoder) {
  training::train_options& o = s.options;
  add_preset_option(cmd, s, autoencoder);
  cmd->add_option("--out", o.out_dir, "output folder (checkpoints, weights, validation.csv)")->required();
  cmd->add_option("--steps", o.steps, "total optimiser steps (a resumed run continues up to this)");
  cmd->add_option("--size", o.size, autoencoder ? "material size in texels (square; a multiple of the preset's latent cell: 32, or 16 for the compact-fine presets)"
                                          : "material size in texels (square; multiple of 64)");
  cmd->add_option("--batch", o.batch, "materials per step");
  add_learning_rate_options(cmd, o);
  cmd->add_option("--seed", o.seed, "run seed (initial weights and training materials)");
  cmd->add_option("--checkpoint-minutes", o.checkpoint_minutes, "minutes between checkpoints");
  cmd->add_option("--validate-every", o.validate_every, "steps between validations");
  cmd->add_option("--validation-count", o.validation_count, "validation materials");
  cmd->add_flag("--resume", o.resume, "continue from OUT/checkpoint.json");
  cmd->add_option_function<std::string>(
         "--network-precision", [&o](const std::string& name) { o.precision = nn::parse_precision(name); },
         "operands of the convolutions: fp32, or bf16 (rounded to bfloat16, summed in FP32, FP32 master weights in Adam; "
         "needs a build for a CPU with AVX-512 BF16, see --version)")
      ->check(CLI::IsMember({"fp32", "bf16"}))
      ->default_str("fp32");
  cmd->add_option("--prefetch", o.prefetch, "build the next step's samples on a second thread during each step (true or false)");
  cmd->add_option("--data-parallel", o.data_parallel,
                  "true: compute each material's gradient alone and add the batch's in a fixed order, the weights of a run "
                  "under mpirun on any rank count bit for bit (always so under mpirun); false: the whole batch in one pass")
      ->default_str(o.data_parallel ? "true" : "false");
  add_mix_option(cmd, o.mix, {material_mix::original, material_mix::training},
                 "procedural families: original (the 8 original kinds) or training (all kinds but the held-out leather and printed)");
  cmd->add_option_function<std::string>(
         "--emphasis", [&o](const std::string& list) { o.emphasis = material_kinds_from_names(list); },
         "a curriculum: draw a share (--emphasis-share) of the training and validation materials from these families, "
         "comma-separated (e.g. brushed,spun), the rest from --materials; never a held-out family")
      ->check(family_list_check());
  cmd->add_option("--emphasis-share", o.emphasis_share, "fraction of the materials drawn from the --emphasis families")
      ->check(CLI::Range(0.0, 1.0));
  add_loss_weight_options(cmd, o);
  cmd->add_option("--init", o.init_weights, "start a fresh run from these weights (safetensors) instead of random ones")->check(CLI::ExistingFile);
  if (autoencoder) add_autoencoder_options(cmd, s);
  else add_estimator_options(cmd, o);
}

/// The flag that sets each train_options field a library message names.
inline constexpr option_name train_field_flags[] = {
    {"train_options::steps", "--steps"},
    {"train_options::seed", "--seed"},
    {"train_options::size", "--size"},
    {"train_options::batch", "--batch"},
    {"train_options::learning_rate", "--lr"},
    {"train_options::checkpoint_minutes", "--checkpoint-minutes"},
    {"train_options::validate_every", "--validate-every"},
    {"train_options::validation_count", "--validation-count"},
    {"train_options::resume", "--resume"},
    {"train_options::init_weights", "--init"},
    {"train_options::smoothness_weight", "--smoothness"},
    {"train_options::latent_noise", "--latent-noise"},
    {"train_options::render_weight", "--render-weight"},
    {"train_options::lobe_weight", "--lobe-weight"},
    {"train_options::sigma_weight", "--sigma-weight"},
    {"train_options::mse_weight", "--mse-weight"},
    {"train_options::diffuse_weight", "--diffuse-weight"},
    {"train_options::normal_weight", "--normal-weight"},
    {"train_options::encoder_only false", "--trainable all"},  // a resume's hint, before the field alone
    {"train_options::encoder_only true", "--trainable encoder"},
    {"train_options::encoder_only", "--trainable encoder"},
    {"train_options::inputs_are_estimates false", "--inputs truth"},
    {"train_options::inputs_are_estimates true", "--inputs estimates"},
    {"train_options::inputs_are_estimates", "--inputs estimates"},
    {"train_options::mix", "--materials"},
    {"train_options::emphasis", "--emphasis"},
    {"train_options::emphasis_share", "--emphasis-share"},
    {"train_options::input_noise.shot", "--shot-noise"},
    {"train_options::input_noise.read", "--read-noise"},
    {"train_options::lr_decay_from", "--lr-decay-from"},
    {"train_options::lr_decay_to", "--lr-decay-to"},
    {"train_options::lr_end", "--lr-end"},
    {"train_options::lr_warmup", "--lr-warmup"},
    {"train_options::lr_rewarmup", "--lr-rewarmup"},
    {"train_options::lr_rewarmup_from", "--lr-rewarmup-from"},
    {"train_options::data_parallel", "--data-parallel"},
    {"train_options::prefetch", "--prefetch"},
    {"train_options::precision", "--network-precision"},
    {"train_autoencoder", "train-autoencoder"},  // the trainer a resume names
    {"train_estimator", "train-estimator"},
    {"the preset", "--preset"},                  // the trainer's template argument
};

/// The flags that set the estimate_options fields eval-networks' messages name.
inline constexpr option_name eval_networks_field_flags[] = {{"estimate_options::window", "--window"}, {"estimate_options::stride", "--stride"}};

/// Runs `train(options, net)` on a Net<P> built from the run seed, P the preset s.preset names:
/// Paper ("paper") or one of the list Compact (networks/presets.hpp), while holding the output
/// folder's lock; a run refused before writing anything leaves no folder behind. Under an MPI
/// launcher every rank trains a share of each batch (train_options::data_parallel) and rank 0
/// alone locks and writes the folder.
template <template <class...> class Net, class Paper, class Compact, class Train>
void train_in_locked_folder(const train_settings& settings, Train train) {
  train_settings s = settings;
  training::train_options& o = s.options;
  const communicator& ranks = program_ranks();
  if (mpi_job()) o.data_parallel = true;
  std::optional<output_lock> lock;
  if (ranks.root()) lock.emplace(o.out_dir);  // one run per output folder
  auto run = [&]<class P>() {
    auto net = std::make_unique<Net<P>>(o.seed);
    train(o, *net, ranks);
  };
  naming_options(train_field_flags, [&] {  // the library names train_options fields: name the flags
    if constexpr (program_has_paper_preset)
      if (s.preset == Paper::name) return run.template operator()<Paper>();
    Compact::call(s.preset, run, [&] { return "--preset " + s.preset + ": not one of " + CLI::detail::join(preset_choices<Paper, Compact>(), ", "); });
  });
}

/// Settings of eval-networks.
struct network_eval_settings {
  std::string estimator = shipped_weights_file("estimator.safetensors").string();
  std::string autoencoder = shipped_weights_file("autoencoder.safetensors").string();
  int count = 30;
  int size = 256;
  int window = 0;  ///< > 0: the estimator runs as the pipeline's estimate does, over sliding windows of this side (0: the whole material at once)
  int stride = 0;  ///< the windows' step (0: window / 4)
  /// The windows `window` and `stride` describe (meaningful when window > 0).
  estimate_options windows() const { return {window, stride > 0 ? stride : window / 4}; }
  std::string markdown;
  material_mix mix = material_mix::original;  ///< the mix the validation materials' kinds are drawn from
  std::string families;  ///< non-empty: comma-separated families, material i gets the (i mod n)-th
  sensor_noise noise;    ///< simulated sensor noise on the estimator's inputs (none: exact renders)
};

inline std::string row(const char* name, const parameter_errors& e) {
  char line[256];
  std::snprintf(line, sizeof line, "| %s | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g |\n", name, e.diffuse, e.specular,
                e.normal, e.lobes, e.rotation, e.rotation_anisotropic, e.fresnel);
  return line;
}

/// eval-networks' validation materials (their kinds in `kinds`), with the settings' sensor noise on
/// their photographs.
inline std::vector<training::sample> network_eval_samples(const network_eval_settings& s, const std::vector<material_kind>& families,
                                                          std::vector<material_kind>& kinds) {
  std::vector<training::sample> samples;
  for (int i = 0; i < s.count; ++i) {
    const std::uint64_t seed = training::validation_seed(i);
    procedural_options options;
    options.mix = s.mix;
    options.kind = evaluation_kind(i, seed, families, s.mix);
    kinds.push_back(*options.kind);
    samples.push_back(training::make_sample(seed, s.size, true, options));
    add_sensor_noise(samples.back().photos, s.noise, hash64(seed ^ 0x6e6574776f726b73ULL));
  }
  return samples;
}

/// The per-texel mean of the samples' true maps (size x size): eval-networks' baseline.
inline material_maps mean_of_truths(const std::vector<training::sample>& samples, int size) {
  material_maps mean(size, size);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t j = 0; j < mean.texel_count(); ++j) {
      double sum = 0;
      for (const auto& x : samples) sum += x.truth.plane(k)[j];
      mean.plane(k)[j] = float(sum / double(samples.size()));
    }
  return mean;
}

/// Each validation material's errors for eval-networks' four rows.
struct network_eval_errors {
  std::vector<material_errors> estimator, baseline, autoencoder, start;
};

/// eval-networks' report (Markdown): the settings, the four rows' mean errors, then per family.
inline std::string network_eval_report(const network_eval_settings& s, const std::vector<material_kind>& families, const char* estimator_name,
                                       const char* autoencoder_name, const network_eval_errors& errors) {
  const parameter_errors est = average_errors(errors.estimator).mean, base = average_errors(errors.baseline).mean,
                         ae = average_errors(errors.autoencoder).mean, start = average_errors(errors.start).mean;
  const auto number = [](double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", v);
    return std::string(text);
  };
  std::string md = "Validation materials: " + std::to_string(s.count) + " (seeds 2^62 + 0 ... ; " +
                   (families.empty() ? std::string(material_mix_name(s.mix)) + " mix" : "families " + s.families) + "), " +
                   std::to_string(s.size) + " x " + std::to_string(s.size) +
                   (s.window > 0 ? ", the estimator over " + std::to_string(s.window) + " x " + std::to_string(s.window) + " windows (stride " +
                                       std::to_string(s.windows().stride) + ", as the pipeline's estimate)"
                                 : std::string()) +
                   ", 5 inputs (training set)" +
                   (s.noise.enabled() ? " with sensor noise (shot " + number(s.noise.shot) + ", read " + number(s.noise.read) + ")"
                                      : std::string()) +
                   "; MSE in the original ranges (compare_maps; alpha modulo pi over all texels, "
                   "and over the anisotropic texels of the materials that have them)\n\n";
  md += "| model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|\n";
  md += row(("estimator (" + std::string(estimator_name) + ")").c_str(), est);
  md += row("mean-map baseline", base);
  md += row(("auto-encoder reconstruction (" + std::string(autoencoder_name) + ")").c_str(), ae);
  md += row("estimate through the auto-encoder (the fine-tune's start)", start);
  md += "\nPer family (held out of training: leather, printed; the baseline is the mean map of all materials above)\n\n";
  md += "| family | materials | model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|---|---|\n";
  const auto est_rows = errors_by_family(errors.estimator), base_rows = errors_by_family(errors.baseline),
             ae_rows = errors_by_family(errors.autoencoder), start_rows = errors_by_family(errors.start);
  for (std::size_t k = 0; k < est_rows.size(); ++k) {
    const std::string prefix = std::string(material_kind_name(est_rows[k].kind)) + (is_held_out(est_rows[k].kind) ? " (held out)" : "") +
                               " | " + std::to_string(est_rows[k].count);
    md += row((prefix + " | estimator").c_str(), est_rows[k].mean);
    md += row((prefix + " | baseline").c_str(), base_rows[k].mean);
    md += row((prefix + " | auto-encoder").c_str(), ae_rows[k].mean);
    md += row((prefix + " | estimate through the auto-encoder").c_str(), start_rows[k].mean);
  }
  return md;
}

/// eval-networks with an estimator and an auto-encoder of the given presets.
template <class EstimatorPreset, class AutoEncoderPreset>
void evaluate_networks_with(const network_eval_settings& s) {
  const std::vector<material_kind> families = material_kinds_from_names(s.families);
  estimation_network<EstimatorPreset> estimator;
  auto_encoder<AutoEncoderPreset> autoencoder;
  nn::load_weights(s.estimator, estimator);
  nn::load_weights(s.autoencoder, autoencoder);
  std::vector<material_kind> kinds;
  const std::vector<training::sample> samples = network_eval_samples(s, families, kinds);
  const material_maps mean = mean_of_truths(samples, s.size);
  network_eval_errors errors;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const auto& x = samples[i];
    tensor<parameter_count> u;
    if (s.window > 0) {
      const material_maps m = estimate(x.photos, estimator, s.windows());
      u = tensor<parameter_count>(1, s.size, s.size);
      network_space::maps_to_network(m, u, 0);
    } else {
      u = training::estimator_output(estimator, x);
    }
    errors.estimator.push_back({kinds[i], compare_maps(network_space::network_to_maps(u, 0), x.truth)});
    errors.baseline.push_back({kinds[i], compare_maps(mean, x.truth)});
    const auto r = training::autoencoder_output(autoencoder, x);
    errors.autoencoder.push_back({kinds[i], compare_maps(network_space::network_to_maps(r, 0), x.truth)});
    // The fine-tune's start: the decoder's maps of the estimate's latent code (docs/method.md section 8.2).
    const auto d = training::autoencoder_output(autoencoder, x, &u);
    errors.start.push_back({kinds[i], compare_maps(network_space::network_to_maps(d, 0), x.truth)});
  }
  const std::string md = network_eval_report(s, families, EstimatorPreset::name, AutoEncoderPreset::name, errors);
  std::printf("%s", md.c_str());
  if (!s.markdown.empty()) write_file_atomically(s.markdown, md);
}

/// Estimator against the mean-map baseline, and auto-encoder reconstruction, on validation
/// materials; the presets (compact or a compact variant) are read from the weight files.
inline void evaluate_networks(const network_eval_settings& s) {
  if (s.window % 64 != 0)
    throw std::invalid_argument("eval-networks: --window " + std::to_string(s.window) + " is not a multiple of 64 (the estimator's)");
  if (s.window > 0) naming_options(eval_networks_field_flags, [&] { s.windows().validate(); });
  with_estimator_preset<program_estimator_presets>(s.estimator, [&]<class P>() {
    with_autoencoder_preset<program_autoencoder_presets>(s.autoencoder, [&]<class A>() { evaluate_networks_with<P, A>(s); });
  });
}

}  // namespace train_detail

/// Settings of convert-weights.
struct convert_settings {
  fs::path input, output;
  bool half = false;  ///< weight_storage::f16 (else f32)
};

/// convert-weights: nn::convert_weights, refusing to write over its input; prints both sizes.
inline void convert_weights(const convert_settings& s) {
  refuse_overwriting_inputs({s.output}, {s.input}, "choose another output file");
  nn::convert_weights(s.input, s.output, s.half ? nn::weight_storage::f16 : nn::weight_storage::f32);
  std::printf("%s: %.1f MB (%s: %.1f MB), the large tensors as %s\n", s.output.string().c_str(), double(fs::file_size(s.output)) / 1e6,
              s.input.string().c_str(), double(fs::file_size(s.input)) / 1e6, s.half ? "half floats" : "floats");
}

/// Registers `anisocap train-estimator`, `train-autoencoder`, `eval-networks` and `convert-weights`.
inline void add_train_commands(CLI::App& app) {
  using namespace train_detail;
  auto est = std::make_shared<train_settings>();
  auto* est_cmd = app.add_subcommand("train-estimator", "train the estimation network on procedural materials");
  add_common(est_cmd, *est, false);
  est_cmd->callback([est] {
    run_on_ranks([&] {
      train_in_locked_folder<estimation_network, estimator_paper, program_estimator_presets>(
          *est, [](const training::train_options& o, auto& net, const communicator& ranks) { training::train_estimator(o, net, ranks); });
    });
  });
  auto ae = std::make_shared<train_settings>();
  ae->options = training::train_options::autoencoder();
  auto* ae_cmd = app.add_subcommand("train-autoencoder", "train the map auto-encoder on procedural materials");
  add_common(ae_cmd, *ae, true);
  ae_cmd->callback([ae] {
    run_on_ranks([&] {
      train_in_locked_folder<auto_encoder, autoencoder_paper, program_autoencoder_presets>(
          *ae, [&s = *ae](const training::train_options& o, auto& net, const communicator& ranks) {
            if (s.inputs == "truth") return training::train_autoencoder(o, net, ranks);
            with_estimator_preset<program_estimator_presets>(s.input_estimator, [&]<class P>() {
              auto estimator = std::make_unique<estimation_network<P>>();
              nn::load_weights(s.input_estimator, *estimator);
              training::train_autoencoder(o, net, *estimator, ranks);
            });
          });
    });
  });
  auto ev = std::make_shared<network_eval_settings>();
  auto* ev_cmd = app.add_subcommand("eval-networks", "per-parameter errors of the compact estimator (against the mean-map baseline) and auto-encoder");
  ev_cmd->add_option("--estimator", ev->estimator, "estimator weights");
  ev_cmd->add_option("--autoencoder", ev->autoencoder, "auto-encoder weights");
  ev_cmd->add_option("--count", ev->count, "validation materials");
  ev_cmd->add_option("--size", ev->size, "material size (multiple of 64)");
  ev_cmd->add_option("--window", ev->window,
                     "run the estimator over sliding windows of this side (stride a quarter), as capture's estimate stage does "
                     "(default: the whole material at once)")
      ->check(CLI::Range(64, 1 << 16));
  ev_cmd->add_option("--stride", ev->stride, "the windows' step (default: a quarter of --window)")->check(CLI::Range(1, 1 << 16));
  ev_cmd->add_option("--markdown", ev->markdown, "also write the table to this file");
  add_mix_option(ev_cmd, ev->mix, {material_mix::original, material_mix::extended, material_mix::training},
                 "families the materials are drawn from: original, extended or training");
  ev_cmd->add_option("--families", ev->families,
                     "evaluate these families only, comma-separated (e.g. leather,printed); material i gets the (i mod n)-th")
      ->check(family_list_check());
  add_noise_options(ev_cmd, ev->noise);
  ev_cmd->callback([ev] { evaluate_networks(*ev); });
  auto cv = std::make_shared<convert_settings>();
  auto* cv_cmd = app.add_subcommand("convert-weights",
                                    "rewrite a weight file with its large tensors as half floats (--half: half the size) or as floats");
  cv_cmd->add_option("input", cv->input, "weight file (safetensors)")->required()->check(CLI::ExistingFile);
  cv_cmd->add_option("output", cv->output, "the file to write (not the input)")->required();
  cv_cmd->add_flag("--half", cv->half,
                   "store the tensors of 1024 or more values (the convolution kernels) as half floats; without it, every tensor as "
                   "floats");
  cv_cmd->callback([cv] { convert_weights(*cv); });
}

}  // namespace anisocap::commands
