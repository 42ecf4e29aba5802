#pragma once
// `anisocap capture`: the map set of a material from its photographs (docs/method.md section 8).
#include <omp.h>

#include <chrono>
#include <memory>
#include <optional>

#include "common.hpp"

namespace anisocap::commands {

/// What the capture command reads and writes besides the library's capture_options.
struct capture_settings {
  fs::path capture_file;
  fs::path out = "anisocap-result";
  std::optional<fs::path> truth, init;
  std::string stages = "auto";  ///< auto: all stages when the weights are there, else refine alone
  bool resume = false;
  model_choice models;
  capture_options options;
};

/// Runs a capture: writes the map set, re-renders, novel views, a contact sheet and report.json
/// into `s.out`; returns the report. `parsed` is the command (to see which options were given).
inline nlohmann::json run_capture_command(capture_settings s, const CLI::App* parsed) {
  const auto start = std::chrono::steady_clock::now();
  capture_options& o = s.options;
  const capture cap = read_capture(s.capture_file);
  const std::vector<image> photos = load_capture_images(cap, s.capture_file.parent_path());
  std::optional<material_maps> truth, start_maps;
  auto check_size = [&](const material_maps& m, const fs::path& file) {
    if (m.width() != photos[0].width() || m.height() != photos[0].height())
      throw std::invalid_argument(file.string() + ": the maps are " + std::to_string(m.width()) + "x" + std::to_string(m.height()) +
                                  " but the photographs are " + std::to_string(photos[0].width()) + "x" + std::to_string(photos[0].height()));
  };
  if (s.truth) check_size(*(truth = read_maps(*s.truth)), *s.truth);
  if (s.init) check_size(*(start_maps = read_maps(*s.init)), *s.init);
  const double load_seconds = seconds_since(start);

  // Which stages: "auto" runs the networks when their weights are there (and no --init), else refine alone.
  std::string stages_text = s.stages;
  if (stages_text == "auto") {
    stages_text = s.models.present() && !s.init ? "all" : "refine";
    if (!s.models.present())
      std::fprintf(stderr, "capture: no %s weights in %s: running the per-texel refine alone (train them with "
                   "`anisocap train-estimator` / `train-autoencoder`, or pass --models)\n", s.models.preset.c_str(),
                   (s.models.models / s.models.preset).c_str());
  }
  o.stages = pipeline_stages::parse(stages_text);
  const bool networks = o.stages.networks();
  if (networks && s.init) throw std::invalid_argument("--init replaces the network stages: use it with --stages refine");
  if (!networks) {  // refine from the first guess starts far from the answer: refine_options' own schedule
    if (parsed->count("--steps") == 0) o.refine.steps = refine_options{}.steps;
    if (parsed->count("--lr") == 0) o.refine.learning_rate = refine_options{}.learning_rate;
  }
  o.checkpoint = {s.out / ".checkpoint", s.resume};
  o.finetune.progress_every = 25;
  o.refine.progress_every = std::max(1, o.refine.steps / 50);
  o.progress = print_progress;
  std::fprintf(stderr, "capture: %zu images of %dx%d from %s, stages %s, %d threads\n", photos.size(), photos[0].width(),
               photos[0].height(), s.capture_file.c_str(), stages_text.c_str(), omp_get_max_threads());

  const capture_result result = run_capture(cap, photos, s.models, o, start_maps ? &*start_maps : nullptr);
  const std::string kernel_used = kernel_analysis{result.features, 0, 0, 0}.describe();
  if (o.kernel.auto_tolerance > 0) std::fprintf(stderr, "capture: kernel auto -> %s\n", kernel_used.c_str());

  const auto t_write = std::chrono::steady_clock::now();
  const material_maps& maps = result.maps;
  fs::create_directories(s.out);
  write_maps(maps, s.out);
  write_renders(maps, cap, s.out / "renders");
  write_capture_sheet(s.out / "contact_sheet.png", photos, render(maps, cap), maps, truth ? &*truth : nullptr);
  const capture novel = novel_view_set(1, maps.width(), maps.height());
  write_renders(maps, novel, s.out / "novel");
  const double write_seconds = seconds_since(t_write);

  nlohmann::json report;
  report["capture"] = fs::absolute(s.capture_file).string();
  report["images"] = photos.size();
  report["width"] = photos[0].width();
  report["height"] = photos[0].height();
  report["kernel"] = o.kernel.auto_tolerance > 0 ? "auto" : kernel_used;
  report["kernel_used"] = kernel_used;
  report["precision"] = o.render.double_precision ? "double" : "float";
  report["exposure_scale"] = result.exposure_scale;
  report["threads"] = omp_get_max_threads();
  report["stages"] = nlohmann::json::array();
  double stage_seconds = 0;
  for (const auto& st : result.stages) {
    report["stages"].push_back({{"name", st.name}, {"ran", st.ran}, {"resumed", st.resumed}, {"steps", st.steps},
                                {"loss", st.loss}, {"seconds", st.seconds}, {"evaluated_fraction", st.evaluated_fraction},
                                {"restarts", st.restarts}});
    stage_seconds += st.seconds;
  }
  report["refine"] = {{"steps", o.refine.steps}, {"learning_rate", o.refine.learning_rate},
                      {"stop", o.refine.min_relative_improvement}, {"freeze", o.refine.freeze_tolerance}};
  if (networks)
    report["finetune"] = {{"steps", o.finetune.steps}, {"learning_rate", o.finetune.learning_rate}, {"warmup", o.finetune.warmup},
                          {"half_life", o.finetune.half_life}, {"crop", o.finetune.crop.cells}, {"guard", o.finetune.guard.factor},
                          {"preset", s.models.preset}};
  report["loss"] = result.loss;
  report["timings"] = {{"load", load_seconds}, {"stages", stage_seconds}, {"write", write_seconds}, {"total", seconds_since(start)}};
  report["novel_views"] = nlohmann::json::array();
  for (const auto& v : novel.images)
    report["novel_views"].push_back({{"file", "novel/" + v.file}, {"camera", v.camera}, {"light", v.light}, {"intensity", v.intensity}});
  if (truth) {
    report["errors"] = errors_to_json(compare_maps(maps, *truth));
    report["errors"]["novel_view_image_loss"] = novel_view_error(maps, *truth, novel);
  }
  report["peak_memory_bytes"] = peak_resident_bytes();
  write_file_atomically(s.out / "report.json", report.dump(2) + "\n");
  std::error_code ec;
  fs::remove_all(s.out / ".checkpoint", ec);  // finished: nothing left to resume
  std::fprintf(stderr, "capture:");
  for (const auto& st : result.stages) std::fprintf(stderr, " %s %.4f (%.1f s)", st.name.c_str(), st.loss, st.seconds);
  std::fprintf(stderr, "; maps, renders, contact sheet and report.json in %s\n", s.out.c_str());
  return report;
}

/// The options of a capture (shared with demo).
inline void add_capture_options(CLI::App* c, capture_settings& s) {
  c->add_option("-o,--out", s.out, "output folder");
  c->add_option("--stages", s.stages, "stages to run: auto (all when the weights are there, else refine), all, or a list of estimate,encode,finetune,refine");
  add_model_options(c, s.models);
  c->add_flag("--resume", s.resume, "continue a killed run from OUT/.checkpoint");
  add_optimiser_options(c, s.options);
}

/// Registers `anisocap capture`.
inline void add_capture_command(CLI::App& app) {
  auto s = std::make_shared<capture_settings>();
  auto* c = app.add_subcommand("capture", "estimate the map set from a capture: estimate, encode, fine-tune, refine (docs/method.md section 8)");
  c->add_option("capture", s->capture_file, "capture.json")->required();
  add_capture_options(c, *s);
  c->add_option("--truth", s->truth, "true map set: adds per-parameter errors to report.json");
  c->add_option("--init", s->init, "start from this map set instead of the built-in first guess");
  c->callback([s, c] { run_capture_command(*s, c); });
}

}  // namespace anisocap::commands
