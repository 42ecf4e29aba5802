#pragma once
// What the `anisocap` program's commands share on the command line: number and name checks, and
// the options bound onto capture_options and the networks' choice (program.hpp holds the rest).
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <exception>
#include <initializer_list>
#include <string>
#include <vector>

#include "program.hpp"

namespace anisocap::commands {

/// A number check with a short message (CLI11's own prints its range's bound in 300 digits):
/// finite, and positive (`positive`) or not negative.
inline CLI::Validator finite_number(bool positive) {
  return CLI::Validator(
      [positive](std::string& text) -> std::string {
        double v = 0;
        try {
          std::size_t used = 0;
          v = std::stod(text, &used);
          if (used != text.size()) return "expected a number, got '" + text + "'";
        } catch (const std::exception&) {
          return "expected a number, got '" + text + "'";
        }
        if (!std::isfinite(v)) return "must be a finite number, got " + text;
        if (positive ? !(v > 0) : !(v >= 0)) return std::string(positive ? "must be positive" : "must not be negative") + ", got " + text;
        return {};
      },
      positive ? "POSITIVE" : "NONNEGATIVE");
}

/// Simulated sensor noise on rendered inputs (synthesize, eval).
inline void add_noise_options(CLI::App* c, sensor_noise& noise) {
  c->add_option("--shot-noise", noise.shot, "simulated sensor shot noise on the inputs: relative standard deviation at pixel value 1 (0: exact renders)")->check(finite_number(false));
  c->add_option("--read-noise", noise.read, "simulated sensor read noise on the inputs: standard deviation independent of the pixel value")->check(finite_number(false));
}

/// Binds `--materials` onto `mix`: the procedural families (data/procedural.hpp material_mix)
/// materials are drawn from, by name, among `allowed`.
inline CLI::Option* add_mix_option(CLI::App* c, material_mix& mix, std::initializer_list<material_mix> allowed, const std::string& help) {
  std::string known;
  for (material_mix m : allowed) known += std::string(known.empty() ? "" : "|") + material_mix_name(m);
  const std::vector<material_mix> names(allowed);
  CLI::Validator by_name(
      [names, known](std::string& input) {
        for (material_mix m : names)
          if (input == material_mix_name(m)) {
            input = std::to_string(static_cast<int>(m));
            return std::string();
          }
        return "unknown mix '" + input + "' (" + known + ")";
      },
      "");
  return c->add_option("--materials", mix, help)->transform(by_name)->type_name(known)->default_str(material_mix_name(mix));
}

/// The radii of `--neighbour-restarts`: "none" (no restarts) or comma-separated whole numbers of at
/// least 1. Throws CLI::ValidationError naming the bad entry.
inline std::vector<int> parse_restart_radii(const std::string& list) {
  if (list == "none") return {};
  std::vector<int> radii;
  std::size_t begin = 0;
  while (begin <= list.size()) {
    const std::size_t end = std::min(list.find(',', begin), list.size());
    const std::string entry = list.substr(begin, end - begin);
    int radius = 0;
    std::size_t used = 0;
    try {
      radius = std::stoi(entry, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (entry.empty() || used != entry.size() || radius < 1)
      throw CLI::ValidationError(capture_flag("capture_options::neighbour_restarts"), "'" + entry + "' is not a radius (a whole number of texels, at least 1); give R,... or none");
    radii.push_back(radius);
    begin = end + 1;
  }
  return radii;
}

/// Checks a comma-separated list of family names (material_kinds_from_names), naming the unknown one.
inline CLI::Validator family_list_check() {
  return CLI::Validator(
      [](const std::string& list) {
        try {
          material_kinds_from_names(list);
          return std::string();
        } catch (const std::invalid_argument& e) {
          return std::string(e.what());
        }
      },
      "FAMILY,...");
}

/// A --preset check that takes `choices` and, refusing `paper` where this build has no paper
/// widths, says how to get them (capture's, demo's and the trainers' --preset).
inline CLI::Validator preset_validator(const std::vector<std::string>& choices) {
  return CLI::Validator(
      [choices](const std::string& v) -> std::string {
        if (std::find(choices.begin(), choices.end(), v) != choices.end()) return "";
        if (v == "paper")
          return "paper: this program was built without the paper's widths (configure with -DANISOCAP_EXPERIMENTAL_PRESETS=ON)";
        return v + ": not one of " + join_names(choices, ", ");
      },
      "{" + join_names(choices, ",") + "}");
}

/// --preset, --models, --also-models and --no-also-models, bound onto `m`.
inline void add_model_options(CLI::App* c, model_choice& m) {
  c->add_option("--preset", m.preset,
                std::string("network preset whose weights to use: compact, or paper (the paper's widths; ") +
                    (program_has_paper_preset ? "no weights are shipped for them)" : "in a build with -DANISOCAP_EXPERIMENTAL_PRESETS=ON)"))
      ->check(preset_validator(program_has_paper_preset ? std::vector<std::string>{"compact", "paper"}
                                                        : std::vector<std::string>{"compact"}));
  c->add_option("--models", m.models,
                "folder holding <preset>/estimator.safetensors and autoencoder.safetensors (default: $ANISOCAP_MODELS, else the "
                "installed share/anisocap/models)");
  c->add_option("--also-models", m.also,
                "the second prior's folder (default: MODELS/also): where the first fit's image loss is above --also-models-above, "
                "the network stages run again with its auto-encoder (and its estimator, or the first folder's) and the better "
                "fit is kept")
      ->check(CLI::ExistingDirectory);
  c->add_flag_callback("--no-also-models", [&m] { m.also = fs::path(); }, "no second prior");
}

/// The second runs' options (second_run_options), bound onto `r`.
inline void add_second_run_options(CLI::App* c, second_run_options& r) {
  c->add_option(capture_flag("capture_options::second_run.above"), r.above,
                "run the network stages a second time (--also-residual, the second prior) only where the first run's final image "
                "loss is above this (0: always)")
      ->check(CLI::NonNegativeNumber);
  c->add_flag(std::string(capture_flag("capture_options::second_run.residual")) + ",!--no-also-residual", r.residual,
              "run the network stages a second time with the fine-tune started at the estimate itself (--finetune-residual) and "
              "keep the result that fits the photographs better; before the second prior's run; on by default where the "
              "fine-tune runs, subject to --also-models-above and --also-residual-ratio");
  c->add_option(capture_flag("capture_options::second_run.residual_ratio"), r.residual_ratio,
                "with --also-residual: run the second time only where the auto-encoder's projection of the estimate fits the "
                "photographs at least this many times worse than the estimate (0: wherever --also-models-above allows)")
      ->check(CLI::NonNegativeNumber);
}

/// A number as --help writes it: "0.008", "500".
inline std::string help_number(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", v);
  return text;
}

/// --schedule and --network-precision, bound onto `o`.
inline void add_schedule_options(CLI::App* c, capture_options& o) {
  // The schedules' numbers in the help are read from the options themselves, so that --help
  // cannot disagree with what a schedule runs; the measured costs beside them are docs/results.md's.
  const auto n = help_number;
  const capture_options fast = capture_options::fast(), thorough = capture_options::thorough(), automatic = capture_options::automatic(),
                        paper = capture_options::paper();
  c->add_option_function<std::string>(
       "--schedule",
       [&o](const std::string& name) { o.apply_schedule(name); },
       "fast: fine-tune " + n(fast.finetune.steps) + " steps at " + n(fast.finetune.learning_rate) + " after a " + n(fast.finetune.warmup) +
           "-step warm-up, refine " + n(fast.refine.steps) + " at " + n(fast.refine.learning_rate) +
           " (~30 s for 256 x 256 on 2 cores, the paper's error; docs/results.md \"Run time against error\"); thorough: fine-tune " +
           n(thorough.finetune.steps) + " at " + n(thorough.finetune.learning_rate) + ", refine " + n(thorough.refine.steps) + " at " +
           n(thorough.refine.learning_rate) +
           " (~2.1x longer, the novel-view loss 17% lower on the family comparison, foil 33%); auto: the fast schedule's steps, then on "
           "while the loss still falls (" + n(100 * automatic.finetune.min_improvement) + "% per " + n(automatic.finetune.patience) +
           " fine-tune steps, " + n(100 * automatic.refine.min_relative_improvement) + "% per " + n(automatic.refine.patience) +
           " refine steps) up to the thorough schedule's (the thorough schedule's error in 0.89x its time on the family comparison); "
           "paper: fine-tune " + n(paper.finetune.steps) + " at " + n(paper.finetune.learning_rate) + ", refine " + n(paper.refine.steps) +
           " at " + n(paper.refine.learning_rate) + ", no neighbour restarts (~5x longer). Options given beside it override its values")
      ->check(CLI::IsMember({"fast", "thorough", "auto", "paper"}))
      ->default_str("fast");
  c->add_option_function<std::string>(
       capture_flag("capture_options::network_precision"), [&o](const std::string& name) { o.network_precision = nn::parse_precision(name); },
       "operands of the networks' convolutions in the estimate and fine-tune: fp32, or bf16 (rounded to bfloat16, multiplied "
       "and summed in FP32, FP32 master weights; about 0.7x the fine-tune's time; needs a build for a CPU with AVX-512 BF16, "
       "see --version; docs/program.md)")
      ->check(CLI::IsMember({"fp32", "bf16"}))
      ->default_str("fp32");
}

/// The estimate's and the fine-tune's options, bound onto `o`.
inline void add_network_stage_options(CLI::App* c, capture_options& o) {
  const auto n = help_number;
  const capture_options fast = capture_options::fast(), paper = capture_options::paper();
  c->add_option(capture_flag("estimate_options::window"), o.estimate.window,
                "side of the sliding windows the estimation network sees, texels (the capture is estimated window by window and "
                "blended; docs/model-card.md measures the choice)")
      ->check(CLI::Range(64, 1 << 16));
  c->add_option(capture_flag("estimate_options::stride"), o.estimate.stride, "step between the estimation windows, texels (at most --estimate-window)")
      ->check(CLI::Range(1, 1 << 16));
  c->add_option(capture_flag("finetune_options::steps"), o.finetune.steps, "decoder fine-tune steps (paper: " + n(paper.finetune.steps) + ")")->check(finite_number(false));
  c->add_flag(capture_flag("finetune_options::residual"), o.finetune.residual,
              "start the fine-tune at the estimate itself: fit D(z) + r, with r fixed so that the start equals the estimate, "
              "instead of D(z) (docs/method.md section 8.3)");
  c->add_option(capture_flag("finetune_options::learning_rate"), o.finetune.learning_rate, "decoder fine-tune learning rate after the warm-up (paper: " + n(paper.finetune.learning_rate) + ")")->check(finite_number(true));
  c->add_option(capture_flag("finetune_options::warmup"), o.finetune.warmup, "fine-tune learning-rate warm-up: linear ramp over this many steps (paper: none)")->check(finite_number(false));
  c->add_option(capture_flag("finetune_options::half_life"), o.finetune.half_life, "fine-tune learning rate halves every this many steps (0: constant)")->check(finite_number(false));
  c->add_option(capture_flag("finetune_options::crop.cells"), o.finetune.crop.cells, "fine-tune on random crops of this many latent cells per side (a cell is 32 x 32 texels, 16 x 16 for the compact-fine auto-encoders; 0: the whole tile, as the paper)")->check(finite_number(false));
  c->add_option(capture_flag("finetune_options::shard_cells"), o.finetune.shard_cells, "cut each fine-tune step into blocks of this many latent cells per side, decoded apart and their gradients added in a fixed order, so that any number of MPI ranks gives the same maps (0: one decode per step; under mpirun 16; docs/scaling.md)")->check(finite_number(false));
  c->add_option(capture_flag("finetune_options::min_improvement"), o.finetune.min_improvement, "stop fine-tuning when " + n(fast.finetune.patience) + " steps improve the loss by less than this fraction (0: never)")->check(CLI::Range(0.0, 1.0));
  c->add_option(capture_flag("finetune_options::guard.factor"), o.finetune.guard.factor, "divergence guard: a step whose loss exceeds this factor times the best goes back to the last snapshot at half the rate (0: off); costs a copy of the decoder every " + n(fast.finetune.guard.every) + " steps, keeps large rates from losing what they gained");
}

/// The refine's options (and its restarts, kernel and arithmetic), bound onto `o`.
inline void add_refine_options(CLI::App* c, capture_options& o) {
  const auto n = help_number;
  const capture_options fast = capture_options::fast();
  const refine_options alone = fast.refine_alone;
  c->add_option_function<int>(
       capture_flag("refine_options::steps"), [&o](int n) { o.refine.steps = o.refine_alone.steps = n; },
       "refine steps (default " + n(fast.refine.steps) + " after the network stages, " + n(alone.steps) + " when they do not run)")
      ->check(finite_number(false));
  c->add_option_function<float>(
       capture_flag("refine_options::learning_rate"), [&o](float r) { o.refine.learning_rate = o.refine_alone.learning_rate = r; },
       "refine learning rate, Adam in unconstrained parameters (default " + n(fast.refine.learning_rate) + " after the network stages, " + n(alone.learning_rate) + " when they do not run)")
      ->check(finite_number(true));
  c->add_option_function<double>(
       capture_flag("refine_options::min_relative_improvement"), [&o](double f) { o.refine.min_relative_improvement = o.refine_alone.min_relative_improvement = f; },
       "stop refining when " + n(fast.refine.patience) + " steps improve the loss by less than this fraction (0: never)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option(capture_flag("capture_options::second_start_lobe_width"), o.second_start_lobe_width,
                "refine also from the same maps with both lobe widths at least this, and keep per 64-texel group the fit with the "
                "lower loss (0: one start; docs/method.md section 8.4)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       capture_flag("capture_options::neighbour_restarts"),
       [&o](const std::string& list) { o.neighbour_restarts = o.neighbour_restarts_alone = parse_restart_radii(list); },
       "after the refine, for each radius R in turn (comma-separated texels), refine again from the maps' means over (2R+1)^2 "
       "windows and keep per 64-texel group the fit with the lower loss (none: no restarts; default 8 after the network stages, none "
       "for the refine alone and with --schedule paper; docs/method.md section 8.4)")
      ->type_name("R,...|none");
  c->add_option_function<double>(
       capture_flag("refine_options::freeze_tolerance"), [&o](double f) { o.refine.freeze_tolerance = o.refine_alone.freeze_tolerance = f; },
       "refine only texels whose loss still moves: freeze a 64-texel group when " + n(fast.refine.freeze_every) +
           " steps improve its loss by less than this fraction (0: never)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       capture_flag("kernel_options"), [&o](const std::string& name) { o.kernel = kernel_options::parse(name); },
       "BRDF terms the fine-tune and refine stages fit: auto (the cheapest kernel that renders the estimate, or the first guess, within "
       "1e-3: the full kernel on anisotropic samples with Fresnel and normals, fewer terms and less time where the sample shows "
       "fewer), full, isotropic, no-fresnel, flat, isotropic-flat, lambert-like")
      ->check(CLI::IsMember({"auto", "full", "isotropic", "no-fresnel", "flat", "isotropic-flat", "lambert-like"}))
      ->default_str(o.kernel.auto_tolerance > 0 ? "auto" : "full");
  c->add_option("--cull", o.render.cull_tolerance, "specular culling tolerance on each pixel's log loss term (0: exact)")->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       "--precision", [&o](const std::string& name) { o.render.double_precision = name == "double"; },
       "arithmetic of the image-loss kernels: float or double (maps stay float; double is ~1.9x slower)")
      ->check(CLI::IsMember({"float", "double"}))
      ->default_str(o.render.double_precision ? "double" : "float");
}

/// The fine-tune and refine options of capture, eval and demo, bound onto `o`. `--schedule paper`
/// comes first so that options after it on the command line refine it.
inline void add_optimiser_options(CLI::App* c, capture_options& o) {
  add_schedule_options(c, o);
  add_network_stage_options(c, o);
  add_refine_options(c, o);
  add_second_run_options(c, o.second_run);
}

}  // namespace anisocap::commands
