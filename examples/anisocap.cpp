// The `anisocap` program: synthesize procedural captures, render map sets, capture materials from
// photographs, and a self-contained demo. `anisocap --help` and `anisocap <command> --help` list
// every option.
#include <omp.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <string>

#include "anisocap/anisocap.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/pipeline/capture_pipeline.hpp"
#include "anisocap/render/analysis.hpp"
#include "commands/train.hpp"

namespace fs = std::filesystem;
using namespace anisocap;

namespace {

// ---- small helpers ------------------------------------------------------------------------------



/// Prints optimisation progress on one refreshed line on a terminal, or one line per report in logs.
struct progress_printer {
  std::string stage;
  bool tty = isatty(fileno(stderr));
  void operator()(const optimisation_progress& p) const {
    std::fprintf(stderr, "%s  %s step %5d/%d  loss %.5f  %6.1f steps/s  %5.1f s left%s", tty ? "\r" : "", stage.c_str(),
                 p.step, p.steps, p.loss, p.steps_per_second, p.seconds_left, tty ? "   " : "\n");
    if (tty && p.step == p.steps) std::fputc('\n', stderr);
    std::fflush(stderr);
  }
};

/// Kernel choice by name: which BRDF terms the optimiser evaluates.
brdf_features features_from_name(const std::string& name) {
  if (name == "full" || name == "auto") return all_features;
  if (name == "isotropic") return {false, true, true};
  if (name == "no-fresnel") return {true, false, true};
  if (name == "flat") return {true, true, false};
  if (name == "isotropic-flat") return {false, true, false};
  if (name == "lambert-like") return {false, false, false};
  throw std::invalid_argument("unknown --kernel '" + name + "' (full, isotropic, no-fresnel, flat, isotropic-flat, lambert-like)");
}

nlohmann::json errors_to_json(const parameter_errors& e) {
  return {{"diffuse", e.diffuse}, {"specular", e.specular}, {"normal", e.normal}, {"lobes", e.lobes},
          {"rotation", e.rotation},
          {"rotation_anisotropic", std::isnan(e.rotation_anisotropic) ? nlohmann::json(nullptr) : nlohmann::json(e.rotation_anisotropic)},
          {"fresnel", e.fresnel}};
}

/// Writes `images` (one per capture image) into `out`: one linear EXR per image under its capture
/// file name (a .png name gets an 8-bit sRGB PNG instead), plus a PNG preview beside every EXR.
/// All files appear together or not at all.
void write_images(const std::vector<image>& images, const capture& cap, const fs::path& out) {
  fs::create_directories(out);
  file_transaction files;
  for (std::size_t i = 0; i < images.size(); ++i) {
    const fs::path target = out / cap.images[i].file;
    if (target.has_parent_path()) fs::create_directories(target.parent_path());
    const auto ext = target.extension().string();
    if (ext == ".exr" || ext == ".EXR") {
      write_exr(images[i], target, files);
      write_png(images[i], fs::path(target).replace_extension(".png"), files);
    } else {
      write_png(images[i], target, files);
    }
  }
  files.commit();
}

/// Renders `maps` under `cap` into `out` (write_images).
void write_renders(const material_maps& maps, const capture& cap, const fs::path& out,
                   const brdf_features& features = all_features) {
  write_images(with_features(features, [&]<brdf_features F>() { return render<F>(maps, cap); }), cap, out);
}

// ---- commands -----------------------------------------------------------------------------------

struct synthesize_args {
  fs::path out = "anisocap-synthetic";
  int width = 256, height = 256, images = 12;
  std::string set = "alpha";
  std::uint64_t seed = 1;
  std::string kind;
  std::string materials = "original";  // mix the kind is drawn from when --kind is not given
  fresnel_options fresnel;  // set alpha's grazing configurations (default: the paper's 2)
  sensor_noise noise;  // simulated sensor noise on the rendered inputs (none by default)
};

/// A procedural material, its map set (truth/), N rendered inputs and capture.json.
void synthesize(const synthesize_args& a) {
  if (a.width < 1 || a.height < 1) throw std::invalid_argument("--width and --height must be positive");
  if (a.images < 4) throw std::invalid_argument("--images must be at least 4 (set alpha needs 2 Fresnel and 2 independent)");
  procedural_options options;
  options.mix = *material_mix_from_name(a.materials);
  if (!a.kind.empty()) {
    options.kind = material_kind_from_name(a.kind);
    if (!options.kind) throw std::invalid_argument("unknown --kind '" + a.kind + "'");
  }
  const material_maps truth = generate_material(a.seed, a.width, a.height, options);
  capture cap;
  if (a.set == "alpha") cap = set_alpha(a.images, a.seed, a.width, a.height, a.fresnel);
  else if (a.set == "beta") cap = set_beta(a.images, a.seed, a.width, a.height);
  else throw std::invalid_argument("--set must be alpha or beta, got '" + a.set + "'");
  fs::create_directories(a.out);
  write_maps(truth, a.out / "truth");
  a.noise.validate();
  std::vector<image> photos = render(truth, cap);
  add_sensor_noise(photos, a.noise, a.seed);
  write_images(photos, cap, a.out);
  write_capture(cap, a.out / "capture.json");
  std::fprintf(stderr, "synthesized %s (%s, seed %llu, %dx%d) with %d inputs (set %s) in %s\n",
               material_kind_name(draw_procedural_parameters(a.seed, options).kind), a.kind.empty() ? "kind from seed" : "forced",
               static_cast<unsigned long long>(a.seed), a.width, a.height, a.images, a.set.c_str(), a.out.c_str());
}

#ifndef ANISOCAP_MODELS_DIR
#define ANISOCAP_MODELS_DIR "models"
#endif

struct capture_args {
  fs::path capture_file;
  fs::path out = "anisocap-result";
  std::optional<fs::path> truth, init;
  std::string stages = "auto";
  std::string preset = "compact";
  fs::path models = ANISOCAP_MODELS_DIR;
  int steps = -1;                 // refine steps (-1: 500 after the networks, 1000 alone)
  float learning_rate = -1;       // refine learning rate (-1: 0.003 after the networks, 0.03 alone)
  int finetune_steps = 5000;
  float finetune_learning_rate = 7.5e-4f;
  double finetune_stop = 0.0;
  int finetune_warmup = 0;        // learning-rate warm-up steps (0: none)
  int finetune_half_life = 0;     // learning-rate half-life in steps (0: constant)
  int finetune_crop = 0;          // crop mini-batches of this many latent cells per side (0: whole tile)
  bool resume = false;
  std::string kernel = "full";
  float cull = 0.0f;
  double refine_stop = 0.0;       // refine early stopping (0: never)
  double freeze = 0.0;            // refine only texels whose loss still moves (0: all, every step)
  std::string precision = "float";
};

/// Applies the options every command that runs the optimisers shares (kernel, culling, precision,
/// early stopping, freezing) after checking them.
void apply_optimiser_options(const capture_args& a, pipeline_options& po) {
  if (a.cull < 0 || a.cull >= 1) throw std::invalid_argument("--cull must be in [0, 1)");
  if (a.refine_stop < 0 || a.refine_stop >= 1) throw std::invalid_argument("--refine-stop must be in [0, 1)");
  if (a.finetune_stop < 0 || a.finetune_stop >= 1) throw std::invalid_argument("--finetune-stop must be in [0, 1)");
  if (a.freeze < 0 || a.freeze >= 1) throw std::invalid_argument("--freeze must be in [0, 1)");
  if (a.finetune_steps < 0) throw std::invalid_argument("--finetune-steps must be >= 0");
  if (!(a.finetune_learning_rate > 0)) throw std::invalid_argument("--finetune-lr must be positive");
  if (a.finetune_warmup < 0) throw std::invalid_argument("--finetune-warmup must be >= 0");
  if (a.finetune_half_life < 0) throw std::invalid_argument("--finetune-half-life must be >= 0");
  if (a.finetune_crop < 0) throw std::invalid_argument("--finetune-crop must be >= 0");
  if (a.precision != "float" && a.precision != "double") throw std::invalid_argument("--precision must be float or double, got '" + a.precision + "'");
  po.features = features_from_name(a.kernel);
  po.auto_kernel_tolerance = a.kernel == "auto" ? 1e-3 : 0.0;
  po.render.cull_tolerance = a.cull;
  po.render.double_precision = a.precision == "double";
  po.finetune_min_improvement = a.finetune_stop;
  po.finetune_learning_rate = a.finetune_learning_rate;
  po.finetune_warmup = a.finetune_warmup;
  po.finetune_half_life = a.finetune_half_life;
  po.finetune_crop = a.finetune_crop;
  po.refine.min_relative_improvement = a.refine_stop;
  po.refine.freeze_tolerance = a.freeze;
}

/// Where the weights of a preset live, and whether both files are there.
struct model_files {
  fs::path estimator, autoencoder;
  bool present() const { return fs::exists(estimator) && fs::exists(autoencoder); }
};
model_files models_for(const capture_args& a) {
  return {a.models / a.preset / "estimator.safetensors", a.models / a.preset / "autoencoder.safetensors"};
}

/// Runs the network stages of docs/method.md section 8 with the weights of `preset`.
pipeline_result run_network_pipeline(const capture_args& a, const capture& cap, const std::vector<image>& photos,
                                     const pipeline_options& o) {
  const model_files files = models_for(a);
  auto run = [&]<class EstimatorPreset, class AutoEncoderPreset>() {
    EstimationNet<EstimatorPreset> estimator;
    AutoEncoder<AutoEncoderPreset> autoencoder;
    nn::load_weights(files.estimator, estimator);
    nn::load_weights(files.autoencoder, autoencoder);
    return run_pipeline(cap, photos, estimator, autoencoder, o);
  };
  if (a.preset == "compact") return run.template operator()<estimator_compact, autoencoder_compact>();
  if (a.preset == "paper") return run.template operator()<estimator_paper, autoencoder_paper>();
  throw std::invalid_argument("unknown --preset '" + a.preset + "' (compact, paper)");
}

/// Per-texel optimisation from a capture: writes the map set, re-renders and report.json.
nlohmann::json capture_command(const capture_args& a) {
  const auto start = std::chrono::steady_clock::now();
  if (a.steps < -1) throw std::invalid_argument("--steps must be >= 0");
  if (!(a.learning_rate > 0) && a.learning_rate != -1) throw std::invalid_argument("--lr must be positive");
  pipeline_options po;
  apply_optimiser_options(a, po);
  const capture cap = read_capture(a.capture_file);
  auto photos = load_capture_images(cap, a.capture_file.parent_path());
  // The optimisers work on a capture rescaled to a standard exposure (pipeline/exposure.hpp); the
  // re-renders below use the capture as given, so they compare with the photographs.
  capture work_cap = cap;
  const double exposure = exposure_scale(cap);
  apply_exposure(work_cap, photos, exposure);
  std::optional<material_maps> truth;
  if (a.truth) truth = read_maps(*a.truth);
  if (truth && (truth->width() != photos[0].width() || truth->height() != photos[0].height()))
    throw std::invalid_argument(a.truth->string() + ": the true maps are " + std::to_string(truth->width()) + "x" +
                                std::to_string(truth->height()) + " but the photographs are " +
                                std::to_string(photos[0].width()) + "x" + std::to_string(photos[0].height()));
  const double load_seconds = seconds_since(start);
  std::fprintf(stderr, "capture: %zu images of %dx%d from %s, kernel %s, %d threads\n", photos.size(), photos[0].width(),
               photos[0].height(), a.capture_file.c_str(), a.kernel.c_str(), omp_get_max_threads());

  // Which stages: "auto" runs the networks when their weights are there, else refine alone.
  const model_files files = models_for(a);
  std::string stages_text = a.stages;
  if (stages_text == "auto") {
    stages_text = files.present() && !a.init ? "all" : "refine";
    if (!files.present())
      std::fprintf(stderr, "capture: no %s weights in %s: running the per-texel refine alone (train them with "
                   "`anisocap train-estimator` / `train-autoencoder`, or pass --models)\n", a.preset.c_str(), (a.models / a.preset).c_str());
  }
  const pipeline_stages stages = pipeline_stages::parse(stages_text);
  const bool networks = stages.estimate || stages.encode;
  if (networks && !files.present())
    throw std::invalid_argument("--stages " + stages_text + " needs the " + a.preset + " weights: " + files.estimator.string() +
                                " and " + files.autoencoder.string() + " (not found)");
  if (networks && a.init) throw std::invalid_argument("--init replaces the network stages: use it with --stages refine");
  const int refine_steps = a.steps >= 0 ? a.steps : (networks ? 500 : 1000);
  const float refine_lr = a.learning_rate > 0 ? a.learning_rate : (networks ? 0.003f : 0.03f);

  const auto t_init = std::chrono::steady_clock::now();
  std::optional<material_maps> start_maps;
  if (a.init) {
    start_maps = read_maps(*a.init);
    if (start_maps->width() != photos[0].width() || start_maps->height() != photos[0].height())
      throw std::invalid_argument(a.init->string() + ": the initial maps differ in size from the photographs");
  }
  const loss_targets targets = make_loss_targets(photos);
  const double init_seconds = seconds_since(t_init);

  po.refine.steps = refine_steps;
  po.refine.learning_rate = refine_lr;
  po.refine.render = po.render;
  material_maps maps;
  std::vector<stage_report> stage_reports;
  brdf_features used_features = po.features;
  if (networks) {
    po.stages = stages;
    po.finetune_steps = a.finetune_steps;
    po.normalise_exposure = false;  // done above
    po.checkpoint_dir = a.out / ".checkpoint";
    po.resume = a.resume;
    po.progress_every = 25;
    po.progress = [](const std::string& stage, const optimisation_progress& p) { progress_printer{stage}(p); };
    pipeline_result pr = run_network_pipeline(a, work_cap, photos, po);
    maps = std::move(pr.maps);
    stage_reports = pr.stages;
    used_features = pr.features;
  } else {
    maps = start_maps ? *start_maps : initial_guess(work_cap, photos);
    if (a.kernel == "auto") used_features = analyse_kernel(maps, work_cap).features;  // exact for the start (--init)
    stage_reports.push_back({"first_guess", true, false, 0, loss_and_gradient(maps, work_cap, targets, nullptr, {}, po.render), init_seconds});
    if (stages.refine) {
      refine_options ro = po.refine;
      ro.progress_every = std::max(1, refine_steps / 50);
      ro.progress = progress_printer{"refine"};
      const refine_result r = with_features(used_features, [&]<brdf_features F>() { return refine<F>(maps, work_cap, targets, ro); });
      stage_reports.push_back({"refine", true, false, r.steps, r.final_loss, r.seconds, r.evaluated_fraction});
    }
  }
  if (a.kernel == "auto")
    std::fprintf(stderr, "capture: kernel auto -> %s\n", kernel_analysis{used_features, 0, 0, 0}.describe().c_str());
  const auto t_write = std::chrono::steady_clock::now();
  fs::create_directories(a.out);
  write_maps(maps, a.out);
  write_renders(maps, cap, a.out / "renders");
  write_capture_sheet(a.out / "contact_sheet.png", photos, render(maps, work_cap), maps, truth ? &*truth : nullptr);
  const capture novel = novel_view_set(1, maps.width(), maps.height());
  write_renders(maps, novel, a.out / "novel");
  const double write_seconds = seconds_since(t_write);

  nlohmann::json report;
  report["capture"] = fs::absolute(a.capture_file).string();
  report["images"] = photos.size();
  report["width"] = photos[0].width();
  report["height"] = photos[0].height();
  report["kernel"] = a.kernel;
  report["kernel_used"] = kernel_analysis{used_features, 0, 0, 0}.describe();
  report["precision"] = a.precision;
  report["exposure_scale"] = exposure;
  report["threads"] = omp_get_max_threads();
  report["stages"] = nlohmann::json::array();
  double stage_seconds = 0;
  for (const auto& st : stage_reports) {
    report["stages"].push_back({{"name", st.name}, {"ran", st.ran}, {"resumed", st.resumed}, {"steps", st.steps},
                                {"loss", st.loss}, {"seconds", st.seconds}, {"evaluated_fraction", st.evaluated_fraction},
                                {"restarts", st.restarts}});
    stage_seconds += st.seconds;
  }
  report["refine"] = {{"steps", refine_steps}, {"learning_rate", refine_lr}, {"stop", a.refine_stop}, {"freeze", a.freeze}};
  if (networks)
    report["finetune"] = {{"steps", a.finetune_steps}, {"learning_rate", a.finetune_learning_rate}, {"warmup", a.finetune_warmup},
                          {"half_life", a.finetune_half_life}, {"crop", a.finetune_crop}, {"preset", a.preset}};
  const double final_loss = loss_and_gradient(maps, work_cap, targets, nullptr, {}, po.render);
  report["loss"] = final_loss;
  report["timings"] = {{"load", load_seconds}, {"stages", stage_seconds}, {"write", write_seconds}, {"total", seconds_since(start)}};
  report["novel_views"] = nlohmann::json::array();
  for (const auto& v : novel.images)
    report["novel_views"].push_back({{"file", "novel/" + v.file}, {"camera", v.camera}, {"light", v.light}, {"intensity", v.intensity}});
  if (truth) {
    report["errors"] = errors_to_json(compare_maps(maps, *truth));
    report["errors"]["novel_view_image_loss"] = novel_view_error(maps, *truth, novel);
  }
  report["peak_memory_bytes"] = peak_resident_bytes();
  write_file_atomically(a.out / "report.json", report.dump(2) + "\n");
  std::error_code ec;
  fs::remove_all(a.out / ".checkpoint", ec);  // finished: nothing left to resume
  std::fprintf(stderr, "capture:");
  for (const auto& st : stage_reports) std::fprintf(stderr, " %s %.4f (%.1f s)", st.name.c_str(), st.loss, st.seconds);
  std::fprintf(stderr, "; maps, renders, contact sheet and report.json in %s\n", a.out.c_str());
  return report;
}


struct eval_args {
  fs::path out = "anisocap-eval";
  int count = 20, min_size = 256, max_size = 640;
  std::vector<int> image_counts{8, 10, 12};
  std::vector<std::string> sets{"alpha", "beta"};
  std::uint64_t first_seed = 900000;  // validation seeds: disjoint from training (training draws below 2^32 from its own salts)
  sensor_noise noise;  // simulated sensor noise on the inputs (the novel views stay exact)
  std::string materials = "original";  // mix the materials' kinds are drawn from (procedural.hpp material_mix)
  std::string families;                // non-empty: these families only, material m gets the (m mod n)-th
  fresnel_options fresnel;             // set alpha's grazing configurations (default: the paper's 2)
};

/// The paper's Table 1 on procedural validation materials (docs/method.md section 9): per N, set and stage the
/// mean over materials of each per-parameter MSE, the novel-view image loss and seconds per material.
void eval_command(const eval_args& e, const capture_args& base) {
  if (e.count < 1 || e.min_size < 1 || e.max_size < e.min_size) throw std::invalid_argument("eval: need --count >= 1 and 1 <= --min-size <= --max-size");
  for (const auto& set : e.sets)
    if (set != "alpha" && set != "beta") throw std::invalid_argument("eval: --sets takes alpha and beta, got '" + set + "'");
  for (int n : e.image_counts)
    if (n < 4 || n < e.fresnel.count + 2)
      throw std::invalid_argument("eval: --images values must be >= 4 and >= --fresnel + 2");
  e.noise.validate();
  const std::vector<material_kind> families = material_kinds_from_names(e.families);
  const auto mix = material_mix_from_name(e.materials);
  if (!mix) throw std::invalid_argument("eval: --materials takes original, extended or training, got '" + e.materials + "'");
  {
    pipeline_options check;
    apply_optimiser_options(base, check);  // reject impossible options before any work
  }
  const model_files files = models_for(base);
  if (!files.present()) throw std::invalid_argument("eval needs the " + base.preset + " weights in " + (base.models / base.preset).string());
  struct row_sum { parameter_errors e{}; double novel = 0, seconds = 0; int n = 0; };
  std::map<std::string, row_sum> rows;
  std::map<std::string, std::vector<material_errors>> family_rows;  // same keys: per-material errors for the per-family table
  std::vector<std::string> order;
  std::ostringstream csv;
  csv << "material,seed,width,height,images,set,stage,diffuse,specular,normal,lobes,rotation,rotation_anisotropic,fresnel,novel_view_loss,seconds,family\n";
  auto add = [&](const std::string& key, const parameter_errors& pe, double novel, double sec) {
    if (!rows.count(key)) order.push_back(key);
    auto& r = rows[key];
    r.e.diffuse += pe.diffuse; r.e.specular += pe.specular; r.e.normal += pe.normal; r.e.lobes += pe.lobes;
    r.e.rotation += pe.rotation; r.e.fresnel += pe.fresnel; r.novel += novel; r.seconds += sec; ++r.n;
  };
  // Rewritten (atomically) after every material, so a long run that is stopped keeps its rows so far.
  auto write_tables = [&]() -> std::string {
    std::ostringstream md;
    md << "| N | stage | set | a_d | a_s | n_s | sigma | alpha | F0 | novel-view loss | s / material |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& key : order) {
      const auto& r = rows[key];
      const double k = r.n;
      const auto p1 = key.find('|'), p2 = key.rfind('|');
      char line[400];
      std::snprintf(line, sizeof line, "| %s | %s | %s | %.4f | %.4f | %.4f | %.4f | %.3f | %.4f | %.4f | %.1f |\n", key.substr(0, p1).c_str(),
                    key.substr(p1 + 1, p2 - p1 - 1).c_str(), key.substr(p2 + 1).c_str(), r.e.diffuse / k, r.e.specular / k,
                    r.e.normal / k, r.e.lobes / k, r.e.rotation / k, r.e.fresnel / k, r.novel / k, r.seconds / k);
      md << line;
    }
    md << "\nPer family (held out of training: leather, printed)\n\n| N | stage | set | family | materials | a_d | a_s | n_s | sigma | alpha | F0 | novel-view loss |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& key : order) {
      const auto p1 = key.find('|'), p2 = key.rfind('|');
      for (const family_errors& f : errors_by_family(family_rows[key])) {
        char line[400];
        std::snprintf(line, sizeof line, "| %s | %s | %s | %s%s | %d | %.4f | %.4f | %.4f | %.4f | %.3f | %.4f | %.4f |\n",
                      key.substr(0, p1).c_str(), key.substr(p1 + 1, p2 - p1 - 1).c_str(), key.substr(p2 + 1).c_str(),
                      material_kind_name(f.kind), is_held_out(f.kind) ? " (held out)" : "", f.count, f.mean.diffuse,
                      f.mean.specular, f.mean.normal, f.mean.lobes, f.mean.rotation, f.mean.fresnel, f.novel_view_loss);
        md << line;
      }
    }
    fs::create_directories(e.out);
    file_transaction files_out;
    const std::string table = md.str(), rows_csv = csv.str();
    files_out.stage(e.out / "table.md", table.data(), table.size());
    files_out.stage(e.out / "table.csv", rows_csv.data(), rows_csv.size());
    files_out.commit();
    return table;
  };
  for (int m = 0; m < e.count; ++m) {
    const std::uint64_t seed = e.first_seed + std::uint64_t(m);
    random_generator rng(hash64(seed ^ 0x6576616cULL));
    const int w = e.min_size + int(rng.uniform_int(std::uint64_t(e.max_size - e.min_size + 1)));
    const int h = e.min_size + int(rng.uniform_int(std::uint64_t(e.max_size - e.min_size + 1)));
    procedural_options material_options;
    material_options.mix = *mix;
    material_options.kind = evaluation_kind(m, seed, families, *mix);
    const material_maps truth = generate_material(seed, w, h, material_options);
    const capture novel = novel_view_set(seed, w, h);
    for (int n : e.image_counts)
      for (const auto& set : e.sets) {
        const capture cap = set == "alpha" ? set_alpha(n, seed, w, h, e.fresnel) : set_beta(n, seed, w, h);
        auto photos = render(truth, cap);
        add_sensor_noise(photos, e.noise, seed ^ hash64(std::uint64_t(n) * 2 + (set == "beta")));
        pipeline_options po;
        apply_optimiser_options(base, po);
        po.finetune_steps = base.finetune_steps;
        po.refine.steps = base.steps >= 0 ? base.steps : 500;
        po.refine.learning_rate = base.learning_rate > 0 ? base.learning_rate : 0.003f;
        const auto t0 = std::chrono::steady_clock::now();
        const pipeline_result pr = run_network_pipeline(base, cap, photos, po);
        const double sec = seconds_since(t0);
        std::fprintf(stderr, "eval: material %d/%d (seed %llu, %dx%d, %s) N=%d set %s: %.1f s\n", m + 1, e.count,
                     static_cast<unsigned long long>(seed), w, h, material_kind_name(*material_options.kind), n, set.c_str(), sec);
        auto record = [&](const char* stage, const material_maps& maps) {
          const parameter_errors pe = compare_maps(maps, truth);
          const double nv = novel_view_error(maps, truth, novel);
          const std::string key = std::to_string(n) + "|" + stage + "|" + set;
          add(key, pe, nv, sec);
          family_rows[key].push_back({*material_options.kind, pe, nv});
          csv << m << ',' << seed << ',' << w << ',' << h << ',' << n << ',' << set << ',' << stage << ',' << pe.diffuse << ','
              << pe.specular << ',' << pe.normal << ',' << pe.lobes << ',' << pe.rotation << ',' << pe.rotation_anisotropic << ','
              << pe.fresnel << ',' << nv << ',' << sec << ',' << material_kind_name(*material_options.kind) << '\n';
        };
        if (pr.after_finetune) record("fine-tuned", *pr.after_finetune);
        record("refined", pr.maps);
      }
    write_tables();
    std::fprintf(stderr, "eval: %d/%d materials done, tables in %s\n", m + 1, e.count, e.out.c_str());
  }
  const std::string table = write_tables();
  std::printf("%s\n(%d materials, %d to %d texels a side; per-material rows in %s)\n", table.c_str(), e.count, e.min_size, e.max_size,
              (e.out / "table.csv").c_str());
}

void render_command(const fs::path& maps_dir, const fs::path& capture_file, const fs::path& out) {
  const material_maps maps = read_maps(maps_dir);
  const capture cap = read_capture(capture_file);
  // The cheapest kernel that renders these maps exactly (within 1e-4 relative): skips anisotropy,
  // Fresnel or the normal frame when the maps and configurations do not need them.
  const kernel_analysis kernel = analyse_kernel(maps, cap, 1e-4);
  write_renders(maps, cap, out, kernel.features);
  std::fprintf(stderr, "rendered %zu images of %dx%d into %s (kernel: %s)\n", cap.images.size(), maps.width(), maps.height(),
               out.c_str(), kernel.describe().c_str());
}

/// The paper's Table 1 row "12, refined, set alpha" (docs/method.md section 9), for the demo's summary.
void print_error_table(const nlohmann::json& errors) {
  struct row { const char* name; const char* key; double paper; };
  const row rows[] = {{"diffuse a_d", "diffuse", 0.0002}, {"specular a'_s", "specular", 0.0019},
                      {"normal n_s", "normal", 0.0016},   {"lobes sigma", "lobes", 0.0068},
                      {"rotation alpha (mod pi)", "rotation", 0.50}, {"Fresnel F0", "fresnel", 0.059}};
  std::printf("\n| parameter | MSE (this run) | paper, N=12 refined, set alpha |\n|---|---|---|\n");
  for (const auto& r : rows) std::printf("| %s | %.5f | %.4f |\n", r.name, errors[r.key].get<double>(), r.paper);
  if (!errors["rotation_anisotropic"].is_null())
    std::printf("| rotation, anisotropic texels only | %.5f | - |\n", errors["rotation_anisotropic"].get<double>());
  std::printf("| novel-view image loss (3 unseen views) | %.5f | - |\n\n", errors["novel_view_image_loss"].get<double>());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"anisocap: capture anisotropic SVBRDFs (Ward + Fresnel) from a few photographs"};
  app.require_subcommand(1);
  int threads = 0;
  app.add_option("--threads", threads, "worker threads (default: all cores)")->check(CLI::NonNegativeNumber);

  // Simulated sensor noise on rendered inputs, for synthesize and eval.
  auto add_noise_options = [](CLI::App* c, sensor_noise& noise) {
    c->add_option("--shot-noise", noise.shot, "simulated sensor shot noise on the inputs: relative standard deviation at pixel value 1 (0: exact renders)")->capture_default_str()->check(CLI::NonNegativeNumber);
    c->add_option("--read-noise", noise.read, "simulated sensor read noise on the inputs: standard deviation independent of the pixel value")->capture_default_str()->check(CLI::NonNegativeNumber);
  };

  synthesize_args syn;
  auto* syn_cmd = app.add_subcommand("synthesize", "make a procedural material, its map set (truth/), rendered inputs and capture.json");
  syn_cmd->add_option("-o,--out", syn.out, "output folder")->capture_default_str();
  syn_cmd->add_option("--width", syn.width, "material width in texels")->capture_default_str();
  syn_cmd->add_option("--height", syn.height, "material height in texels")->capture_default_str();
  syn_cmd->add_option("--images", syn.images, "number of input images")->capture_default_str();
  syn_cmd->add_option("--set", syn.set, "configuration set: alpha (Fresnel + anisotropic pairs + independent) or beta (independent + mirror)")->capture_default_str();
  syn_cmd->add_option("--seed", syn.seed, "material and configuration seed")->capture_default_str();
  syn_cmd->add_option("--kind", syn.kind,
                      "force a material kind: plain, basket, twill, herringbone, satin, velvet, brushed, spun, leather, "
                      "coated, printed, foil");
  syn_cmd->add_option("--fresnel", syn.fresnel.count,
                      "grazing (Fresnel) configurations in set alpha; 4 with N = 12 separates a'_s from F0 better on metals "
                      "(studies/README.md)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  syn_cmd->add_option("--materials", syn.materials, "families the kind is drawn from without --kind: original, extended or training")
      ->check(CLI::IsMember({"original", "extended", "training"}))
      ->capture_default_str();
  add_noise_options(syn_cmd, syn.noise);

  fs::path maps_dir, render_capture, render_out;
  auto* render_cmd = app.add_subcommand("render", "render a map set under a capture's configurations");
  render_cmd->add_option("--maps", maps_dir, "map set folder")->required();
  render_cmd->add_option("--capture", render_capture, "capture.json")->required();
  render_cmd->add_option("-o,--out", render_out, "output folder")->required();

  capture_args cap;
  // The optimisers' options, shared by capture, demo and eval.
  auto add_optimiser_options = [&](CLI::App* c) {
    c->add_option("--finetune-lr", cap.finetune_learning_rate, "decoder fine-tune learning rate (paper: 7.5e-4)")->capture_default_str();
    c->add_option("--finetune-stop", cap.finetune_stop, "stop fine-tuning when 200 steps improve the loss by less than this fraction (0: never)")->capture_default_str();
    c->add_option("--finetune-warmup", cap.finetune_warmup, "fine-tune learning-rate warm-up: linear ramp over this many steps (0: none)")->capture_default_str();
    c->add_option("--finetune-half-life", cap.finetune_half_life, "fine-tune learning rate halves every this many steps (0: constant)")->capture_default_str();
    c->add_option("--finetune-crop", cap.finetune_crop, "fine-tune on random crops of this many 32-texel latent cells per side (0: the whole tile, as the paper)")->capture_default_str();
    c->add_option("--kernel", cap.kernel, "BRDF terms the fine-tune and refine stages fit: full, auto (the cheapest kernel that renders the estimate, or the first guess, within 1e-3), isotropic, no-fresnel, flat, isotropic-flat, lambert-like")->capture_default_str();
    c->add_option("--cull", cap.cull, "specular culling tolerance on each pixel's log loss term (0: exact)")->capture_default_str();
    c->add_option("--refine-stop", cap.refine_stop, "stop refining when 50 steps improve the loss by less than this fraction (0: never)")->capture_default_str();
    c->add_option("--freeze", cap.freeze, "refine only texels whose loss still moves: freeze a 64-texel group when 25 steps improve its loss by less than this fraction (0: never)")->capture_default_str();
    c->add_option("--precision", cap.precision, "arithmetic of the image-loss kernels: float or double (maps stay float)")->capture_default_str();
  };
  auto add_capture_options = [&](CLI::App* c) {
    c->add_option("-o,--out", cap.out, "output folder")->capture_default_str();
    c->add_option("--stages", cap.stages, "stages to run: auto (all when the weights are there, else refine), all, or a list of estimate,encode,finetune,refine")->capture_default_str();
    c->add_option("--preset", cap.preset, "network preset whose weights to use: compact, paper")->capture_default_str();
    c->add_option("--models", cap.models, "folder holding <preset>/estimator.safetensors and autoencoder.safetensors")->capture_default_str();
    c->add_option("--steps", cap.steps, "refine steps (default 500 after the networks, 1000 alone)");
    c->add_option("--lr", cap.learning_rate, "refine learning rate, Adam in unconstrained parameters (default 0.003 after the networks, 0.03 alone)");
    c->add_option("--finetune-steps", cap.finetune_steps, "decoder fine-tune steps (paper: 5000)")->capture_default_str();
    c->add_flag("--resume", cap.resume, "continue a killed run from OUT/.checkpoint");
    add_optimiser_options(c);
  };
  auto* capture_cmd = app.add_subcommand("capture", "estimate the map set from a capture (per-texel optimisation)");
  capture_cmd->add_option("capture", cap.capture_file, "capture.json")->required();
  add_capture_options(capture_cmd);
  capture_cmd->add_option("--truth", cap.truth, "true map set: adds per-parameter errors to report.json");
  capture_cmd->add_option("--init", cap.init, "start from this map set instead of the built-in first guess");

  eval_args ev;
  auto* eval_cmd = app.add_subcommand("eval", "the paper's Table 1 on procedural validation materials (per N, set, stage)");
  eval_cmd->add_option("-o,--out", ev.out, "output folder for table.md and table.csv")->capture_default_str();
  eval_cmd->add_option("--count", ev.count, "validation materials")->capture_default_str();
  eval_cmd->add_option("--min-size", ev.min_size, "smallest side in texels")->capture_default_str();
  eval_cmd->add_option("--max-size", ev.max_size, "largest side in texels")->capture_default_str();
  eval_cmd->add_option("--images", ev.image_counts, "input counts N")->delimiter(',')->capture_default_str();
  eval_cmd->add_option("--sets", ev.sets, "configuration sets")->delimiter(',')->capture_default_str();
  add_noise_options(eval_cmd, ev.noise);
  eval_cmd->add_option("--fresnel", ev.fresnel.count, "grazing (Fresnel) configurations in set alpha")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  eval_cmd->add_option("--materials", ev.materials, "families the materials are drawn from: original, extended or training")
      ->check(CLI::IsMember({"original", "extended", "training"}))
      ->capture_default_str();
  eval_cmd->add_option("--families", ev.families,
                       "evaluate these families only, comma-separated (e.g. leather,printed or brushed,spun,foil); "
                       "material m gets the (m mod n)-th");
  eval_cmd->add_option("--preset", cap.preset, "network preset")->capture_default_str();
  eval_cmd->add_option("--models", cap.models, "weights folder")->capture_default_str();
  eval_cmd->add_option("--finetune-steps", cap.finetune_steps, "decoder fine-tune steps")->capture_default_str();
  eval_cmd->add_option("--steps", cap.steps, "refine steps (default 500)");
  add_optimiser_options(eval_cmd);

  synthesize_args demo_syn;
  demo_syn.out = "anisocap-demo";
  auto* demo_cmd = app.add_subcommand("demo", "synthesize a procedural fabric, capture it, report per-parameter errors");
  demo_cmd->add_option("-o,--out", demo_syn.out, "output folder")->capture_default_str();
  demo_cmd->add_option("--seed", demo_syn.seed, "material seed")->capture_default_str();
  demo_cmd->add_option("--size", demo_syn.width, "material size (square)")->capture_default_str();
  demo_cmd->add_option("--steps", cap.steps, "refine steps (default 500 after the networks, 1000 alone)");
  // The demo runs the fast fine-tune schedule of studies/README.md "Run time against error": 800
  // steps at 8e-3 after a 200-step warm-up reach about the error of the paper's 5000 steps at
  // 7.5e-4 in a sixth of the time. --finetune-lr / --finetune-warmup override it.
  int demo_finetune_steps = 800;
  demo_cmd->add_option("--finetune-steps", demo_finetune_steps, "decoder fine-tune steps (the paper uses 5000 at 7.5e-4; the demo 800 at 8e-3 after a 200-step warm-up)")->capture_default_str();
  demo_cmd->add_option("--stages", cap.stages, "stages to run (see capture --help)")->capture_default_str();
  add_optimiser_options(demo_cmd);

  std::vector<std::pair<CLI::App*, std::function<void()>>> actions;
  commands::add_train_commands(app, actions);

  CLI11_PARSE(app, argc, argv);
  if (threads > 0) omp_set_num_threads(threads);
  try {
    if (*syn_cmd) synthesize(syn);
    if (*render_cmd) render_command(maps_dir, render_capture, render_out);
    if (*capture_cmd) capture_command(cap);
    if (*eval_cmd) eval_command(ev, cap);
    for (auto& [command, action] : actions)
      if (*command) action();
    if (*demo_cmd) {
      demo_syn.height = demo_syn.width;
      const fs::path root = demo_syn.out;
      demo_syn.out = root / "input";
      synthesize(demo_syn);
      cap.capture_file = demo_syn.out / "capture.json";
      cap.truth = demo_syn.out / "truth";
      cap.out = root / "result";
      cap.finetune_steps = demo_finetune_steps;
      if (demo_cmd->count("--finetune-lr") == 0) cap.finetune_learning_rate = 8e-3f;
      if (demo_cmd->count("--finetune-warmup") == 0) cap.finetune_warmup = 200;
      const auto report = capture_command(cap);
      print_error_table(report["errors"]);
      std::printf("inputs and true maps: %s\nestimated maps, re-renders and report.json: %s\n", demo_syn.out.c_str(), cap.out.c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "anisocap: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
