#pragma once
// Training subcommands of the `anisocap` program (train-estimator, train-autoencoder) and the
// networks' evaluation (eval-networks). Registered by examples/anisocap.cpp through
// add_train_commands(); issue 4, models/README.md.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "anisocap/pipeline/training.hpp"

namespace anisocap::commands {

namespace train_detail {

/// Command-line settings of a training run (mirrors training::train_options).
struct train_settings {
  std::string preset = "compact";
  std::string out;
  long steps = 2000;
  int size = 128;
  int batch = 2;
  double learning_rate = 0;
  unsigned long long seed = 1;
  double checkpoint_minutes = 5;
  long validate_every = 250;
  int validation_count = 8;
  bool resume = false;
  std::string init;
  double smoothness = 0.1;
  double latent_noise = 0.1;
  std::string materials = "original";
};

inline training::train_options to_options(const train_settings& s) {
  training::train_options o;
  o.out_dir = s.out;
  o.steps = s.steps;
  o.size = s.size;
  o.batch = s.batch;
  o.learning_rate = s.learning_rate;
  o.seed = s.seed;
  o.checkpoint_minutes = s.checkpoint_minutes;
  o.validate_every = s.validate_every;
  o.validation_count = s.validation_count;
  o.resume = s.resume;
  o.init_weights = s.init;
  o.smoothness_weight = s.smoothness;
  o.latent_noise = s.latent_noise;
  o.mix = *material_mix_from_name(s.materials);
  return o;
}

inline void add_common(CLI::App* cmd, train_settings& s, bool autoencoder) {
  cmd->add_option("--preset", s.preset, "network widths: compact or paper")->check(CLI::IsMember({"compact", "paper"}));
  cmd->add_option("--out", s.out, "output folder (checkpoints, weights, validation.csv)")->required();
  cmd->add_option("--steps", s.steps, "total optimiser steps (a resumed run continues up to this)");
  cmd->add_option("--size", s.size, std::string("material size in texels (square; multiple of ") + (autoencoder ? "32" : "64") + ")");
  cmd->add_option("--batch", s.batch, "materials per step");
  cmd->add_option("--lr", s.learning_rate, "Adam learning rate (default: the paper's, 5e-5 estimator / 1e-3 auto-encoder)");
  cmd->add_option("--seed", s.seed, "run seed (initial weights and training materials)");
  cmd->add_option("--checkpoint-minutes", s.checkpoint_minutes, "minutes between checkpoints");
  cmd->add_option("--validate-every", s.validate_every, "steps between validations");
  cmd->add_option("--validation-count", s.validation_count, "validation materials");
  cmd->add_flag("--resume", s.resume, "continue from OUT/checkpoint.json");
  cmd->add_option("--materials", s.materials,
                  "procedural families: original (the 8 original kinds) or training (all kinds but the held-out "
                  "leather and printed)")
      ->check(CLI::IsMember({"original", "training"}));
  cmd->add_option("--init", s.init, "start a fresh run from these weights (safetensors) instead of random ones")->check(CLI::ExistingFile);
  if (autoencoder) {
    cmd->add_option("--smoothness", s.smoothness, "weight of the latent smoothness term");
    cmd->add_option("--latent-noise", s.latent_noise, "standard deviation of the latent step delta");
  }
}

/// Settings of eval-networks.
struct eval_settings {
  std::string estimator = "models/compact/estimator.safetensors";
  std::string autoencoder = "models/compact/autoencoder.safetensors";
  int count = 30;
  int size = 256;
  std::string markdown;
  std::string materials = "original";  ///< mix the validation materials' kinds are drawn from
  std::string families;                ///< non-empty: comma-separated families, material i gets the (i mod n)-th
};

inline std::string row(const char* name, const parameter_errors& e) {
  char line[256];
  std::snprintf(line, sizeof line, "| %s | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g |\n", name, e.diffuse, e.specular,
                e.normal, e.lobes, e.rotation, e.fresnel);
  return line;
}

/// Estimator against the mean-map baseline, and auto-encoder reconstruction, on validation materials.
inline void evaluate_networks(const eval_settings& s) {
  const std::vector<material_kind> families = material_kinds_from_names(s.families);
  const material_mix mix = *material_mix_from_name(s.materials);
  EstimationNet<estimator_compact> estimator;
  AutoEncoder<autoencoder_compact> autoencoder;
  nn::load_weights(s.estimator, estimator);
  nn::load_weights(s.autoencoder, autoencoder);
  std::vector<training::sample> samples;
  std::vector<material_kind> kinds;
  for (int i = 0; i < s.count; ++i) {
    const std::uint64_t seed = training::validation_seed(i);
    procedural_options options;
    options.mix = mix;
    options.kind = evaluation_kind(i, seed, families, mix);
    kinds.push_back(*options.kind);
    samples.push_back(training::make_sample(seed, s.size, true, options));
  }
  // The baseline: the per-texel mean of the validation set's true maps.
  material_maps mean(s.size, s.size);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t j = 0; j < mean.texel_count(); ++j) {
      double sum = 0;
      for (const auto& x : samples) sum += x.truth.plane(k)[j];
      mean.plane(k)[j] = float(sum / s.count);
    }
  parameter_errors est, base, ae;
  std::vector<material_errors> est_all, base_all, ae_all;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const auto& x = samples[i];
    const auto u = training::estimator_output(estimator, x);
    const parameter_errors e = compare_maps(network_space::network_to_maps(u, 0), x.truth), b = compare_maps(mean, x.truth);
    const auto r = training::autoencoder_output(autoencoder, x);
    const parameter_errors a = compare_maps(network_space::network_to_maps(r, 0), x.truth);
    training::accumulate(est, e, s.count);
    training::accumulate(base, b, s.count);
    training::accumulate(ae, a, s.count);
    est_all.push_back({kinds[i], e});
    base_all.push_back({kinds[i], b});
    ae_all.push_back({kinds[i], a});
  }
  std::string md = "Validation materials: " + std::to_string(s.count) + " (seeds 2^62 + 0 ... ; " +
                   (families.empty() ? std::string(material_mix_name(mix)) + " mix" : "families " + s.families) + "), " +
                   std::to_string(s.size) + " x " + std::to_string(s.size) +
                   ", 5 inputs (training set); MSE in the original ranges (compare_maps)\n\n";
  md += "| model | a_d | a'_s | n_s | sigma | alpha (mod pi) | F0 |\n|---|---|---|---|---|---|---|\n";
  md += row("estimator (compact)", est);
  md += row("mean-map baseline", base);
  md += row("auto-encoder reconstruction (compact)", ae);
  md += "\nPer family (held out of training: leather, printed; the baseline is the mean map of all materials above)\n\n";
  md += "| family | materials | model | a_d | a'_s | n_s | sigma | alpha (mod pi) | F0 |\n|---|---|---|---|---|---|---|---|---|\n";
  const auto est_rows = errors_by_family(est_all), base_rows = errors_by_family(base_all), ae_rows = errors_by_family(ae_all);
  for (std::size_t k = 0; k < est_rows.size(); ++k) {
    const std::string prefix = std::string(material_kind_name(est_rows[k].kind)) + (is_held_out(est_rows[k].kind) ? " (held out)" : "") +
                               " | " + std::to_string(est_rows[k].count);
    md += row((prefix + " | estimator").c_str(), est_rows[k].mean);
    md += row((prefix + " | baseline").c_str(), base_rows[k].mean);
    md += row((prefix + " | auto-encoder").c_str(), ae_rows[k].mean);
  }
  std::printf("%s", md.c_str());
  if (!s.markdown.empty()) {
    std::ofstream out(s.markdown);
    out << md;
    if (!out) throw std::runtime_error(s.markdown + ": cannot write");
  }
}

}  // namespace train_detail

/// Adds the training subcommands to `app`. Each returns, through `actions`, the function to run
/// when its subcommand was chosen (the program runs every action whose subcommand parsed).
inline void add_train_commands(CLI::App& app, std::vector<std::pair<CLI::App*, std::function<void()>>>& actions) {
  using namespace train_detail;
  auto est = std::make_shared<train_settings>();
  est->learning_rate = 0;
  auto* est_cmd = app.add_subcommand("train-estimator", "train the estimation network on procedural materials");
  add_common(est_cmd, *est, false);
  actions.emplace_back(est_cmd, [est] {
    const auto o = to_options(*est);
    if (est->preset == "paper") {
      auto net = std::make_unique<EstimationNet<estimator_paper>>(est->seed);
      training::train_estimator(o, *net);
    } else {
      auto net = std::make_unique<EstimationNet<estimator_compact>>(est->seed);
      training::train_estimator(o, *net);
    }
  });
  auto ae = std::make_shared<train_settings>();
  ae->batch = 4;
  auto* ae_cmd = app.add_subcommand("train-autoencoder", "train the map auto-encoder on procedural materials");
  add_common(ae_cmd, *ae, true);
  actions.emplace_back(ae_cmd, [ae] {
    const auto o = to_options(*ae);
    if (ae->preset == "paper") {
      auto net = std::make_unique<AutoEncoder<autoencoder_paper>>(ae->seed);
      training::train_autoencoder(o, *net);
    } else {
      auto net = std::make_unique<AutoEncoder<autoencoder_compact>>(ae->seed);
      training::train_autoencoder(o, *net);
    }
  });
  auto ev = std::make_shared<eval_settings>();
  auto* ev_cmd = app.add_subcommand("eval-networks", "per-parameter errors of the compact estimator (against the mean-map baseline) and auto-encoder");
  ev_cmd->add_option("--estimator", ev->estimator, "estimator weights");
  ev_cmd->add_option("--autoencoder", ev->autoencoder, "auto-encoder weights");
  ev_cmd->add_option("--count", ev->count, "validation materials");
  ev_cmd->add_option("--size", ev->size, "material size (multiple of 64)");
  ev_cmd->add_option("--markdown", ev->markdown, "also write the table to this file");
  ev_cmd->add_option("--materials", ev->materials, "families the materials are drawn from: original, extended or training")
      ->check(CLI::IsMember({"original", "extended", "training"}));
  ev_cmd->add_option("--families", ev->families,
                     "evaluate these families only, comma-separated (e.g. leather,printed); material i gets the (i mod n)-th")
      ->check([](const std::string& list) {
        try {
          material_kinds_from_names(list);
          return std::string();
        } catch (const std::invalid_argument& e) {
          return std::string(e.what());
        }
      });
  actions.emplace_back(ev_cmd, [ev] { evaluate_networks(*ev); });
}

}  // namespace anisocap::commands
