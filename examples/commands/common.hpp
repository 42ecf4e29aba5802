#pragma once
// What the `anisocap` program's commands share: progress lines, image writing, the optimiser
// options bound onto capture_options, and the network weights of a preset.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <initializer_list>
#include <string>
#include <vector>

#include "anisocap/anisocap.hpp"

#ifndef ANISOCAP_MODELS_DIR
#define ANISOCAP_MODELS_DIR "models"
#endif

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
/// fails, `release_empty` removes it again if it made it and it stayed empty.
class output_lock {
 public:
  explicit output_lock(const fs::path& folder) : folder_(folder) {
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
    if (fd_ >= 0) ::close(fd_);
  }
  /// Removes the folder when this lock created it and nothing was written there.
  void release_empty() {
    std::error_code ec;
    if (created_ && fs::is_empty(folder_, ec)) fs::remove(folder_, ec);
  }

 private:
  fs::path folder_;
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

/// Where the network weights come from.
struct model_choice {
  std::string preset = "compact";          ///< compact or paper
  fs::path models = ANISOCAP_MODELS_DIR;   ///< folder holding <preset>/estimator.safetensors, autoencoder.safetensors
  /// The estimator's file: this folder's, or where the folder has none and `estimator_fallback` is
  /// set (an `--also-models` folder, alternative_choice), that file.
  fs::path estimator() const {
    fs::path own = models / preset / "estimator.safetensors";
    return estimator_fallback.empty() || fs::exists(own) ? own : estimator_fallback;
  }
  /// The estimator an `--also-models` folder without one of its own uses: the first folder's
  /// (empty for the first folder itself). A folder holding only an auto-encoder then runs the
  /// shipped estimator with its own decoder (`--also-models models/also`).
  fs::path estimator_fallback;
  fs::path autoencoder() const { return models / preset / "autoencoder.safetensors"; }
  bool present() const { return fs::exists(estimator()) && fs::exists(autoencoder()); }
  /// A second weights folder (`--also-models`), empty for none: the network stages then run with
  /// each folder's weights and the result that fits the photographs better (the lower final image
  /// loss, capture_result::loss) is kept. A folder without an estimator uses this one's
  /// (estimator_fallback). With models/also (a `compact-fine-512` auto-encoder alone, so run with
  /// this folder's estimator) it took 3.9% and 18.7% off Table 1's two 20-material samples'
  /// novel-view error, trying the second folder on 6 of the 40 (models/README.md "Run 45").
  fs::path alternative;
  /// The second folder runs only when the first run's final image loss is above this
  /// (`--also-models-above`; 0: always). At 0.1 it ran on 4 of the family comparison's 16
  /// materials and 7 of 8 spun tiles and kept the whole choice's gain (models/README.md "Run 16").
  double alternative_above = 0.1;
  /// `--also-residual`: a second run on the same weights starts its fine-tune at the estimate itself
  /// (finetune_options::residual); with `--also-models` the alternative folder's run comes after it
  /// (run_capture).
  /// Kept where it fits better: with run 18's estimator it took the family comparison's novel-view
  /// error from 0.033 to 0.023 (models/README.md "Run 19"). On by default where the encode and
  /// fine-tune stages run (resolve_second_run); `--no-also-residual` turns it off.
  bool alternative_residual = true;
  /// The residual start's second run on the same weights happens only where the first run's
  /// auto-encoder projection of the estimate fits the photographs at least this many times worse
  /// than the estimate itself (projection_ratio; `--also-residual-ratio`, 0: no such condition),
  /// on top of `alternative_above`. The ratio is measured before any fine-tuning and, unlike the
  /// final loss, hardly moves with the photographs' noise (models/README.md "Run 20").
  double residual_ratio = 1.4;
  /// Whether a second run is asked for (`--also-models` or `--also-residual`).
  bool second_run() const { return !alternative.empty() || alternative_residual; }
  /// The weights of the last run run_capture may add: the alternative folder's, or these without
  /// `--also-models` (same preset, no second run of its own).
  model_choice alternative_choice() const {
    model_choice m = *this;
    if (!alternative.empty()) {
      m.models = alternative;
      m.estimator_fallback = estimator();
    }
    m.alternative.clear();
    m.alternative_residual = false;
    return m;
  }
};

inline void add_model_options(CLI::App* c, model_choice& m) {
  c->add_option("--preset", m.preset, "network preset whose weights to use")->check(CLI::IsMember({"compact", "paper"}));
  c->add_option("--models", m.models, "folder holding <preset>/estimator.safetensors and autoencoder.safetensors");
  c->add_option("--also-models", m.alternative,
                "a second such folder: run the network stages with both and keep the result that fits the photographs better "
                "(without an estimator of its own, the first folder's is used; e.g. models/also, a wider auto-encoder alone, "
                "models/README.md \"Run 44\"); the residual start's second run (--also-residual) on the first folder's "
                "weights comes before it and takes part in the choice")
      ->check(CLI::ExistingDirectory);
  c->add_option("--also-models-above", m.alternative_above,
                "with --also-models or --also-residual: run the second time only when the first run's final image loss is above this "
                "(0: always)")
      ->check(CLI::NonNegativeNumber);
  c->add_flag("--also-residual,!--no-also-residual", m.alternative_residual,
              "run the network stages a second time with the fine-tune started at the estimate itself (--finetune-residual) and "
              "keep the result that fits the photographs better (models/README.md \"Run 19\"); with --also-models, before the "
              "other folder's run (models/README.md \"Run 30\"); on by default where the fine-tune runs, subject to "
              "--also-models-above and --also-residual-ratio");
  c->add_option("--also-residual-ratio", m.residual_ratio,
                "with --also-residual on the same weights: run the second time only where the auto-encoder's projection of the "
                "estimate fits the photographs at least this many times worse than the estimate (0: wherever --also-models-above "
                "allows)")
      ->check(CLI::NonNegativeNumber);
}

/// The residual start's second run is on by default (model_choice::alternative_residual) but only
/// where it can differ from the first: unless `parsed` (the command) gave `--also-residual`, it is
/// turned off when `stages` leave out the encode or fine-tune stage.
inline void resolve_second_run(model_choice& m, const pipeline_stages& stages, const CLI::App& parsed) {
  if (parsed.count("--also-residual") > 0) return;
  if (!stages.encode || !stages.finetune) m.alternative_residual = false;
}

/// How many times worse the auto-encoder projection of the estimate (the encode stage) fits the
/// photographs than the estimate itself: large where the projection loses what the estimator
/// found, the case the residual start (finetune_options::residual) is for. NaN when either stage
/// did not run.
inline double projection_ratio(const capture_result& r) { return r.stage_loss("encode") / r.stage_loss("estimate"); }

/// Without the network stages the refine starts from the first guess, far from the answer: it then
/// takes refine_options' own steps and rate, unless `parsed` (the command) gave --steps or --lr.
inline void refine_alone_schedule(capture_options& o, const CLI::App& parsed) {
  if (o.stages.networks()) return;
  if (parsed.count("--steps") == 0) o.refine.steps = refine_options{}.steps;
  if (parsed.count("--lr") == 0) o.refine.learning_rate = refine_options{}.learning_rate;
}

/// The neighbour restarts' default, unless `parsed` (the command) gave --neighbour-restarts: one
/// round at radius 8 after the network stages (studies/README.md "Neighbour restarts"); none with
/// --schedule paper, and none where the refine starts from the first guess, where each round would
/// be another whole refine and nothing was measured.
inline void resolve_neighbour_restarts(capture_options& o, const CLI::App& parsed) {
  if (parsed.count("--neighbour-restarts") > 0) return;
  const bool paper = parsed.count("--schedule") > 0 && parsed.get_option("--schedule")->as<std::string>() == "paper";
  if (o.stages.networks() && o.stages.refine && !paper) o.neighbour_restarts = {8};
  else o.neighbour_restarts.clear();
}

/// The fine-tune and refine options of capture, eval and demo, bound onto `o`. `--schedule paper`
/// comes first so that options after it on the command line refine it.
inline void add_optimiser_options(CLI::App* c, capture_options& o) {
  c->add_option_function<std::string>(
       "--schedule",
       [&o](const std::string& name) {
         if (name == "paper") {
           o.finetune = finetune_options::paper();
           o.refine = refine_options::paper();
         } else if (name == "thorough") {
           const capture_options thorough = capture_options::thorough();
           o.finetune = thorough.finetune;
           o.refine = thorough.refine;
         }
       },
       "fast: fine-tune 800 steps at 8e-3 after a 200-step warm-up, refine 500 at 3e-3 (~30 s for 256 x 256 on 2 cores, the paper's "
       "error; studies/README.md \"Run time against error\"); thorough: fine-tune 2000 at 8e-3, refine 1000 at 3e-3 (~2.2x longer, "
       "every parameter's error and the novel-view loss lower, by 20% on the family comparison, metals most: studies/README.md \"Longer fine-tunes, longer refines and a second start\"); paper: fine-tune 5000 at 7.5e-4, refine 500 at 1e-4 "
       "(~5x longer). Options given beside it override its values")
      ->check(CLI::IsMember({"fast", "thorough", "paper"}))
      ->default_str("fast");
  c->add_option("--estimate-window", o.estimate.window,
                "side of the sliding windows the estimation network sees, texels (the capture is estimated window by window and "
                "blended; models/README.md \"Run 18\" measures the choice)")
      ->check(CLI::Range(64, 1 << 16));
  c->add_option("--estimate-stride", o.estimate.stride, "step between the estimation windows, texels (at most --estimate-window)")
      ->check(CLI::Range(1, 1 << 16));
  c->add_option("--finetune-steps", o.finetune.steps, "decoder fine-tune steps (paper: 5000)")->check(finite_number(false));
  c->add_flag("--finetune-residual", o.finetune.residual,
              "start the fine-tune at the estimate itself: fit D(z) + r, with r fixed so that the start equals the estimate, "
              "instead of D(z) (docs/method.md section 8.3; models/README.md \"Run 19\")");
  c->add_option("--finetune-lr", o.finetune.learning_rate, "decoder fine-tune learning rate after the warm-up (paper: 7.5e-4)")->check(finite_number(true));
  c->add_option("--finetune-warmup", o.finetune.warmup, "fine-tune learning-rate warm-up: linear ramp over this many steps (paper: none)")->check(finite_number(false));
  c->add_option("--finetune-half-life", o.finetune.half_life, "fine-tune learning rate halves every this many steps (0: constant)")->check(finite_number(false));
  c->add_option("--finetune-crop", o.finetune.crop.cells, "fine-tune on random crops of this many latent cells per side (a cell is 32 x 32 texels, 16 x 16 for the compact-fine auto-encoders; 0: the whole tile, as the paper)")->check(finite_number(false));
  c->add_option("--finetune-stop", o.finetune.min_improvement, "stop fine-tuning when 200 steps improve the loss by less than this fraction (0: never)")->check(CLI::Range(0.0, 1.0));
  c->add_option("--finetune-guard", o.finetune.guard.factor, "divergence guard: a step whose loss exceeds this factor times the best goes back to the last snapshot at half the rate (0: off); costs a copy of the decoder every 50 steps, keeps large rates from losing what they gained");
  c->add_option("--steps", o.refine.steps, "refine steps (1000 when the networks do not run)")->check(finite_number(false));
  c->add_option("--lr", o.refine.learning_rate, "refine learning rate, Adam in unconstrained parameters (0.03 when the networks do not run)")->check(finite_number(true));
  c->add_option("--refine-stop", o.refine.min_relative_improvement, "stop refining when 50 steps improve the loss by less than this fraction (0: never)")->check(CLI::Range(0.0, 1.0));
  c->add_option("--second-start", o.second_start_lobe_width,
                "refine also from the same maps with both lobe widths at least this, and keep per 64-texel group the fit with the "
                "lower loss (0: one start; docs/method.md section 8.4)")
      ->check(CLI::Range(0.0, 1.0));
  c->add_option_function<std::string>(
       "--neighbour-restarts", [&o](const std::string& list) { o.neighbour_restarts = parse_restart_radii(list); },
       "after the refine, for each radius R in turn (comma-separated texels), refine again from the maps' means over (2R+1)^2 "
       "windows and keep per 64-texel group the fit with the lower loss (none: no restarts; default 8 after the network stages, none "
       "for the refine alone and with --schedule paper; docs/method.md section 8.4)")
      ->type_name("R,...|none");
  c->add_option("--freeze", o.refine.freeze_tolerance, "refine only texels whose loss still moves: freeze a 64-texel group when 25 steps improve its loss by less than this fraction (0: never)")->check(CLI::Range(0.0, 1.0));
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
}

/// Runs capture_material with the networks of `models` (loaded here) when `o.stages` needs them,
/// else without networks; `masks` as capture_material's. `models.alternative` is not looked at.
inline capture_result run_capture_once(const capture& cap, const std::vector<image>& photos, const model_choice& models,
                                  const capture_options& o, const material_maps* start = nullptr, const std::vector<image>& masks = {}) {
  if (!o.stages.networks()) return capture_material(cap, photos, o, start, masks);
  if (!models.present())
    throw std::invalid_argument("the network stages need the " + models.preset + " weights: " + models.estimator().string() + " and " +
                                models.autoencoder().string() + " (not found)");
  auto run = [&]<class EstimatorPreset, class AutoEncoderPreset>() {
    estimation_network<EstimatorPreset> estimator;
    auto_encoder<AutoEncoderPreset> autoencoder;
    nn::load_weights(models.estimator(), estimator);
    nn::load_weights(models.autoencoder(), autoencoder);
    return capture_material(cap, photos, estimator, autoencoder, o, start, masks);
  };
  if (models.preset == "paper") return run.template operator()<estimator_paper, autoencoder_paper>();
  return with_compact_estimator_preset(models.estimator(), [&]<class P>() {
    return with_compact_autoencoder_preset(models.autoencoder(), [&]<class A>() { return run.template operator()<P, A>(); });
  });
}

/// What run_capture chose between when it ran with two weights folders.
struct model_selection {
  fs::path chosen, other;          ///< the weights folders of the kept and the other result
  double loss = 0, other_loss = 0; ///< their final image losses against the photographs
  double other_seconds = 0;        ///< the time the other run's stages took
  bool other_ran = true;           ///< false: a condition below was not met, the other did not run
  bool chosen_residual = false, other_residual = false;  ///< whether each run's fine-tune had the residual start
  double projection_ratio = 0;     ///< the first run's projection_ratio (NaN when its network stages did not both run)
};

/// run_capture_once with `models`, and where a second start or a second prior is asked for
/// (`models.second_run()`), the better fit of up to three whole runs:
/// - the residual start on the same weights (`models.alternative_residual`), where the first run's
///   final image loss is above `models.alternative_above`, the first run did not have that start
///   already, and its projection_ratio is at least `models.residual_ratio` (a ratio that cannot be
///   measured, without the estimate stage, does not hold it back); check-points in
///   o.checkpoint.folder/alternative;
/// - then the alternative folder's weights (`models.alternative`, with `o`'s start: the standard
///   one unless o.finetune.residual), where the better of the runs so far ends above
///   `models.alternative_above`; check-points in
///   o.checkpoint.folder/also_models.
/// Returns the result with the lowest final image loss (the earlier on a tie) and says in
/// `selection` (when given) which it kept against the last choice's other run and whether that
/// ran. A second run without the network stages in `o.stages` is refused (std::invalid_argument).
inline capture_result run_capture(const capture& cap, const std::vector<image>& photos, const model_choice& models,
                                  const capture_options& o, const material_maps* start = nullptr, const std::vector<image>& masks = {},
                                  model_selection* selection = nullptr) {
  if (!models.second_run()) return run_capture_once(cap, photos, models, o, start, masks);
  const bool same_weights = models.alternative.empty();
  const char* option = same_weights ? "--also-residual" : "--also-models";
  if (!o.stages.networks())
    throw std::invalid_argument(std::string(option) + " chooses between the network stages' results, and these stages do not run "
                                "(--stages without estimate, encode and fine-tune, --init, or no weights in --models)");
  const model_choice other = models.alternative_choice();
  if (!other.present())
    throw std::invalid_argument("--also-models: no " + other.preset + " weights in " + (other.models / other.preset).string() +
                                " (autoencoder.safetensors, and estimator.safetensors unless the first folder's is to be used)");
  auto name = [](const model_choice& m, bool residual) {
    return "the weights in " + m.models.string() + (residual ? " with the residual start" : "");
  };
  // The first run: these weights alone or, with a second prior, these weights with their own
  // choice of the residual start (the same-weights case below).
  model_selection first_selection;
  bool first_residual = o.finetune.residual, first_chose = false;
  capture_result first = [&] {
    if (same_weights) return run_capture_once(cap, photos, models, o, start, masks);
    model_choice own = models;
    own.alternative.clear();
    if (!own.second_run()) return run_capture_once(cap, photos, own, o, start, masks);
    capture_result r = run_capture(cap, photos, own, o, start, masks, &first_selection);
    first_residual = first_selection.chosen_residual;
    first_chose = first_selection.other_ran;
    return r;
  }();
  const double ratio = !same_weights && models.alternative_residual ? first_selection.projection_ratio : projection_ratio(first);
  capture_options o2 = o;
  if (same_weights) o2.finetune.residual = true;
  const bool second_residual = o2.finetune.residual;
  const std::string first_name =
      first_chose ? "the better of two starts with the weights in " + models.models.string() : name(models, first_residual);
  const std::string second_name = name(other, second_residual);
  auto not_tried = [&](const std::string& why) {
    std::fprintf(stderr, "capture: %s fit the photographs to %.4f; %s: %s not tried\n", first_name.c_str(), first.loss, why.c_str(),
                 second_name.c_str());
    if (selection)
      *selection = model_selection{models.models, other.models, first.loss, 0, 0, false, first_residual, second_residual, ratio};
    return std::move(first);
  };
  char why[200];
  if (!(first.loss > models.alternative_above)) {
    std::snprintf(why, sizeof why, "at most %g", models.alternative_above);
    return not_tried(why);
  }
  if (same_weights && first_residual) return not_tried("it had the residual start already");
  if (same_weights && models.residual_ratio > 0 && ratio < models.residual_ratio) {
    std::snprintf(why, sizeof why, "the auto-encoder's projection fits %.2fx worse than the estimate, under %g", ratio,
                  models.residual_ratio);
    return not_tried(why);
  }
  std::fprintf(stderr, "capture: %s fit the photographs to %.4f; now %s\n", first_name.c_str(), first.loss, second_name.c_str());
  if (!o2.checkpoint.folder.empty()) o2.checkpoint.folder /= same_weights ? "alternative" : "also_models";
  capture_result second = run_capture_once(cap, photos, other, o2, start, masks);
  const bool take_second = !first.stopped && !second.stopped && second.loss < first.loss;
  if (selection)
    *selection = take_second ? model_selection{other.models, models.models, second.loss, first.loss, first.stage_seconds(), true,
                                               second_residual, first_residual, ratio}
                             : model_selection{models.models, other.models, first.loss, second.loss, second.stage_seconds(), true,
                                               first_residual, second_residual, ratio};
  std::fprintf(stderr, "capture: kept %s (image loss %.4f against %.4f)\n", (take_second ? second_name : first_name).c_str(),
               take_second ? second.loss : first.loss, take_second ? first.loss : second.loss);
  return take_second ? std::move(second) : std::move(first);
}

}  // namespace anisocap::commands
