#pragma once
// The command lines of the `anisocap` program's training subcommands (train-estimator,
// train-autoencoder), the networks' evaluation (eval-networks) and convert-weights; what the first
// three run is in training_runs.hpp. docs/model-card.md.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <memory>
#include <string>

#include "anisocap/training/options.hpp"
#include "common.hpp"
#include "ranks.hpp"
#include "training_runs.hpp"

namespace anisocap::commands {

namespace train_detail {

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
  cmd->add_option(train_flag("train_options::learning_rate"), o.learning_rate, "Adam learning rate (0: the paper's, 5e-5 estimator / 1e-3 auto-encoder; on --resume, the run's saved rate, "
                  "and another rate is logged and recorded in checkpoint.json)");
  cmd->add_option(train_flag("train_options::lr_decay_from"), o.lr_decay_from,
                  "optimiser step at which the learning rate starts to decay along half a cosine (with --lr-decay-to)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option(train_flag("train_options::lr_decay_to"), o.lr_decay_to,
                  "optimiser step at which the decay reaches --lr-end times the rate, kept after it (0: a constant rate; "
                  "on --resume, the run's saved decay, and another one is logged and recorded in checkpoint.json)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option(train_flag("train_options::lr_end"), o.lr_end, "the learning rate after the decay, as a fraction of --lr")->check(CLI::Range(0.0, 1.0));
  cmd->add_option(train_flag("train_options::lr_warmup"), o.lr_warmup,
                  "optimiser steps over which the learning rate rises linearly to its schedule (0: none; a run that starts "
                  "from trained weights with --init wants some: Adam's first steps at the full rate knock it off its minimum; "
                  "a resume must give the run's own value)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option(train_flag("train_options::lr_rewarmup"), o.lr_rewarmup,
                  "optimiser steps over which the learning rate rises linearly again from --lr-rewarmup-from on (0: none; "
                  "for a --resume with a new decay, which otherwise jumps from the last decay's end rate to the full rate; "
                  "kept by a later resume that does not name another)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option(train_flag("train_options::lr_rewarmup_from"), o.lr_rewarmup_from, "the optimiser step at which --lr-rewarmup starts (with it)")
      ->check(CLI::NonNegativeNumber)
      ->default_str("");  // unset (-1) until given
}

/// The training loss's weights: --render-weight, --lobe-weight, --sigma-weight, --mse-weight,
/// --diffuse-weight, --normal-weight.
inline void add_loss_weight_options(CLI::App* cmd, training::train_options& o) {
  cmd->add_option(train_flag("train_options::render_weight"), o.render_weight,
                  "weight of the render loss against the L1 term in the training loss (validation always uses 1)");
  cmd->add_option(train_flag("train_options::lobe_weight"), o.lobe_weight,
                  "weight of the lobe widths' and rotation's L1 against the other maps' in the training loss (validation always uses 1)");
  cmd->add_option(train_flag("train_options::sigma_weight"), o.sigma_weight,
                  "weight of the lobe widths' squared error in the original range (what evaluations measure) added to the training loss "
                  "(0: none; validation always uses 0)");
  cmd->add_option(train_flag("train_options::mse_weight"), o.mse_weight,
                  "weight of a_d's, a'_s', F0's and the normal's squared error in the original ranges (what evaluations measure) added "
                  "to the training loss (0: none; validation always uses 0)");
  cmd->add_option(train_flag("train_options::diffuse_weight"), o.diffuse_weight,
                  "weight of a_d's L1 and squared error against the other maps' in the training loss (validation always uses 1)");
  cmd->add_option(train_flag("train_options::normal_weight"), o.normal_weight,
                  "weight of the normal's L1 and squared error against the other maps' in the training loss (validation always "
                  "uses 1)");
}

/// train-autoencoder's own options: the smoothness term, the trainable part and the encoder's inputs.
inline void add_autoencoder_options(CLI::App* cmd, train_settings& s) {
  training::train_options& o = s.options;
  cmd->add_option(train_flag("train_options::smoothness_weight"), o.smoothness_weight, "weight of the latent smoothness term");
  cmd->add_option(train_flag("train_options::latent_noise"), o.latent_noise, "standard deviation of the latent step delta");
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
  cmd->add_option(train_flag("train_options::input_noise.shot"), o.input_noise.shot,
                  "sensor shot noise on the training photographs: each material's get noise at a fraction, uniform in [0, 1], "
                  "of this level (relative standard deviation at pixel value 1; validation photographs stay exact)")
      ->check(finite_number(false));
  cmd->add_option(train_flag("train_options::input_noise.read"), o.input_noise.read,
                  "sensor read noise on the training photographs, scaled by the same fraction as --shot-noise")
      ->check(finite_number(false));
}

/// The options both trainers share (and each one's own).
inline void add_common(CLI::App* cmd, train_settings& s, bool autoencoder) {
  training::train_options& o = s.options;
  add_preset_option(cmd, s, autoencoder);
  cmd->add_option("--out", o.out_dir, "output folder (checkpoints, weights, validation.csv)")->required();
  cmd->add_option(train_flag("train_options::steps"), o.steps, "total optimiser steps (a resumed run continues up to this)");
  cmd->add_option(train_flag("train_options::size"), o.size, autoencoder ? "material size in texels (square; a multiple of the preset's latent cell: 32, or 16 for the compact-fine presets)"
                                          : "material size in texels (square; multiple of 64)");
  cmd->add_option(train_flag("train_options::batch"), o.batch, "materials per step");
  add_learning_rate_options(cmd, o);
  cmd->add_option(train_flag("train_options::seed"), o.seed, "run seed (initial weights and training materials)");
  cmd->add_option(train_flag("train_options::checkpoint_minutes"), o.checkpoint_minutes, "minutes between checkpoints");
  cmd->add_option(train_flag("train_options::validate_every"), o.validate_every, "steps between validations");
  cmd->add_option(train_flag("train_options::validation_count"), o.validation_count, "validation materials");
  cmd->add_flag(train_flag("train_options::resume"), o.resume, "continue from OUT/checkpoint.json");
  cmd->add_option_function<std::string>(
         train_flag("train_options::precision"), [&o](const std::string& name) { o.precision = nn::parse_precision(name); },
         "operands of the convolutions: fp32, or bf16 (rounded to bfloat16, summed in FP32, FP32 master weights in Adam; "
         "needs a build for a CPU with AVX-512 BF16, see --version)")
      ->check(CLI::IsMember({"fp32", "bf16"}))
      ->default_str("fp32");
  cmd->add_option(train_flag("train_options::prefetch"), o.prefetch, "build the next step's samples on a second thread during each step (true or false)");
  cmd->add_option(train_flag("train_options::data_parallel"), o.data_parallel,
                  "true: compute each material's gradient alone and add the batch's in a fixed order, the weights of a run "
                  "under mpirun on any rank count bit for bit (always so under mpirun); false: the whole batch in one pass")
      ->default_str(o.data_parallel ? "true" : "false");
  add_mix_option(cmd, o.mix, {material_mix::original, material_mix::training},
                 "procedural families: original (the 8 original kinds) or training (all kinds but the held-out leather and printed)");
  cmd->add_option_function<std::string>(
         train_flag("train_options::emphasis"), [&o](const std::string& list) { o.emphasis = material_kinds_from_names(list); },
         "a curriculum: draw a share (--emphasis-share) of the training and validation materials from these families, "
         "comma-separated (e.g. brushed,spun), the rest from --materials; never a held-out family")
      ->check(family_list_check());
  cmd->add_option(train_flag("train_options::emphasis_share"), o.emphasis_share, "fraction of the materials drawn from the --emphasis families")
      ->check(CLI::Range(0.0, 1.0));
  add_loss_weight_options(cmd, o);
  cmd->add_option(train_flag("train_options::init_weights"), o.init_weights, "start a fresh run from these weights (safetensors) instead of random ones")->check(CLI::ExistingFile);
  if (autoencoder) add_autoencoder_options(cmd, s);
  else add_estimator_options(cmd, o);
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
  est_cmd->callback([est] { run_on_ranks([&] { run_train_estimator(*est); }); });
  auto ae = std::make_shared<train_settings>();
  ae->options = training::train_options::autoencoder();
  auto* ae_cmd = app.add_subcommand("train-autoencoder", "train the map auto-encoder on procedural materials");
  add_common(ae_cmd, *ae, true);
  ae_cmd->callback([ae] { run_on_ranks([&] { run_train_autoencoder(*ae); }); });
  auto ev = std::make_shared<network_eval_settings>();
  auto* ev_cmd = app.add_subcommand("eval-networks", "per-parameter errors of the compact estimator (against the mean-map baseline) and auto-encoder");
  ev_cmd->add_option("--estimator", ev->estimator, "estimator weights");
  ev_cmd->add_option("--autoencoder", ev->autoencoder, "auto-encoder weights");
  ev_cmd->add_option("--count", ev->count, "validation materials");
  ev_cmd->add_option("--size", ev->size, "material size (multiple of 64)");
  ev_cmd->add_option(flag_of(eval_networks_field_flags, "estimate_options::window"), ev->window,
                     "run the estimator over sliding windows of this side (stride a quarter), as capture's estimate stage does "
                     "(default: the whole material at once)")
      ->check(CLI::Range(64, 1 << 16));
  ev_cmd->add_option(flag_of(eval_networks_field_flags, "estimate_options::stride"), ev->stride, "the windows' step (default: a quarter of --window)")->check(CLI::Range(1, 1 << 16));
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
