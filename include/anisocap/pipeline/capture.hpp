#pragma once
/// @file
/// The capture pipeline (docs/method.md section 8, the paper's Figure 3) at any resolution:
///
///   photographs --estimate--> maps --encode--> z --finetune (decoder)--> maps --refine--> maps
///
/// Every stage can be skipped; without networks the first guess from the photographs stands in
/// for the estimate and refine runs alone. Stages check-point into a folder so that a killed run
/// resumes.
#include <chrono>
#include <fstream>
#include <sstream>
#include <filesystem>
#include <functional>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "anisocap/core/text.hpp"
#include "anisocap/pipeline/encode.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/finetune.hpp"
#include "anisocap/pipeline/fingerprint.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/pipeline/uncertainty.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/nn/precision.hpp"
#include "anisocap/render/analysis.hpp"

namespace anisocap {

/// Which stages run.
struct pipeline_stages {
  bool estimate = true;  ///< estimation network over sliding windows (else: first guess from the photographs)
  bool encode = true;    ///< encode + fine-tune the decoder need the estimate (or the first guess)
  bool finetune = true;  ///< fine-tune the decoder's weights on the photographs
  bool refine = true;    ///< per-texel refinement

  /// Whether a network runs.
  bool networks() const noexcept { return estimate || encode; }

  /// Parses "estimate,encode,finetune,refine" (any subset, comma separated; "all").
  static pipeline_stages parse(const std::string& text) {
    pipeline_stages s{false, false, false, false};
    std::size_t start = 0;
    while (start <= text.size()) {
      const std::size_t end = std::min(text.find(',', start), text.size());
      const std::string name = text.substr(start, end - start);
      if (name == "estimate") s.estimate = true;
      else if (name == "encode") s.encode = true;
      else if (name == "finetune" || name == "fine-tune") s.finetune = true;
      else if (name == "refine") s.refine = true;
      else if (name == "all") s = pipeline_stages{};
      else throw std::invalid_argument("pipeline_stages: unknown stage '" + name + "' (estimate, encode, finetune, refine, all)");
      start = end + 1;
    }
    if (s.finetune && !s.encode) throw std::invalid_argument("pipeline_stages: finetune needs encode");
    return s;
  }
};

/// Which BRDF terms the fine-tune and refine losses evaluate.
struct kernel_options {
  brdf_features features = all_features;  ///< the kernel when no automatic choice is made
  /// When > 0: after the estimate, the cheapest kernel that renders the estimate (or the first
  /// guess) within this relative tolerance (render/analysis.hpp analyse_kernel) replaces
  /// `features`. It picks the full kernel for anisotropic materials with Fresnel and normals, so
  /// it costs no accuracy there, and skips the terms a sample does not show.
  double auto_tolerance = 1e-3;
  /// F0 written where the kernel leaves Fresnel out and no network gave an estimate (no networks
  /// and no start maps): the photographs do not determine F0 there (every one sees F / F0 within
  /// the tolerance of 1), so the maps carry a prior, not the kernel's placeholder F0 = 1. 0.04 is
  /// the reflectance at normal incidence of a dielectric of refractive index 1.5 (fabrics,
  /// plastics, coatings). With networks the estimate's F0 is kept instead.
  float prior_f0 = 0.04f;

  /// Calls `f(name, field)` for each field (`o` a kernel_options, const or not): the one list that
  /// the check-point fingerprint (capture_fingerprint) and the program's report.json read.
  template <class Self, class F>
  static void visit_fields(Self& o, F&& f) {
    f("features", o.features);
    f("auto_tolerance", o.auto_tolerance);
    f("prior_f0", o.prior_f0);
  }
  /// Throws std::invalid_argument for impossible values.
  void validate() const {
    if (!(auto_tolerance >= 0) || !std::isfinite(auto_tolerance))
      throw std::invalid_argument("capture_options::kernel.auto_tolerance must be a finite number >= 0 (0: no automatic choice)");
    if (!(prior_f0 >= 0 && prior_f0 <= 1)) throw std::invalid_argument("capture_options::kernel.prior_f0 must be in [0, 1]");
  }

  /// The kernel of a name: full, auto, isotropic, no-fresnel, flat, isotropic-flat, lambert-like.
  static kernel_options parse(const std::string& name) {
    if (name == "auto") return {all_features, 1e-3};
    if (name == "full") return {all_features, 0};
    if (name == "isotropic") return {{false, true, true}, 0};
    if (name == "no-fresnel") return {{true, false, true}, 0};
    if (name == "flat") return {{true, true, false}, 0};
    if (name == "isotropic-flat") return {{false, true, false}, 0};
    if (name == "lambert-like") return {{false, false, false}, 0};
    throw std::invalid_argument("kernel_options: unknown kernel '" + name + "' (full, auto, isotropic, no-fresnel, flat, isotropic-flat, lambert-like)");
  }
};

/// When capture_material runs the network stages a second time and keeps the better fit against
/// the photographs (lower final image loss; the first on a tie). Each applies only where the first
/// run's final image loss is above `above`.
struct second_run_options {
  /// Again on the same networks with the fine-tune started at the estimate itself
  /// (finetune_options::residual), where the first run did not have that start, the stages include
  /// encode and fine-tune, and the auto-encoder's projection of the estimate fits the photographs
  /// at least `residual_ratio` times worse than the estimate (projection_ratio). On the 16-material
  /// family comparison it took the novel-view error from 0.033 to 0.023 (docs/results.md).
  bool residual = true;
  /// Then with the networks' second prior (networks::has_second_prior), where the better fit so far
  /// is still above `above`. On Table 1's two 20-material samples it lowers the refined novel-view
  /// error by 4% and 19% for about a third more time (docs/results.md).
  bool second_prior = true;
  /// Final image loss at or below which no second run is made (0: always).
  double above = 0.1;
  /// The residual start's condition on projection_ratio (0: none). The ratio is measured before
  /// any fine-tuning and, unlike the final loss, hardly moves with the photographs' noise.
  double residual_ratio = 1.4;
  /// Calls `f(name, field)` for each field (`o` a second_run_options, const or not): the one list
  /// that validate() and the program's report.json read.
  template <class Self, class F>
  static void visit_fields(Self& o, F&& f) {
    f("residual", o.residual), f("second_prior", o.second_prior);
    f("above", o.above), f("residual_ratio", o.residual_ratio);
  }
  /// Throws std::invalid_argument for impossible values: every number must be finite and >= 0.
  void validate() const {
    visit_fields(*this, [](const char* name, const auto& value) {
      if constexpr (std::is_same_v<std::decay_t<decltype(value)>, double>)
        if (!(value >= 0) || !std::isfinite(value))
          throw std::invalid_argument(std::string("capture_options::second_run.") + name + " must be a finite number >= 0");
    });
  }
};

/// Options of a capture, one struct per stage. `capture_options{}` is the `anisocap capture`
/// default (the fast schedule); `thorough()` and `paper()` are the other named schedules.
struct capture_options {
  pipeline_stages stages{};
  estimate_options estimate{};
  finetune_options finetune{};
  /// The refine after the network stages: the maps start near the answer (500 steps at 3e-3).
  refine_options refine = refine_options::after_networks();
  /// When > 0, refine also from a second start with both lobe widths at least this, and keep per
  /// texel group the fit with the lower loss (refine_two_starts). 0: one start.
  float second_start_lobe_width = 0.0f;
  /// After the refine that follows the network stages, one neighbourhood restart per radius, in
  /// this order (refine_neighbour_restarts; docs/method.md 8.4). Empty: none.
  std::vector<int> neighbour_restarts{8};
  /// The refine when the network stages do not run (no networks, or start maps): it starts from the
  /// first guess, far from the answer, so it takes refine_options' own 1000 steps at 0.03.
  refine_options refine_alone{};
  /// Neighbourhood restarts after the refine alone: none by default (each round would be another
  /// whole refine, and nothing was measured).
  std::vector<int> neighbour_restarts_alone{};
  /// capture_material's second runs of the network stages.
  second_run_options second_run{};
  /// capture_material's per-texel posterior standard deviations of the maps it returns
  /// (pipeline/uncertainty.hpp); unset: none computed.
  std::optional<uncertainty_options> uncertainty = uncertainty_options{};
  render_options render{};  ///< culling, double precision etc. for every image loss
  kernel_options kernel{};
  /// Operand precision of the networks' convolutions in the estimate, encode and fine-tune stages
  /// (nn/precision.hpp): fp32, or bf16 with FP32 accumulation and FP32 master weights on builds
  /// for CPUs with AVX-512 BF16 (nn::bf16_available()), where it takes about 0.7x the fine-tune
  /// step's time (bench/README.md). The refine does not use the networks.
  nn::precision network_precision = nn::precision::fp32;
  /// Rescale photographs and intensities to the synthetic captures' exposure first (exposure.hpp),
  /// so that the maps do not depend on the photographs' units.
  bool normalise_exposure = true;
  /// Check-point folder: each stage check-points into a subfolder; with `resume` completed stages
  /// are read back and the fine-tune continues from its last saved step.
  checkpoint_options checkpoint{};
  /// The processes the capture runs on (core/distributed.hpp; null: this one alone). Every rank
  /// calls capture_material with the same inputs and options and gets the same result. The
  /// estimate's windows and the fine-tune's steps are shared between them (the estimate gives the
  /// same bits on any rank count; for the fine-tune set finetune_options::shard_cells, e.g. to
  /// finetune_options::distributed_shard_cells, so that any rank count, one included, gives the
  /// same bits); so are the refine's texel groups (refine_options::ranks; any rank count gives the
  /// same bits). Only rank 0 writes check-points. Resuming needs the check-point folder on a file
  /// system every rank reads. Not owned: it must outlive the call.
  const communicator* ranks = nullptr;
  /// Progress of every stage (estimate: windows; fine-tune and refine every `progress_every` of theirs).
  std::function<void(const std::string& stage, const optimisation_progress&)> progress;
  /// The choices capture_material makes (a second run tried or not, and why; which fit was kept),
  /// one sentence each; none when unset.
  std::function<void(const std::string& message)> log;

  /// The fast schedule, the default: fine-tune 800 steps at 8e-3 after a 200-step warm-up, refine
  /// 500 at 3e-3, one neighbourhood restart round at radius 8 (about 30 s for 256 x 256 on 2 cores).
  static capture_options fast() { return {}; }
  /// The thorough schedule: fine-tune 2000 steps (finetune_options::thorough), refine 1000. On the
  /// 16-material family comparison it lowers the novel-view loss by 17% (foil 33%, satin 24%) for
  /// 2.1x the time (docs/results.md). For metals, or wherever accuracy matters more than time.
  static capture_options thorough() {
    capture_options o;
    o.finetune = finetune_options::thorough();
    o.refine.steps = 1000;
    return o;
  }
  /// The automatic schedule: the thorough schedule's step counts as caps, the fast one's as floors,
  /// and early stopping between them. The fine-tune runs 800 steps, then on while 200 steps lower
  /// the loss by at least `automatic_finetune_improvement`, up to 2000; the refine takes 500 steps, then
  /// on while 50 steps lower it by at least `automatic_refine_improvement`, up to 1000. A sample
  /// whose fit has settled by the fast schedule's end stops there; one still descending gets up to
  /// the thorough schedule's steps, without the user having to know which it is. On the
  /// 16-material family comparison it matched the thorough schedule's error at 0.89x its time: most
  /// fits, fabrics included, are still descending at step 800 (docs/results.md).
  static capture_options automatic() {
    capture_options o = thorough();
    o.finetune.min_steps = fast().finetune.steps;
    o.finetune.min_improvement = automatic_finetune_improvement;
    o.finetune.patience = 200;
    o.refine.min_steps = fast().refine.steps;
    o.refine.min_relative_improvement = automatic_refine_improvement;
    o.refine.patience = 50;
    return o;
  }
  /// The automatic schedule's thresholds: the fraction by which the loss must fall over the
  /// fine-tune's 200 steps and the refine's 50 for the stage to go on.
  static constexpr double automatic_finetune_improvement = 0.02, automatic_refine_improvement = 0.002;
  /// The paper's schedule (section 5): fine-tune 5000 steps at 7.5e-4 without warm-up, refine 500
  /// steps at 1e-4, no neighbourhood restarts.
  static capture_options paper() {
    capture_options o;
    o.finetune = finetune_options::paper();
    o.refine = refine_options::paper();
    o.neighbour_restarts.clear();
    return o;
  }
  /// The schedule of a name: fast, thorough, auto (automatic) or paper. Throws std::invalid_argument for another.
  static capture_options schedule(std::string_view name) {
    if (name == "fast") return fast();
    if (name == "thorough") return thorough();
    if (name == "auto") return automatic();
    if (name == "paper") return paper();
    throw std::invalid_argument("unknown schedule '" + std::string(name) + "' (fast, thorough, auto, paper)");
  }
  /// Takes the named schedule's fine-tune, refine and neighbourhood restarts (what a schedule sets)
  /// and keeps every other field, so that options set before or after it combine with it. Throws as
  /// schedule() for an unknown name.
  capture_options& apply_schedule(std::string_view name) {
    const capture_options s = schedule(name);
    finetune = s.finetune;
    refine = s.refine;
    neighbour_restarts = s.neighbour_restarts;
    return *this;
  }
  /// Throws std::invalid_argument when network_precision is bf16 and this build lacks AVX-512 BF16.
  void validate_precision() const { nn::require_available(network_precision, "capture_options::network_precision"); }
  /// Throws std::invalid_argument for a second start or neighbour-restart radius out of range.
  void validate_restarts() const {
    if (!(second_start_lobe_width >= 0 && second_start_lobe_width <= 1))
      throw std::invalid_argument("capture_options::second_start_lobe_width must be in [0, 1]");
    for (const auto* radii : {&neighbour_restarts, &neighbour_restarts_alone})
      for (int r : *radii)
        if (r < 1)
          throw std::invalid_argument("capture_options::neighbour_restarts: a radius must be at least 1 texel (got " + std::to_string(r) + ")");
  }
  /// Throws std::invalid_argument naming the field for impossible values.
  void validate() const {
    refine.validate();
    refine_alone.validate();
    estimate.validate();
    finetune.validate();
    second_run.validate();
    kernel.validate();
    if (uncertainty) uncertainty->validate();
    validate_precision();
    validate_restarts();
  }
};

/// What one stage did.
struct stage_report {
  std::string name;
  bool ran = false;
  bool resumed = false;   ///< read back from a check-point instead of computed
  int steps = 0;
  double loss = 0;        ///< image loss against the photographs after the stage
  double seconds = 0;
  double evaluated_fraction = 1.0;  ///< refine: fraction of texel-steps evaluated (freezing)
  int restarts = 0;                 ///< fine-tune: times the divergence guard went back and halved the rate
  double replaced_fraction = 0;     ///< refine with a second start: share of texel groups taken from it
  /// refine with neighbour restarts: per round, share of texel groups taken from its start
  std::vector<double> restart_replaced_fractions{};
};

/// What capture_material chose between when it could run the network stages more than once
/// (second_run_options): the kept run and the other one of its last choice.
struct run_choice {
  std::filesystem::path chosen, other;  ///< the weights folders of the kept and the other run
  double loss = 0, other_loss = 0;      ///< their final image losses against the photographs
  double other_seconds = 0;             ///< the time the other run's stages took
  bool other_ran = true;                ///< false: its condition was not met, the other did not run
  bool chosen_residual = false, other_residual = false;  ///< whether each run's fine-tune had the residual start
  double projection_ratio = 0;          ///< the first run's projection_ratio (NaN when encode or estimate did not run)
};

/// The result: the map set and a report per stage.
struct capture_result {
  material_maps maps;
  std::vector<stage_report> stages;
  /// The maps after the fine-tune stage (before refine), when that stage ran: the paper's Table 1
  /// reports both.
  std::optional<material_maps> after_finetune;
  /// The kernel the fine-tune and refine losses used (options.kernel's, or the automatic choice).
  brdf_features features = all_features;
  /// capture_material's per-texel posterior standard deviations of `maps` (capture_options::uncertainty).
  std::optional<uncertainty_result> uncertainty;
  /// Where the F0 map comes from: "photographs" (the kernel fitted the Fresnel term), "estimate"
  /// (the photographs do not determine F0, e.g. a flash capture, so the networks' estimate, or the
  /// start maps', is kept) or "prior" (the same without networks: kernel_options::prior_f0).
  std::string f0_source = "photographs";
  /// The factor photographs and intensities were multiplied by (1 without normalisation).
  double exposure_scale = 1.0;
  /// The image loss of `maps` (full kernel) against the photographs as the optimisers saw them.
  double loss = 0;
  /// The fine-tune returned at its `stop_after` (refine did not run); resume from the check-point.
  bool stopped = false;
  /// Whether the network stages ran (capture_material runs the refine alone without networks).
  bool networks_ran = false;
  /// capture_material's choice between runs, where a second run was possible.
  std::optional<run_choice> choice;

  /// The time the stages took, in seconds (the sum of stages' seconds).
  double stage_seconds() const {
    double t = 0;
    for (const stage_report& st : stages) t += st.seconds;
    return t;
  }

  /// The image loss after the stage named `name` (stage_report::loss), NaN when it did not run.
  double stage_loss(std::string_view name) const {
    for (const stage_report& st : stages)
      if (st.name == name && st.ran) return st.loss;
    return std::numeric_limits<double>::quiet_NaN();
  }
};

/// Each image's floor in the image loss's units: the file's level times its exposure factor (which
/// the loaded photographs already carry) and the capture's exposure scale (1 without normalisation).
inline std::vector<float> loss_floors(const capture& cap, double exposure_scale) {
  std::vector<float> floors;
  for (const capture_image& im : cap.images) floors.push_back(float(double(im.floor) * im.exposure * exposure_scale));
  return floors;
}

/// The configurations and loss targets a capture fits (capture_result::exposure_scale).
struct fitted_photographs {
  capture configurations;           ///< the configurations, their intensities times the exposure scale
  std::vector<image> photographs;   ///< the photographs times the exposure scale (what the estimate sees)
  loss_targets targets;             ///< the loss targets of `photographs`, with their masks and floors
};

/// What the stages fitted: `cap` and `photos` times `exposure_scale` (exposure.hpp; 1 without
/// normalisation), `masks` and the images' floors (loss_floors): what the stages fit, and what
/// checks the maps against the photographs afterwards (the uncertainty, the plan) in their units.
inline fitted_photographs fitted_targets(capture cap, std::vector<image> photos, const std::vector<image>& masks, double exposure_scale) {
  if (exposure_scale != 1.0) apply_exposure(cap, photos, exposure_scale);
  fitted_photographs out{std::move(cap), std::move(photos), {}};
  out.targets = make_loss_targets(out.photographs, masks, loss_floors(out.configurations, exposure_scale));
  return out;
}

/// Stands for the networks of a capture that runs without them.
struct no_networks {};

/// The fingerprint of capture_once's check-points: what their contents depend on. The
/// photographs' pixels, the configurations (positions and intensities; file names do not matter),
/// the start maps, the networks' weights, and the options of the stages that check-point (estimate
/// and fine-tune, with the kernel, the renderer's and the exposure options). Not the step counts:
/// a check-point after k steps is the same whatever the total, so a run may be resumed longer.
/// Not refine's options either: refine runs after the last check-point.
template <class Estimator = no_networks, class AutoEncoderNet = no_networks>
fingerprint capture_fingerprint(const capture& cap, const std::vector<image>& photos, Estimator& estimator,
                                AutoEncoderNet& autoencoder, const capture_options& o, const material_maps* start = nullptr) {
  fingerprint f;
  content_hash pixels;
  for (const image& p : photos) {
    pixels.value(p.width()).value(p.height()).value(p.channels());
    for (int c = 0; c < p.channels(); ++c) pixels.bytes(p.plane(c), p.pixel_count() * sizeof(float));
  }
  f.add("photographs", pixels.hex());
  content_hash configurations;
  for (const capture_image& i : cap.images) configurations.value(i.camera).value(i.light).value(i.intensity).value(i.floor).value(i.exposure);
  f.add("capture", configurations.hex());
  if (start) {
    content_hash maps;
    maps.value(start->width()).value(start->height());
    for (int k = 0; k < parameter_count; ++k) maps.bytes(start->plane(k), start->texel_count() * sizeof(float));
    f.add("start_maps", maps.hex());
  }
  auto weights = [](auto& net) {
    content_hash h;
    nn::detail::visit_weights(net, [&](auto& p) { h.bytes(p.value.data(), p.size() * sizeof(p.value[0])); });
    return h.hex();
  };
  if constexpr (!std::is_same_v<Estimator, no_networks>) f.add("estimator_weights", weights(estimator));
  if constexpr (!std::is_same_v<AutoEncoderNet, no_networks>) f.add("autoencoder_weights", weights(autoencoder));
  const pipeline_stages& st = o.stages;
  f.add("stages", std::string(st.estimate ? "estimate," : "") + (st.encode ? "encode," : "") + (st.finetune ? "finetune," : "") +
                      (st.refine ? "refine" : ""));
  estimate_options::visit_fields(o.estimate, [&](const std::string& name, int value) { f.add("estimate." + name, value); });
  kernel_options::visit_fields(o.kernel, [&](const std::string& name, const auto& value) {
    if constexpr (std::is_same_v<std::decay_t<decltype(value)>, brdf_features>) {
      // In the text check-points have always recorded (hence the comma a kernel without normal
      // maps leaves at the end), so that they still match.
      f.add("kernel." + name, std::string(value.anisotropic ? "anisotropic," : "") + (value.fresnel ? "fresnel," : "") +
                                  (value.normal_map ? "normal_map" : ""));
    } else if (name != "prior_f0") {  // F0 written after the stages, where no network gave one
      f.add("kernel." + name, double(value));
    }
  });
  f.add("normalise_exposure", o.normalise_exposure ? 1.0 : 0.0);
  f.add("render.cull_tolerance", o.render.cull_tolerance).add("render.double_precision", o.render.double_precision ? 1.0 : 0.0);
  finetune_options::visit_fields(o.finetune, [&](const std::string& name, const auto& value) {
    if (name == "steps") return;  // see above
    // Absent when 0 (the whole window; early stopping from the first step), so that check-points
    // written without these fields still match.
    if ((name == "shard_cells" || name == "min_steps") && value == 0) return;
    f.add("finetune." + name, double(value));
  });
  if (o.network_precision != nn::precision::fp32) f.add("network_precision", nn::to_string(o.network_precision));  // absent: fp32
  return f;
}

namespace capture_detail {

/// Prepares the check-point folder of capture_once: when resuming, refuses a folder whose
/// fingerprint differs from `now` (or that holds stages without one), naming what differs; when
/// not, removes the stages a previous run left there. Then writes `now` as fingerprint.txt.
inline void prepare_checkpoint_folder(const std::filesystem::path& folder, bool resume, const fingerprint& now) {
  namespace fs = std::filesystem;
  fs::create_directories(folder);
  const fs::path file = folder / "fingerprint.txt";
  const bool has_stages = fs::exists(folder / "estimate") || fs::exists(folder / "finetune");
  if (resume && fs::exists(file)) {
    std::ifstream in(file, std::ios::binary);
    std::stringstream text;
    text << in.rdbuf();
    if (!in) throw std::runtime_error(file.string() + ": cannot read the check-point's fingerprint");
    const auto differences = now.differences_from(fingerprint::parse(text.str()));
    if (!differences.empty()) {
      throw std::runtime_error(folder.string() + ": the check-point is of another capture or other options: " + join_names(differences, "; ") +
                               ". Run with the same inputs and options, or start over without resuming (checkpoint_options::resume)");
    }
  } else if (resume && has_stages) {
    throw std::runtime_error(folder.string() + ": the check-point has no fingerprint.txt, so it cannot be checked against "
                             "these inputs; remove the folder or start over without resuming (checkpoint_options::resume)");
  } else if (!resume) {
    fs::remove_all(folder / "estimate");
    fs::remove_all(folder / "finetune");
  }
  write_file_atomically(file, now.text());
}

/// Throws std::invalid_argument for what capture_once cannot run: no photograph per configuration,
/// network stages without networks, start maps beside the estimate, impossible stage options.
inline void validate_once(const capture_options& o, std::size_t photos, std::size_t configurations, bool has_networks, bool start) {
  if (photos == 0 || photos != configurations) throw std::invalid_argument("capture_once: need one photograph per configuration");
  if (o.stages.networks() && !has_networks) throw std::invalid_argument("capture_once: the estimate and encode stages need networks");
  if (start && o.stages.estimate) throw std::invalid_argument("capture_once: start maps replace the estimate stage");
  o.refine.validate();
  if (o.stages.estimate) o.estimate.validate();
  o.validate_restarts();
  if (o.stages.finetune) o.finetune.validate();
  o.validate_precision();
}

/// The kernel a capture fits with, and the F0 it keeps where that kernel leaves Fresnel out.
struct kernel_choice {
  brdf_features features;       ///< the kernel's features
  std::vector<float> prior_f0;  ///< per texel: the estimate's (or the start's) F0, else the prior
  /// Writes prior_f0 into `m` where the kernel has no Fresnel term.
  void keep_prior_f0(material_maps& m) const {
    if (!features.fresnel) std::copy(prior_f0.begin(), prior_f0.end(), m.plane(fresnel_f0));
  }
};

/// Chooses the kernel for `maps` under `cap`: o.kernel's features, or with auto_tolerance the
/// cheapest that renders them as the full one does. The kernel is chosen on the maps as they will
/// be written (F0 the estimate's where `estimated_f0`, else the prior), so that the full kernel
/// renders them on these configurations as the reduced one does.
inline kernel_choice choose_kernel(const material_maps& maps, const capture& cap, const capture_options& o, bool estimated_f0) {
  kernel_choice k;
  k.prior_f0 = estimated_f0 ? std::vector<float>(maps.plane(fresnel_f0), maps.plane(fresnel_f0) + maps.texel_count())
                            : std::vector<float>(maps.texel_count(), o.kernel.prior_f0);
  if (o.kernel.auto_tolerance > 0 && estimated_f0) {
    k.features = analyse_kernel(maps, cap, o.kernel.auto_tolerance).features;  // F0 as written already
  } else if (o.kernel.auto_tolerance > 0) {
    material_maps analysed = maps;
    std::copy(k.prior_f0.begin(), k.prior_f0.end(), analysed.plane(fresnel_f0));
    k.features = analyse_kernel(analysed, cap, o.kernel.auto_tolerance).features;
  } else {
    k.features = o.kernel.features;
  }
  return k;
}

/// A stage's progress callback: o.progress with the stage's name, or none.
inline std::function<void(const optimisation_progress&)> stage_reporter(const capture_options& o, const char* stage) {
  return o.progress ? std::function<void(const optimisation_progress&)>([&o, stage](const optimisation_progress& p) { o.progress(stage, p); })
                    : nullptr;
}

/// 4. The per-texel refine of `maps` (8.4) with `features`, its second start and neighbour restarts
/// as `o` asks; returns its report.
inline stage_report refine_stage(material_maps& maps, const capture& cap, const loss_targets& targets, const capture_options& o,
                                 brdf_features features) {
  refine_options ro = o.refine;
  ro.render = o.render;
  ro.ranks = o.ranks;  // the texel groups shared over the ranks
  if (!ro.progress) ro.progress = stage_reporter(o, "refine");
  stage_report r{"refine", true};
  if (o.second_start_lobe_width > 0) {
    const two_start_result tr = with_features(features, [&]<brdf_features F>() {
      return refine_two_starts<F>(maps, cap, targets, o.second_start_lobe_width, ro);
    });
    r = {"refine", true, false, tr.first.steps + tr.second.steps, tr.final_loss, tr.seconds,
         0.5 * (tr.first.evaluated_fraction + tr.second.evaluated_fraction)};
    r.replaced_fraction = tr.replaced_fraction;
  } else {
    const refine_result rr = with_features(features, [&]<brdf_features F>() { return refine<F>(maps, cap, targets, ro); });
    r = {"refine", true, false, rr.steps, rr.final_loss, rr.seconds, rr.evaluated_fraction};
  }
  if (!o.neighbour_restarts.empty()) {
    refine_options rounds = ro;
    if (!o.refine.progress) rounds.progress = stage_reporter(o, "restart");  // each round's refine
    const neighbour_restart_result nr = with_features(features, [&]<brdf_features F>() {
      return refine_neighbour_restarts<F>(maps, cap, targets, o.neighbour_restarts, rounds);
    });
    r.steps += nr.steps;
    r.loss = nr.final_loss;
    r.seconds += nr.seconds;
    r.restart_replaced_fractions = nr.replaced_fraction;
  }
  return r;
}

/// 2. Encode (8.2) and 3. fine-tune the decoder (8.3) as `o.stages` asks, from `maps` (replaced by
/// the decoding, then the fine-tuned maps), appending their reports to `result`. Returns false when
/// the fine-tune stopped early as if killed (finetune_options::stop_after): its check-point holds the rest.
template <class AutoEncoderNet>
bool network_stages(AutoEncoderNet& autoencoder, material_maps& maps, const capture& cap, const loss_targets& targets,
                    const capture_options& o, const kernel_choice& kernel, const communicator& comm, capture_result& result) {
  if (!o.stages.encode) return true;
  const int W = targets.width, H = targets.height;  // the photographs' size
  stage_report enc{"encode", true};
  const auto t1 = std::chrono::steady_clock::now();
  const auto z = encode(autoencoder, maps);
  // The residual start keeps the estimate as the fine-tune's start (D(z) + r = the estimate).
  std::optional<tensor<parameter_count, float>> residual;
  if (o.stages.finetune && o.finetune.residual) residual = decoder_residual(autoencoder, z, maps);
  enc.seconds = seconds_since(t1);
  maps = decode(autoencoder, z, W, H, residual ? &*residual : nullptr);
  enc.loss = image_loss(maps, cap, targets, kernel.features, o.render);
  result.stages.push_back(enc);
  if (!o.stages.finetune) return true;
  finetune_options fo = o.finetune;
  if (!fo.progress) fo.progress = stage_reporter(o, "finetune");
  checkpoint_options co = o.checkpoint;
  if (!co.folder.empty()) co.folder /= "finetune";
  finetune_result fr = finetune(autoencoder, z, W, H, cap, targets, kernel.features, o.render, enc.loss, fo, co,
                                residual ? &*residual : nullptr, comm);
  maps = std::move(fr.maps);
  kernel.keep_prior_f0(maps);
  result.after_finetune = maps;
  result.stages.push_back({"finetune", true, fr.resumed, fr.steps, fr.loss, fr.seconds, 1.0, fr.restarts});
  return !fr.stopped;
}

}  // namespace capture_detail

/// One run of exactly the stages and options in `o` (capture_material, the entry point, resolves
/// the schedules and adds the second runs): the map set of one material from its photographs (one
/// per configuration of `cap`). `estimator` and `autoencoder` hold trained weights for the stages that use them; pass
/// `no_networks` for both to run the first guess and refine alone. `start`, when given, replaces
/// the estimate (or the first guess). `masks` (optional, one 1-channel image per photograph,
/// 0 = left out, e.g. clipped pixels: data/photo_io.hpp; other values weigh the pixel) keep pixels out of every image loss (the
/// first guess, fine-tune with or without crops, refine and every stage's reported loss); the
/// estimator still sees whole photographs.
template <class Estimator = no_networks, class AutoEncoderNet = no_networks>
capture_result capture_once(const capture& given_cap, const std::vector<image>& given_photos, Estimator& estimator,
                            AutoEncoderNet& autoencoder, const capture_options& o, const material_maps* start = nullptr,
                            const std::vector<image>& masks = {}) {
  namespace fs = std::filesystem;
  constexpr bool has_networks = !std::is_same_v<Estimator, no_networks> && !std::is_same_v<AutoEncoderNet, no_networks>;
  capture_detail::validate_once(o, given_photos.size(), given_cap.images.size(), has_networks, start != nullptr);
  const nn::precision_scope precision(o.network_precision);
  capture_result result;
  if (o.normalise_exposure) result.exposure_scale = exposure_scale(given_cap);
  const fitted_photographs fitted = fitted_targets(given_cap, given_photos, masks, result.exposure_scale);
  const capture& cap = fitted.configurations;
  const std::vector<image>& photos = fitted.photographs;
  const loss_targets& targets = fitted.targets;
  const communicator& comm = o.ranks ? *o.ranks : serial_communicator();
  const bool checkpoints = !o.checkpoint.folder.empty();
  if (checkpoints && comm.root())
    capture_detail::prepare_checkpoint_folder(o.checkpoint.folder, o.checkpoint.resume,
                                              capture_fingerprint(given_cap, given_photos, estimator, autoencoder, o, start));
  const fs::path estimate_folder = o.checkpoint.folder / "estimate";
  // Whether the estimate is read back: rank 0 decides before it may write one.
  const bool resume_estimate =
      comm.root_decides([&] { return checkpoints && o.checkpoint.resume && fs::exists(estimate_folder / "diffuse.exr"); });

  // 1. Estimate (8.1), or the first guess.
  const auto t0 = std::chrono::steady_clock::now();
  stage_report first{o.stages.estimate ? "estimate" : "first_guess", o.stages.estimate};
  material_maps maps;
  if (resume_estimate) {
    maps = read_maps(estimate_folder);
    first.resumed = true;
  } else if (o.stages.estimate) {
    if constexpr (has_networks) maps = estimate(photos, estimator, o.estimate, capture_detail::stage_reporter(o, "estimate"), comm);
    if (checkpoints && comm.root()) write_maps(maps, estimate_folder, false);
  } else {
    maps = start ? *start : initial_guess(cap, photos, {}, masks);
    first.ran = !start;
  }
  // F0 where the kernel leaves Fresnel out: the estimate's (or the start's), else the prior.
  const bool estimated_f0 = o.stages.estimate || start;
  const capture_detail::kernel_choice kernel = capture_detail::choose_kernel(maps, cap, o, estimated_f0);
  result.features = kernel.features;
  if (!result.features.fresnel) result.f0_source = estimated_f0 ? "estimate" : "prior";
  first.loss = image_loss(maps, cap, targets, result.features, o.render);
  first.seconds = seconds_since(t0);
  result.stages.push_back(first);

  // 2. Encode and 3. fine-tune the decoder.
  if constexpr (has_networks) {
    if (!capture_detail::network_stages(autoencoder, maps, cap, targets, o, kernel, comm, result)) {
      result.stopped = true;  // as if killed: the check-point holds the rest
      result.loss = image_loss(maps, cap, targets, all_features, o.render);
      result.maps = std::move(maps);
      return result;
    }
  }
  // 4. Refine per texel.
  if (o.stages.refine) result.stages.push_back(capture_detail::refine_stage(maps, cap, targets, o, result.features));
  kernel.keep_prior_f0(maps);
  result.loss = image_loss(maps, cap, targets, all_features, o.render);
  result.maps = std::move(maps);
  return result;
}

/// capture_once without networks: the first guess (or `start`) and refine, with `masks` as there.
inline capture_result capture_once(const capture& cap, const std::vector<image>& photos, const capture_options& o,
                                   const material_maps* start = nullptr, const std::vector<image>& masks = {}) {
  no_networks none;
  return capture_once(cap, photos, none, none, o, start, masks);
}

}  // namespace anisocap
