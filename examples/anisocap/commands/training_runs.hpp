#pragma once
// What the training commands run, apart from their command line: train-estimator's and
// train-autoencoder's settings and runs, and eval-networks'. The runs are compiled in
// training_runs.cpp, beside the networks they train (the program's -O3 unit); train.hpp binds
// their options in the commands' unit.
#include <string>
#include <vector>

#include "anisocap/training/options.hpp"
#include "program.hpp"

namespace anisocap::commands::train_detail {

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

/// train-estimator: trains the estimator preset `s.preset` names into `s.options.out_dir`.
void run_train_estimator(const train_settings& s);

/// train-autoencoder: trains the auto-encoder preset `s.preset` names, from the true maps or from
/// the estimates of `s.input_estimator` (`s.inputs`).
void run_train_autoencoder(const train_settings& s);

/// Estimator against the mean-map baseline, and auto-encoder reconstruction, on validation
/// materials; the presets (compact or a compact variant) are read from the weight files.
void evaluate_networks(const network_eval_settings& s);

}  // namespace anisocap::commands::train_detail
