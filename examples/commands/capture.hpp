#pragma once
// `anisocap capture`: the map set of a material from its photographs (docs/method.md section 8).
#include <omp.h>

#include <chrono>
#include <memory>
#include <optional>

#include "anisocap/export/canonical_maps.hpp"
#include "anisocap/export/viewer.hpp"
#include "common.hpp"

namespace anisocap::commands {

/// What the capture command reads and writes besides the library's capture_options.
struct capture_settings {
  fs::path capture_file;
  fs::path out = "anisocap-result";
  std::optional<fs::path> truth, init;
  std::string stages = "auto";  ///< auto: all stages when the weights are there, else refine alone
  bool resume = false;
  bool view = true;  ///< write material.html (the viewer page, export/viewer.hpp) beside the maps
  model_choice models;
  capture_options options;
  photo_options photos;  ///< clipped-pixel detection (--saturation, --fit-clipped)
  std::optional<float> floor;  ///< --floor: replaces every image's floor (capture_image::floor)
};

/// Runs a capture: writes the map set (canonical, export/canonical_maps.hpp), the viewer page
/// (unless `s.view` is off), re-renders, novel views, a contact sheet and report.json into `s.out`; returns the report. `parsed` is the command (to see which options were given).
inline nlohmann::json run_capture_command(capture_settings s, const CLI::App* parsed) {
  const auto start = std::chrono::steady_clock::now();
  capture_options& o = s.options;
  o.finetune.validate();  // impossible options and missing weights are refused before any work
  o.refine.validate();
  if (parsed->count("--models") > 0 && !s.models.present())
    throw std::invalid_argument("--models " + s.models.models.string() + ": no " + s.models.preset + " weights there (" +
                                s.models.estimator().string() + ", " + s.models.autoencoder().string() + ")");
  capture cap = read_capture(s.capture_file);
  if (s.floor) {
    if (!(std::isfinite(*s.floor) && *s.floor >= 0)) throw std::invalid_argument("--floor must be a finite number >= 0");
    for (capture_image& im : cap.images) im.floor = *s.floor;
  }
  const std::vector<photo> loaded = load_capture_photos(cap, s.capture_file.parent_path(), s.photos);
  const std::vector<image> photos = photo_pixels(loaded);
  const std::vector<image> masks = photo_masks(loaded);
  // Clipped and masked pixels, per image: never fitted silently.
  nlohmann::json photo_report = nlohmann::json::array();
  for (std::size_t i = 0; i < loaded.size(); ++i) {
    const photo& p = loaded[i];
    const capture_image& entry = cap.images[i];
    if (p.clipped > 0)
      std::fprintf(stderr, "capture: image %zu (%s): %.1f%% of pixels clipped, %s\n", i, entry.file.c_str(), 100.0 * p.clipped_fraction(),
                   s.photos.exclude_clipped ? "excluded from the loss" : "FITTED (--fit-clipped)");
    if (!entry.mask.empty())
      std::fprintf(stderr, "capture: image %zu (%s): %.1f%% of pixels left out of the loss (mask %s%s)\n", i, entry.file.c_str(),
                   100.0 * p.masked_fraction(), entry.mask.c_str(), p.clipped > 0 && s.photos.exclude_clipped ? " and clipping" : "");
    photo_report.push_back({{"file", entry.file}, {"mask", entry.mask}, {"exposure", entry.exposure}, {"floor", entry.floor},
                            {"clipped_fraction", p.clipped_fraction()}, {"masked_fraction", p.masked_fraction()}});
  }
  if (photos.size() < 4)
    std::fprintf(stderr, "capture: warning: %zu photograph%s cannot separate the maps' parameters (the problem is ill-posed: many "
                 "map sets render the same); the method needs about 8 (docs/method.md section 6), at least 4\n",
                 photos.size(), photos.size() == 1 ? "" : "s");
  std::optional<material_maps> truth, start_maps;
  auto check_size = [&](const material_maps& m, const fs::path& file) {
    if (m.width() != photos[0].width() || m.height() != photos[0].height())
      throw std::invalid_argument(file.string() + ": the maps are " + std::to_string(m.width()) + "x" + std::to_string(m.height()) +
                                  " but the photographs are " + std::to_string(photos[0].width()) + "x" + std::to_string(photos[0].height()));
  };
  if (s.truth) check_size(*(truth = read_maps(*s.truth)), *s.truth);
  if (s.init) check_size(*(start_maps = read_maps(*s.init)), *s.init);
  // Outputs stay inside OUT and never replace an input; checked before any work.
  std::vector<fs::path> inputs = capture_inputs(cap, s.capture_file);
  for (const auto& folder : {s.truth, s.init})
    if (folder) {
      const auto files = map_files(*folder);
      inputs.insert(inputs.end(), files.begin(), files.end());
    }
  std::vector<fs::path> outputs = map_files(s.out), renders = image_outputs(cap, s.out / "renders");
  outputs.insert(outputs.end(), renders.begin(), renders.end());
  for (const char* name : {"report.json", "contact_sheet.png"}) outputs.push_back(s.out / name);
  refuse_overwriting_inputs(outputs, inputs);
  output_lock lock(s.out);
  // A failed run leaves nothing but a check-point with completed stages, and says so.
  struct on_failure {
    output_lock& lock;
    fs::path checkpoint;
    bool succeeded = false;
    ~on_failure() {
      if (succeeded) return;
      std::error_code ec;
      if (fs::exists(checkpoint / "estimate", ec) || fs::exists(checkpoint / "finetune", ec))
        std::fprintf(stderr, "capture: failed; the completed stages are kept in %s: after fixing the cause, the same command with "
                     "--resume continues from them\n", checkpoint.c_str());
      else
        fs::remove_all(checkpoint, ec);
      lock.release_empty();
    }
  } cleanup{lock, s.out / ".checkpoint"};
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
  refine_alone_schedule(o, *parsed);
  resolve_neighbour_restarts(o, *parsed);
  resolve_second_run(s.models, o.stages, *parsed);
  o.checkpoint = {s.out / ".checkpoint", s.resume};
  o.finetune.progress_every = 25;
  o.refine.progress_every = std::max(1, o.refine.steps / 50);
  o.progress = print_progress;
  std::fprintf(stderr, "capture: %zu images of %dx%d from %s, stages %s, %d threads\n", photos.size(), photos[0].width(),
               photos[0].height(), s.capture_file.c_str(), stages_text.c_str(), omp_get_max_threads());

  model_selection selection;
  capture_result result = run_capture(cap, photos, s.models, o, start_maps ? &*start_maps : nullptr, masks, &selection);
  const std::string kernel_used = kernel_analysis{result.features, 0, 0, 0}.describe();
  if (o.kernel.auto_tolerance > 0) std::fprintf(stderr, "capture: kernel auto -> %s\n", kernel_used.c_str());

  const auto t_write = std::chrono::steady_clock::now();
  material_maps& maps = result.maps;
  canonicalise(maps);
  create_output_folder(s.out);
  // Every result file is staged under a temporary name and all are renamed into place together at
  // the end: a failure while producing any of them leaves the folder's earlier results as they were.
  file_transaction files;
  const std::vector<fs::path> stale_maps = stage_maps(maps, s.out, files);
  if (s.view) files.stage(s.out / "material.html", viewer_html(maps, {s.out.filename().string()}));
  const std::vector<image> rerenders = render(maps, cap);
  stage_images(rerenders, cap, s.out / "renders", files, inputs);
  write_png(make_capture_sheet(photos, rerenders, maps, truth ? &*truth : nullptr), s.out / "contact_sheet.png", files);
  const capture novel = novel_view_set(1, maps.width(), maps.height());
  stage_images(render(maps, novel), novel, s.out / "novel", files);
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
  report["saturation"] = s.photos.saturation;
  report["clipped_excluded"] = s.photos.exclude_clipped;
  report["photos"] = photo_report;
  report["threads"] = omp_get_max_threads();
  report["stages"] = nlohmann::json::array();
  for (const auto& st : result.stages)
    report["stages"].push_back({{"name", st.name}, {"ran", st.ran}, {"resumed", st.resumed}, {"steps", st.steps},
                                {"loss", st.loss}, {"seconds", st.seconds}, {"evaluated_fraction", st.evaluated_fraction},
                                {"restarts", st.restarts}, {"replaced_fraction", st.replaced_fraction},
                                {"restart_replaced_fractions", st.restart_replaced_fractions}});
  report["refine"] = {{"steps", o.refine.steps}, {"learning_rate", o.refine.learning_rate},
                      {"stop", o.refine.min_relative_improvement}, {"freeze", o.refine.freeze_tolerance},
                      {"neighbour_restarts", o.neighbour_restarts}};
  if (networks)
    report["finetune"] = {{"steps", o.finetune.steps}, {"learning_rate", o.finetune.learning_rate}, {"warmup", o.finetune.warmup},
                          {"half_life", o.finetune.half_life}, {"crop", o.finetune.crop.cells}, {"guard", o.finetune.guard.factor},
                          {"residual", o.finetune.residual}, {"preset", s.models.preset}};
  if (o.stages.estimate) report["estimate"] = {{"window", o.estimate.window}, {"stride", o.estimate.stride}};
  report["loss"] = result.loss;
  if (s.models.second_run() && networks)
    report["models"] = {{"chosen", fs::absolute(selection.chosen).string()}, {"loss", selection.loss},
                        {"other", fs::absolute(selection.other).string()}, {"other_ran", selection.other_ran},
                        {"other_loss", selection.other_ran ? nlohmann::json(selection.other_loss) : nlohmann::json()},
                        {"other_seconds", selection.other_seconds}, {"above", s.models.alternative_above},
                        {"chosen_residual", selection.chosen_residual}, {"other_residual", selection.other_residual},
                        {"residual_ratio", s.models.residual_ratio},
                        {"projection_ratio", std::isfinite(selection.projection_ratio) ? nlohmann::json(selection.projection_ratio)
                                                                                       : nlohmann::json()}};
  report["timings"] = {{"load", load_seconds}, {"stages", result.stage_seconds()}, {"write", write_seconds}, {"total", seconds_since(start)}};
  report["novel_views"] = nlohmann::json::array();
  for (const auto& v : novel.images)
    report["novel_views"].push_back({{"file", "novel/" + v.file}, {"camera", v.camera}, {"light", v.light}, {"intensity", v.intensity}});
  if (truth) {
    report["errors"] = errors_to_json(compare_maps(maps, *truth));
    report["errors"]["novel_view_image_loss"] = novel_view_error(maps, *truth, novel);
  }
  report["peak_memory_bytes"] = peak_resident_bytes();
  files.stage(s.out / "report.json", report.dump(2) + "\n");
  files.commit();
  remove_stale_files(stale_maps);
  cleanup.succeeded = true;
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
  c->add_option("--floor", s.floor,
                "every image's floor, replacing capture.json's: the linear level (in the files' values) below which they are not "
                "measurements; the loss takes photograph and render as at least this (rectify sets it for JPEG photos; 0: none)")
      ->check(CLI::NonNegativeNumber);
  c->add_option("--saturation", s.photos.saturation, "linear level at or above which a pixel counts as clipped, in any format (EXR, HDR: the only clip test; 0: off). 8/16-bit PNG and JPEG pixels at the largest code are always clipped")
      ->check(CLI::NonNegativeNumber);
  c->add_flag_callback("--fit-clipped", [&s] { s.photos.exclude_clipped = false; },
                       "fit clipped pixels instead of leaving them out of the loss (still counted and reported; for comparisons)");
}

/// Registers `anisocap capture`.
inline void add_capture_command(CLI::App& app) {
  auto s = std::make_shared<capture_settings>();
  auto* c = app.add_subcommand("capture", "estimate the map set from a capture: estimate, encode, fine-tune, refine (docs/method.md section 8)");
  c->add_option("capture", s->capture_file, "capture.json")->required();
  add_capture_options(c, *s);
  c->add_option("--truth", s->truth, "true map set: adds per-parameter errors to report.json");
  c->add_option("--init", s->init, "start from this map set instead of the built-in first guess");
  c->add_flag("!--no-view", s->view, "do not write the viewer page material.html beside the maps");
  c->callback([s, c] { run_capture_command(*s, c); });
}

}  // namespace anisocap::commands
