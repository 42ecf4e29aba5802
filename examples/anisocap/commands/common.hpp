#pragma once
// What the `anisocap` program's commands share: progress lines, image writing, the optimiser
// options bound onto capture_options, and the network weights of a preset.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <initializer_list>
#include <optional>
#include <string>
#include <vector>

// The library below calibration/, export/ and training/: each command includes those it uses.
#include "anisocap/core/image.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/core/memory.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/srgb.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/core/tensor.hpp"
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/conv.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/layers.hpp"
#include "anisocap/nn/linear.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/nn/normalization.hpp"
#include "anisocap/nn/parameter.hpp"
#include "anisocap/nn/pooling.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/nn/precision.hpp"
#include "anisocap/nn/schedule.hpp"
#include "anisocap/nn/upsample.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/render/analysis.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/contact_sheet.hpp"
#include "anisocap/data/data.hpp"
#include "anisocap/data/family_errors.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/network_layers.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/networks/presets.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/pipeline/encode.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/finetune.hpp"
#include "anisocap/pipeline/fingerprint.hpp"
#include "anisocap/pipeline/networks.hpp"
#include "anisocap/pipeline/progress_line.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/pipeline/texel_kernels.hpp"
#include "field_flags.hpp"

// The per-texel kernels are compiled once, in networks.cpp, not in every unit of the program.
ANISOCAP_TEXEL_KERNELS(extern)

namespace anisocap::commands {

namespace fs = std::filesystem;

/// Prints optimisation progress on one refreshed line on a terminal, or one line per report in logs.
inline void print_progress(const std::string& stage, const optimisation_progress& p) {
  static const bool tty = isatty(fileno(stderr));
  std::fprintf(stderr, "%s  %s step %5d/%d  loss %.5f  %6.1f steps/s  %5.1f s left%s", tty ? "\r" : "", stage.c_str(), p.step,
               p.steps, p.loss, p.steps_per_second, p.seconds_left, tty ? "   " : "\n");
  if (tty && p.step == p.steps) std::fputc('\n', stderr);
  std::fflush(stderr);
}

/// The per-parameter errors as JSON (alpha over anisotropic texels is null when there are none).
inline nlohmann::json errors_to_json(const parameter_errors& e) {
  return {{"diffuse", e.diffuse}, {"specular", e.specular}, {"normal", e.normal}, {"lobes", e.lobes},
          {"rotation", e.rotation},
          {"rotation_anisotropic", std::isnan(e.rotation_anisotropic) ? nlohmann::json(nullptr) : nlohmann::json(e.rotation_anisotropic)},
          {"fresnel", e.fresnel}};
}

/// An exclusive lock on an output folder for the life of a command (flock on the folder itself, so
/// nothing is left behind and the kernel drops it when the process dies): a second run into the
/// same folder fails at once instead of both writing there. Creates the folder; when the command
/// fails (the lock is destroyed by an exception), removes it again if it made it and it stayed empty.
class output_lock {
 public:
  explicit output_lock(const fs::path& folder) : folder_(folder), exceptions_(std::uncaught_exceptions()) {
    created_ = !fs::exists(folder);
    fs::create_directories(folder);
    fd_ = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd_ < 0) throw std::runtime_error(folder.string() + ": cannot open the output folder");
    if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd_);
      fd_ = -1;
      throw std::runtime_error(folder.string() + ": another anisocap run is writing into this folder; wait for it or choose another -o");
    }
  }
  output_lock(const output_lock&) = delete;
  output_lock& operator=(const output_lock&) = delete;
  ~output_lock() {
    if (std::uncaught_exceptions() > exceptions_) release_empty();
    if (fd_ >= 0) ::close(fd_);
  }

 private:
  /// Removes the folder when this lock created it and nothing was written there.
  void release_empty() {
    std::error_code ec;
    if (created_ && fs::is_empty(folder_, ec)) fs::remove(folder_, ec);
  }

  fs::path folder_;
  int exceptions_ = 0;  ///< std::uncaught_exceptions() when the lock was taken
  bool created_ = false;
  int fd_ = -1;
};

/// `out / name` for a file name read from a capture description. Throws std::invalid_argument when
/// the name is absolute or climbs out of `out` (a ".." that leaves it): outputs stay inside the
/// output folder whatever a capture description says.
inline fs::path output_inside(const fs::path& out, const std::string& name) {
  const fs::path n = fs::path(name).lexically_normal();
  if (n.empty() || n.has_root_name() || n.has_root_directory() || *n.begin() == ".." || n == ".")
    throw std::invalid_argument("image file name '" + name + "' would be written outside the output folder " + out.string() +
                                ": a capture's file names must be relative and stay inside its folder");
  return out / n;
}

/// Throws std::invalid_argument when one of `outputs` is one of `inputs` (the same file, however
/// named): a command never overwrites what it reads. `advice` ends the message: what to choose instead.
inline void refuse_overwriting_inputs(const std::vector<fs::path>& outputs, const std::vector<fs::path>& inputs,
                                      const std::string& advice = "choose another output folder (-o)") {
  std::vector<fs::path> existing;
  for (const auto& in : inputs)
    if (fs::exists(in)) existing.push_back(fs::weakly_canonical(in));
  for (const auto& out : outputs) {
    const fs::path o = fs::weakly_canonical(out);
    for (const auto& in : existing)
      if (o == in)
        throw std::invalid_argument(out.string() + ": this output would overwrite one of the command's inputs; " + advice);
  }
}

/// The files write_images writes for `cap` into `out` (each EXR with its PNG preview).
inline std::vector<fs::path> image_outputs(const capture& cap, const fs::path& out) {
  std::vector<fs::path> files;
  for (const auto& i : cap.images) {
    const fs::path target = output_inside(out, i.file);
    files.push_back(target);
    const auto ext = target.extension().string();
    if (ext == ".exr" || ext == ".EXR") files.push_back(fs::path(target).replace_extension(".png"));
  }
  return files;
}

/// The files a capture description names, resolved against its folder, and the description itself.
inline std::vector<fs::path> capture_inputs(const capture& cap, const fs::path& capture_file) {
  std::vector<fs::path> files{capture_file};
  for (const auto& i : cap.images) {
    files.push_back(capture_file.parent_path() / i.file);
    if (!i.mask.empty()) files.push_back(capture_file.parent_path() / i.mask);
  }
  return files;
}

/// The files of a map set folder (read_maps reads them; write_maps writes them with previews).
inline std::vector<fs::path> map_files(const fs::path& folder) {
  std::vector<fs::path> files;
  for (const auto name : map_file_names) {
    files.push_back(folder / name);
    files.push_back(fs::path(folder / name).replace_extension(".png"));
  }
  return files;
}

/// Creates `folder` (and its parents); io_error naming it when that fails (a file in the way).
inline void create_output_folder(const fs::path& folder) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (!fs::is_directory(folder))
    throw io_error(folder, "cannot create the output folder" + (ec ? ": " + ec.message() : std::string()));
}

/// Stages `images` (one per capture image) for `out` into `files`: one linear EXR per image under
/// its capture file name (a .png name gets an 8-bit sRGB PNG instead), plus a PNG preview beside
/// every EXR. Names stay inside `out` (output_inside) and none may be one of `inputs`.
inline void stage_images(const std::vector<image>& images, const capture& cap, const fs::path& out, file_transaction& files,
                         const std::vector<fs::path>& inputs = {}) {
  refuse_overwriting_inputs(image_outputs(cap, out), inputs);
  create_output_folder(out);
  for (std::size_t i = 0; i < images.size(); ++i) {
    const fs::path target = output_inside(out, cap.images[i].file);
    if (target.has_parent_path()) create_output_folder(target.parent_path());
    const auto ext = target.extension().string();
    if (ext == ".exr" || ext == ".EXR") {
      write_exr(images[i], target, files);
      write_png(images[i], fs::path(target).replace_extension(".png"), files);
    } else {
      write_png(images[i], target, files);
    }
  }
}

/// Writes `images` into `out` as stage_images lays them out; all files appear together or not at all.
inline void write_images(const std::vector<image>& images, const capture& cap, const fs::path& out, const std::vector<fs::path>& inputs = {}) {
  file_transaction files;
  stage_images(images, cap, out, files, inputs);
  files.commit();
}

/// Renders `maps` under `cap` into `out` (write_images).
inline void write_renders(const material_maps& maps, const capture& cap, const fs::path& out, const brdf_features& features = all_features,
                          const std::vector<fs::path>& inputs = {}) {
  write_images(with_features(features, [&]<brdf_features F>() { return render<F>(maps, cap); }), cap, out, inputs);
}

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
      throw CLI::ValidationError("--neighbour-restarts", "'" + entry + "' is not a radius (a whole number of texels, at least 1); give R,... or none");
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

/// Where the program's network weights come from: --preset, --models and the second prior's
/// --also-models / --no-also-models, mapped onto load_networks (pipeline/networks.hpp).
struct model_choice {
  std::string preset = "compact";  ///< compact or paper
  fs::path models;                 ///< --models; empty: the library's search (ANISOCAP_MODELS, the install, beside the program)
  std::optional<fs::path> also;    ///< --also-models (a folder) or --no-also-models (an empty path); unset: MODELS/also
  /// The load_networks options of these choices.
  network_options options() const { return {preset, also}; }
};

/// Loads the networks of `m` (commands/networks.cpp: the preset dispatch is compiled there once).
/// Throws std::invalid_argument naming the option and the files when weights are missing.
networks load_program_networks(const model_choice& m);

#ifdef ANISOCAP_EXPERIMENTAL_PRESETS
/// The estimator presets the program's capture and trainers take: all compact ones (built with
/// -DANISOCAP_EXPERIMENTAL_PRESETS=ON).
using program_estimator_presets = compact_estimator_presets;
/// The auto-encoder presets the program's capture and trainers take: all compact ones.
using program_autoencoder_presets = compact_autoencoder_presets;
/// Whether the program captures with and trains the paper's widths (`--preset paper`).
inline constexpr bool program_has_paper_preset = true;
#else
/// The estimator presets the program's capture and trainers take: the shipped ones (the
/// experimental ones with -DANISOCAP_EXPERIMENTAL_PRESETS=ON, at the cost of a longer build).
using program_estimator_presets = trainable_estimator_presets;
/// The auto-encoder presets the program's capture and trainers take: the shipped ones.
using program_autoencoder_presets = shipped_autoencoder_presets;
/// Whether the program captures with and trains the paper's widths (`--preset paper`). No weights
/// ship for them and they do not train in useful time on a few cores, while their pipeline and
/// trainers are a third of the program's compile time: like the experimental compact presets,
/// they come with -DANISOCAP_EXPERIMENTAL_PRESETS=ON.
inline constexpr bool program_has_paper_preset = false;
#endif

/// A --preset check that takes `choices` and, refusing `paper` where this build has no paper
/// widths, says how to get them (capture's, demo's and the trainers' --preset).
inline CLI::Validator preset_validator(const std::vector<std::string>& choices) {
  return CLI::Validator(
      [choices](const std::string& v) -> std::string {
        if (std::find(choices.begin(), choices.end(), v) != choices.end()) return "";
        if (v == "paper")
          return "paper: this program was built without the paper's widths (configure with -DANISOCAP_EXPERIMENTAL_PRESETS=ON)";
        return v + ": not one of " + CLI::detail::join(choices, ", ");
      },
      "{" + CLI::detail::join(choices, ",") + "}");
}

/// load_program_networks where weights are found; empty networks, with a note on stderr, where
/// none are (no --models given and none installed): the capture then runs the refine alone.
networks find_program_networks(const model_choice& m);

/// The shipped compact weight file `name` where the library finds the weights (find_models_folder),
/// else models/compact/`name` (a default for options that name one file).
inline fs::path shipped_weights_file(const char* name) {
  const fs::path folder = find_models_folder("compact");
  return (folder.empty() ? fs::path("models") : folder) / "compact" / name;
}

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
  c->add_option("--also-models-above", r.above,
                "run the network stages a second time (--also-residual, the second prior) only where the first run's final image "
                "loss is above this (0: always)")
      ->check(CLI::NonNegativeNumber);
  c->add_flag("--also-residual,!--no-also-residual", r.residual,
              "run the network stages a second time with the fine-tune started at the estimate itself (--finetune-residual) and "
              "keep the result that fits the photographs better; before the second prior's run; on by default where the "
              "fine-tune runs, subject to --also-models-above and --also-residual-ratio");
  c->add_option("--also-residual-ratio", r.residual_ratio,
                "with --also-residual: run the second time only where the auto-encoder's projection of the estimate fits the "
                "photographs at least this many times worse than the estimate (0: wherever --also-models-above allows)")
      ->check(CLI::NonNegativeNumber);
}

/// Prints capture_material's choices (capture_options::log) as "capture: ..." lines.
inline void print_capture_choice(const std::string& message) { std::fprintf(stderr, "capture: %s\n", message.c_str()); }

/// A number as --help writes it: "0.008", "500".
inline std::string help_number(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", v);
  return text;
}

/// The fine-tune and refine options of capture, eval and demo, bound onto `o`. `--schedule paper`
/// comes first so that options after it on the command line refine it.
inline void add_optimiser_options(CLI::App* c, capture_options& o) {
  // The schedules' numbers in the help are read from the options themselves, so that --help
  // cannot disagree with what a schedule runs; the measured costs beside them are docs/results.md's.
  const auto n = help_number;
  const capture_options fast = capture_options::fast(), thorough = capture_options::thorough(), automatic = capture_options::automatic(),
                        paper = capture_options::paper();
  const refine_options alone = fast.refine_alone;
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
       "--network-precision", [&o](const std::string& name) { o.network_precision = nn::parse_precision(name); },
       "operands of the networks' convolutions in the estimate and fine-tune: fp32, or bf16 (rounded to bfloat16, multiplied "
       "and summed in FP32, FP32 master weights; about 0.7x the fine-tune's time; needs a build for a CPU with AVX-512 BF16, "
       "see --version; docs/program.md)")
      ->check(CLI::IsMember({"fp32", "bf16"}))
      ->default_str("fp32");
  c->add_option("--estimate-window", o.estimate.window,
                "side of the sliding windows the estimation network sees, texels (the capture is estimated window by window and "
                "blended; docs/model-card.md measures the choice)")
      ->check(CLI::Range(64, 1 << 16));
  c->add_option("--estimate-stride", o.estimate.stride, "step between the estimation windows, texels (at most --estimate-window)")
      ->check(CLI::Range(1, 1 << 16));
  c->add_option("--finetune-steps", o.finetune.steps, "decoder fine-tune steps (paper: " + n(paper.finetune.steps) + ")")->check(finite_number(false));
  c->add_flag("--finetune-residual", o.finetune.residual,
              "start the fine-tune at the estimate itself: fit D(z) + r, with r fixed so that the start equals the estimate, "
              "instead of D(z) (docs/method.md section 8.3)");
  c->add_option("--finetune-lr", o.finetune.learning_rate, "decoder fine-tune learning rate after the warm-up (paper: " + n(paper.finetune.learning_rate) + ")")->check(finite_number(true));
  c->add_option("--finetune-warmup", o.finetune.warmup, "fine-tune learning-rate warm-up: linear ramp over this many steps (paper: none)")->check(finite_number(false));
  c->add_option("--finetune-half-life", o.finetune.half_life, "fine-tune learning rate halves every this many steps (0: constant)")->check(finite_number(false));
  c->add_option("--finetune-crop", o.finetune.crop.cells, "fine-tune on random crops of this many latent cells per side (a cell is 32 x 32 texels, 16 x 16 for the compact-fine auto-encoders; 0: the whole tile, as the paper)")->check(finite_number(false));
  c->add_option("--finetune-shards", o.finetune.shard_cells, "cut each fine-tune step into blocks of this many latent cells per side, decoded apart and their gradients added in a fixed order, so that any number of MPI ranks gives the same maps (0: one decode per step; under mpirun 16; docs/scaling.md)")->check(finite_number(false));
  c->add_option("--finetune-stop", o.finetune.min_improvement, "stop fine-tuning when " + n(fast.finetune.patience) + " steps improve the loss by less than this fraction (0: never)")->check(CLI::Range(0.0, 1.0));
  c->add_option("--finetune-guard", o.finetune.guard.factor, "divergence guard: a step whose loss exceeds this factor times the best goes back to the last snapshot at half the rate (0: off); costs a copy of the decoder every " + n(fast.finetune.guard.every) + " steps, keeps large rates from losing what they gained");
  c->add_option_function<int>(
       "--steps", [&o](int n) { o.refine.steps = o.refine_alone.steps = n; },
       "refine steps (default " + n(fast.refine.steps) + " after the network stages, " + n(alone.steps) + " when they do not run)")
      ->check(finite_number(false));
  c->add_option_function<float>(
       "--lr", [&o](float r) { o.refine.learning_rate = o.refine_alone.learning_rate = r; },
       "refine learning rate, Adam in unconstrained parameters (default " + n(fast.refine.learning_rate) + " after the network stages, " + n(alone.learning_rate) + " when they do not run)")
      ->check(finite_number(true));
  c->add_option_function<double>(
       "--refine-stop", [&o](double f) { o.refine.min_relative_improvement = o.refine_alone.min_relative_improvement = f; },
       "stop refining when " + n(fast.refine.patience) + " steps improve the loss by less than this fraction (0: never)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option("--second-start", o.second_start_lobe_width,
                "refine also from the same maps with both lobe widths at least this, and keep per 64-texel group the fit with the "
                "lower loss (0: one start; docs/method.md section 8.4)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       "--neighbour-restarts",
       [&o](const std::string& list) { o.neighbour_restarts = o.neighbour_restarts_alone = parse_restart_radii(list); },
       "after the refine, for each radius R in turn (comma-separated texels), refine again from the maps' means over (2R+1)^2 "
       "windows and keep per 64-texel group the fit with the lower loss (none: no restarts; default 8 after the network stages, none "
       "for the refine alone and with --schedule paper; docs/method.md section 8.4)")
      ->type_name("R,...|none");
  c->add_option_function<double>(
       "--freeze", [&o](double f) { o.refine.freeze_tolerance = o.refine_alone.freeze_tolerance = f; },
       "refine only texels whose loss still moves: freeze a 64-texel group when " + n(fast.refine.freeze_every) +
           " steps improve its loss by less than this fraction (0: never)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       "--kernel", [&o](const std::string& name) { o.kernel = kernel_options::parse(name); },
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
  add_second_run_options(c, o.second_run);
}

}  // namespace anisocap::commands
