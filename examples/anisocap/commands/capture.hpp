#pragma once
// `anisocap capture`: the map set of a material from its photographs (docs/method.md section 8).
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <optional>
#include <type_traits>

#include "anisocap/export/viewer.hpp"
#include "anisocap/pipeline/progress_line.hpp"
#include "common.hpp"
#include "ranks.hpp"
#include "tileable.hpp"

namespace anisocap::commands {

/// What the capture command reads and writes besides the library's capture_options.
struct capture_settings {
  fs::path capture_file;
  fs::path out = "anisocap-result";
  std::optional<fs::path> truth, init;
  std::string stages = "auto";  ///< auto: all stages when the weights are there, else refine alone
  bool resume = false;
  double checkpoint_seconds = checkpoint_options{}.seconds;  ///< --checkpoint-every
  bool view = true;  ///< write material.html (the viewer page, export/viewer.hpp) beside the maps
  model_choice models;
  capture_options options;
  photo_options photos;  ///< clipped-pixel detection (--saturation, --fit-clipped)
  std::optional<float> floor;  ///< --floor: replaces every image's floor (capture_image::floor)
  bool tileable = false;       ///< --tileable: also write a seamless tile of the maps to OUT/tileable/
  tileable_options tile;       ///< --tile-overlap
};

/// The end of a capture in a few lines: what was made, where, how well it fits the photographs,
/// and what to do next.
inline void print_capture_summary(const capture_result& r, const fs::path& out, double seconds, bool view) {
  std::string path;
  for (const auto& st : r.stages)
    if (st.ran || st.resumed) {
      char step[80];
      std::snprintf(step, sizeof step, "%s%s %.4f", path.empty() ? "" : " -> ", st.name.c_str(), st.loss);
      path += step;
    }
  std::fprintf(stderr,
               "capture: done in %.0f s: %dx%d maps, image loss %.4f against the photographs (%s)\n"
               "  maps and previews   %s/  (diffuse, specular, normal, lobes, rotation, fresnel: .exr and .png)\n"
               "  photos vs renders   %s\n",
               seconds, r.maps.width(), r.maps.height(), r.loss, path.c_str(), out.c_str(), (out / "contact_sheet.png").c_str());
  if (view) std::fprintf(stderr, "  look at it          open %s in a browser\n", (out / "material.html").c_str());
  std::fprintf(stderr, "  export              anisocap export %s --format gltf -o %s  (or mitsuba, blender, mtlx)\n"
               "  details             %s\n", out.c_str(), (out / "material.gltf").c_str(), (out / "report.json").c_str());
}

/// What the capture command reads: the description (with --floor applied), the photographs and
/// their masks, what was clipped or masked per photograph (said on stderr, kept for report.json),
/// and the --truth and --init map sets.
struct capture_command_inputs {
  capture cap;
  std::vector<image> photos, masks;
  nlohmann::json photo_report = nlohmann::json::array();
  std::optional<material_maps> truth, start_maps;
  std::vector<fs::path> files;  ///< every file read: outputs never replace one
};

/// Reads what `s` names, checking sizes; says on stderr which pixels are clipped or masked.
inline capture_command_inputs read_capture_command_inputs(const capture_settings& s) {
  capture_command_inputs in;
  in.cap = read_capture(s.capture_file);
  if (s.floor) {
    if (!(std::isfinite(*s.floor) && *s.floor >= 0)) throw std::invalid_argument("--floor must be a finite number >= 0");
    for (capture_image& im : in.cap.images) im.floor = *s.floor;
  }
  const std::vector<photo> loaded = load_capture_photos(in.cap, s.capture_file.parent_path(), s.photos);
  set_photo_encodings(in.cap, loaded);
  in.photos = photo_pixels(loaded);
  in.masks = photo_masks(loaded);
  // Clipped and masked pixels, per image: never fitted silently.
  for (std::size_t i = 0; i < loaded.size(); ++i) {
    const photo& p = loaded[i];
    const capture_image& entry = in.cap.images[i];
    if (p.clipped > 0)
      std::fprintf(stderr, "capture: image %zu (%s): %.1f%% of pixels clipped, %s\n", i, entry.file.c_str(), 100.0 * p.clipped_fraction(),
                   s.photos.exclude_clipped ? "excluded from the loss" : "FITTED (--fit-clipped)");
    if (!entry.mask.empty())
      std::fprintf(stderr, "capture: image %zu (%s): %.1f%% of pixels left out of the loss (mask %s%s)\n", i, entry.file.c_str(),
                   100.0 * p.masked_fraction(), entry.mask.c_str(), p.clipped > 0 && s.photos.exclude_clipped ? " and clipping" : "");
    in.photo_report.push_back({{"file", entry.file}, {"mask", entry.mask}, {"exposure", entry.exposure}, {"floor", entry.floor},
                               {"clipped_fraction", p.clipped_fraction()}, {"masked_fraction", p.masked_fraction()},
                               {"encoding", photo_encoding_name(entry.encoding)}});
  }
  const auto subsampled = std::count_if(in.cap.images.begin(), in.cap.images.end(),
                                        [](const capture_image& im) { return im.encoding == photo_encoding::jpeg_subsampled; });
  if (subsampled > 0)
    std::fprintf(stderr, "capture: %td of %zu photographs store their colour at a lower resolution than their brightness (JPEG chroma "
                 "subsampling): the colour blur is alike in all of them, so the fit cannot see it; the uncertainty maps allow for it "
                 "(save JPEGs with full-resolution colour where the camera offers it)\n",
                 subsampled, in.cap.images.size());
  if (in.photos.size() < 4)
    std::fprintf(stderr, "capture: warning: %zu photograph%s cannot separate the maps' parameters (the problem is ill-posed: many "
                 "map sets render the same); the method needs about 8 (docs/method.md section 6), at least 4\n",
                 in.photos.size(), in.photos.size() == 1 ? "" : "s");
  const image& first = in.photos[0];
  auto check_size = [&](const material_maps& m, const fs::path& file) {
    if (m.width() != first.width() || m.height() != first.height())
      throw std::invalid_argument(file.string() + ": the maps are " + std::to_string(m.width()) + "x" + std::to_string(m.height()) +
                                  " but the photographs are " + std::to_string(first.width()) + "x" + std::to_string(first.height()));
  };
  if (s.truth) check_size(*(in.truth = read_maps(*s.truth)), *s.truth);
  if (s.init) check_size(*(in.start_maps = read_maps(*s.init)), *s.init);
  in.files = capture_inputs(in.cap, s.capture_file);
  for (const auto& folder : {s.truth, s.init})
    if (folder) {
      const auto files = map_files(*folder);
      in.files.insert(in.files.end(), files.begin(), files.end());
    }
  return in;
}

/// A failed capture leaves nothing but a check-point with completed stages, and says so.
class capture_failure_cleanup {
 public:
  explicit capture_failure_cleanup(fs::path checkpoint) : checkpoint_(std::move(checkpoint)) {}
  capture_failure_cleanup(const capture_failure_cleanup&) = delete;
  capture_failure_cleanup& operator=(const capture_failure_cleanup&) = delete;
  ~capture_failure_cleanup() {
    if (succeeded) return;
    std::error_code ec;
    if (fs::exists(checkpoint_ / "estimate", ec) || fs::exists(checkpoint_ / "finetune", ec))
      std::fprintf(stderr, "capture: failed; the completed stages are kept in %s: after fixing the cause, the same command with "
                   "--resume continues from them\n", checkpoint_.c_str());
    else
      fs::remove_all(checkpoint_, ec);  // then the output lock removes OUT if it made it and it is empty
  }
  bool succeeded = false;

 private:
  fs::path checkpoint_;
};

/// The networks the command's stages run with, and the stages in `o`: "auto" runs the networks
/// where their weights are found (and no --init), else the refine alone (capture_material's own
/// rule); a list given runs those, and needs the weights. Refuses --init with network stages, and
/// a second run asked for by name without them. `stages_text` says what runs.
inline networks choose_networks(const capture_settings& s, capture_options& o, const CLI::App* parsed, std::string& stages_text) {
  const bool explicit_stages = s.stages != "auto";
  if (explicit_stages) o.stages = pipeline_stages::parse(s.stages);
  if (s.init && explicit_stages && o.stages.networks())
    throw std::invalid_argument("--init replaces the network stages: use it with --stages refine");
  networks nets;
  if (!s.init && o.stages.networks())
    nets = explicit_stages || parsed->count("--models") > 0 ? load_program_networks(s.models) : find_program_networks(s.models);
  const bool asked_models = parsed->count("--also-models") > 0;
  const bool asked_residual = parsed->count("--also-residual") > 0 && o.second_run.residual;
  if (nets.empty() && (asked_models || asked_residual))
    throw std::invalid_argument(std::string(asked_models ? "--also-models" : "--also-residual") +
                                " chooses between the network stages' results, and these stages do not run "
                                "(--stages without estimate, encode and fine-tune, --init, or no weights in --models)");
  stages_text = nets.empty() ? "refine" : explicit_stages ? s.stages : "all";
  return nets;
}

/// The fields `Options::visit_fields` lists (finetune_options, refine_options, estimate_options,
/// second_run_options, kernel_options), as a JSON object keyed by their names: report.json's record
/// of the options a capture ran with. A kernel's features are written as kernel_used is.
template <class Options>
nlohmann::json fields_json(const Options& o) {
  nlohmann::json j = nlohmann::json::object();
  Options::visit_fields(o, [&](const char* name, const auto& value) {
    if constexpr (std::is_same_v<std::decay_t<decltype(value)>, brdf_features>)
      j[name] = kernel_analysis{value, 0, 0, 0}.describe();
    else
      j[name] = value;
  });
  return j;
}

/// report.json of a capture (without its timings): inputs, options as run, every stage, the choice
/// between runs, the novel views and, with --truth, the errors.
inline nlohmann::json capture_report(const capture_settings& s, const capture_options& o, const capture_command_inputs& in,
                                     const capture_result& result, const networks& nets, const capture& novel) {
  const bool with_networks = result.networks_ran;
  const std::string kernel_used = kernel_analysis{result.features, 0, 0, 0}.describe();
  nlohmann::json report;
  report["capture"] = fs::absolute(s.capture_file).string();
  report["images"] = in.photos.size();
  report["width"] = in.photos[0].width();
  report["height"] = in.photos[0].height();
  report["kernel"] = o.kernel.auto_tolerance > 0 ? "auto" : kernel_used;
  report["kernel_used"] = kernel_used;
  report["kernel_options"] = fields_json(o.kernel);
  report["f0_source"] = result.f0_source;
  report["precision"] = o.render.double_precision ? "double" : "float";
  report["network_precision"] = nn::to_string(o.network_precision);
  report["exposure_scale"] = result.exposure_scale;
  report["saturation"] = s.photos.saturation;
  report["clipped_excluded"] = s.photos.exclude_clipped;
  report["photos"] = in.photo_report;
  report["threads"] = omp_get_max_threads();
  if (o.ranks && o.ranks->distributed()) report["ranks"] = o.ranks->size();
  report["stages"] = nlohmann::json::array();
  for (const auto& st : result.stages)
    report["stages"].push_back({{"name", st.name}, {"ran", st.ran}, {"resumed", st.resumed}, {"steps", st.steps},
                                {"loss", st.loss}, {"seconds", st.seconds}, {"evaluated_fraction", st.evaluated_fraction},
                                {"restarts", st.restarts}, {"replaced_fraction", st.replaced_fraction},
                                {"restart_replaced_fractions", st.restart_replaced_fractions}});
  const refine_options& refined = with_networks ? o.refine : o.refine_alone;
  report["refine"] = fields_json(refined);
  report["refine"]["neighbour_restarts"] = with_networks ? o.neighbour_restarts : o.neighbour_restarts_alone;
  if (with_networks) {
    report["finetune"] = fields_json(o.finetune);
    report["finetune"]["preset"] = s.models.preset;
  }
  if (with_networks && o.stages.estimate) report["estimate"] = fields_json(o.estimate);
  if (with_networks) report["second_run"] = fields_json(o.second_run);
  report["loss"] = result.loss;
  if (result.choice) {
    const run_choice& c = *result.choice;
    report["models"] = {{"chosen", fs::absolute(c.chosen).string()}, {"loss", c.loss},
                        {"other", fs::absolute(c.other).string()}, {"other_ran", c.other_ran},
                        {"other_loss", c.other_ran ? nlohmann::json(c.other_loss) : nlohmann::json()},
                        {"other_seconds", c.other_seconds}, {"above", o.second_run.above},
                        {"chosen_residual", c.chosen_residual}, {"other_residual", c.other_residual},
                        {"residual_ratio", o.second_run.residual_ratio},
                        {"projection_ratio", std::isfinite(c.projection_ratio) ? nlohmann::json(c.projection_ratio) : nlohmann::json()}};
  }
  report["networks"] = nets.describe();
  if (result.uncertainty) {
    nlohmann::json determined;
    for (int k = 0; k < parameter_count; ++k) determined[parameter_name(k)] = result.uncertainty->determined_share[std::size_t(k)];
    report["uncertainty"] = {{"folder", "uncertainty"}, {"noise", result.uncertainty->noise},
                             {"calibration", photo_encoding_name(result.uncertainty->calibration.value_or(photo_encoding::lossless))},
                             {"determined_ratio", o.uncertainty->determined_ratio}, {"determined_share", determined}};
  }
  report["novel_views"] = nlohmann::json::array();
  for (const auto& v : novel.images)
    report["novel_views"].push_back({{"file", "novel/" + v.file}, {"camera", v.camera}, {"light", v.light}, {"intensity", v.intensity}});
  if (in.truth) {
    report["errors"] = errors_to_json(compare_maps(result.maps, *in.truth));
    report["errors"]["novel_view_image_loss"] = novel_view_error(result.maps, *in.truth, novel);
  }
  return report;
}

/// Every file a capture writes into OUT, after checking --tileable against the photographs' size:
/// the list refuse_overwriting_inputs checks before any work.
inline std::vector<fs::path> capture_output_files(const capture_settings& s, const capture_command_inputs& in) {
  std::vector<fs::path> outputs = map_files(s.out), renders = image_outputs(in.cap, s.out / "renders");
  if (s.tileable) {
    try {
      validate_tileable(in.photos[0].width(), in.photos[0].height(), s.tile);
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("--tileable: " + std::string(e.what()));
    }
    const std::vector<fs::path> tile_files = map_files(s.out / "tileable");
    outputs.insert(outputs.end(), tile_files.begin(), tile_files.end());
  }
  outputs.insert(outputs.end(), renders.begin(), renders.end());
  for (const char* name : {"report.json", "contact_sheet.png"}) outputs.push_back(s.out / name);
  return outputs;
}

/// Prints, after the fit, what the photographs do not tell: F0 held from the networks or the prior,
/// and the parameters undetermined on most texels.
inline void print_undetermined(const capture_result& result, const capture_options& o) {
  if (result.f0_source != "photographs") {
    const std::string held = result.f0_source == "estimate" ? "the networks' estimate"
                                                            : "the prior F0 " + std::to_string(o.kernel.prior_f0).substr(0, 4);
    if (o.kernel.auto_tolerance > 0)
      std::fprintf(stderr, "capture: F0 is not determined by these photographs (each sees the Fresnel factor F / F0 within %g of 1): "
                   "fresnel.exr holds %s; a photograph with the light away from the camera at a low angle measures it\n",
                   o.kernel.auto_tolerance, held.c_str());
    else  // the kernel was chosen by hand, without the Fresnel term
      std::fprintf(stderr, "capture: the kernel has no Fresnel term (--kernel), so F0 was not fitted: fresnel.exr holds %s\n",
                   held.c_str());
  }
  if (!result.uncertainty) return;
  std::vector<std::string> undetermined;
  for (int k = 0; k < parameter_count; ++k)
    if (!result.uncertainty->determined(k)) {
      char text[64];
      std::snprintf(text, sizeof text, "%s (%.0f%% of texels)", parameter_name(k), 100 * result.uncertainty->determined_share[std::size_t(k)]);
      undetermined.emplace_back(text);
    }
  if (!undetermined.empty())
    std::fprintf(stderr, "capture: these photographs determine on most texels every parameter but %s; uncertainty/ holds each "
                 "parameter's standard deviation per texel\n", join_names(undetermined, ", ").c_str());
}

/// What stage_capture_files staged beside the maps.
struct staged_capture {
  std::vector<fs::path> stale_maps;           ///< map files of an earlier capture to remove after the commit
  std::optional<tileable_change> tile_change;  ///< with --tileable: how the tile differs from the maps
  capture novel;                              ///< the novel views rendered into novel/
};

/// Stages every result file of a capture but report.json within `files`: the maps (and the
/// tileable ones), uncertainty/, the viewer, the re-renders, the contact sheet and the novel views.
inline staged_capture stage_capture_files(const capture_settings& s, const capture_command_inputs& in, const capture_result& result,
                                          file_transaction& files) {
  const material_maps& maps = result.maps;  // canonical (capture_material)
  create_output_folder(s.out);
  staged_capture staged;
  // Every file is one job of one batch, run once all are known: the contact sheet (the largest
  // PNG) starts first and the other thread encodes the rest meanwhile.
  job_batch encodes;
  staged.stale_maps = stage_maps(maps, s.out, files, encodes);
  if (s.tileable) {
    const material_maps tile = make_tileable(maps, s.tile);
    staged.tile_change = compare_tile(maps, tile);
    const std::vector<fs::path> stale_tile = stage_maps(tile, s.out / "tileable", files, encodes);
    staged.stale_maps.insert(staged.stale_maps.end(), stale_tile.begin(), stale_tile.end());
  }
  if (result.uncertainty) write_uncertainty(*result.uncertainty, s.out / "uncertainty", files, encodes);
  if (s.view) {
    viewer_options view{s.out.filename().string()};
    const std::optional<material_maps> ratio = result.uncertainty ? std::optional(result.uncertainty->ratio()) : std::nullopt;
    if (ratio) view.uncertainty = &*ratio;
    files.stage(s.out / "material.html", viewer_html(maps, view));
  }
  const auto rerenders = std::make_shared<const std::vector<image>>(render(maps, in.cap));
  stage_images(rerenders, in.cap, s.out / "renders", files, encodes, in.files);
  const fs::path sheet = s.out / "contact_sheet.png";
  const double sheet_cost = 3.0 * double(maps.texel_count()) * double(3 * in.photos.size() + 6);  // photos, renders, maps
  encodes.add([&in, rerenders, &maps, sheet, &files] {
    write_png(make_capture_sheet(in.photos, *rerenders, maps, in.truth ? &*in.truth : nullptr), sheet, files);
  }, sheet_cost);
  staged.novel = novel_view_set(1, maps.width(), maps.height());
  stage_images(std::make_shared<const std::vector<image>>(render(maps, staged.novel)), staged.novel, s.out / "novel", files, encodes);
  encodes.run();
  return staged;
}

/// Runs a capture: writes the map set (canonical, brdf/canonical_maps.hpp), the viewer page
/// (unless `s.view` is off), re-renders, novel views, a contact sheet and report.json into `s.out`;
/// returns the report (empty on ranks other than 0, which share the fit and write nothing).
/// `parsed` is the command (to see which options were given).
inline nlohmann::json run_capture_command(capture_settings s, const CLI::App* parsed) {
  const auto start = std::chrono::steady_clock::now();
  capture_options& o = s.options;
  o.validate();  // impossible options are refused before any work
  const communicator& ranks = program_ranks();
  o.ranks = &ranks;
  if (mpi_job() && o.finetune.shard_cells == 0) o.finetune.shard_cells = finetune_options::distributed_shard_cells;
  const capture_command_inputs in = read_capture_command_inputs(s);
  std::string stages_text;
  if (!ranks.root()) {  // the same capture, sharing the fine-tune's steps; rank 0 writes every output
    const networks nets = choose_networks(s, o, parsed, stages_text);
    o.checkpoint = {s.out / ".checkpoint", s.resume, s.checkpoint_seconds};
    o.uncertainty.reset();  // rank 0's alone is written
    capture_material(in.cap, in.photos, nets, o, in.masks, in.start_maps ? &*in.start_maps : nullptr);
    return {};
  }
  // Outputs stay inside OUT and never replace an input; checked before any work, as is --tileable.
  refuse_overwriting_inputs(capture_output_files(s, in), in.files);
  output_lock lock(s.out);
  capture_failure_cleanup cleanup(s.out / ".checkpoint");
  const double load_seconds = seconds_since(start);

  const networks nets = choose_networks(s, o, parsed, stages_text);
  o.checkpoint = {s.out / ".checkpoint", s.resume, s.checkpoint_seconds};
  o.finetune.progress_every = 25;
  o.refine.progress_every = std::max(1, o.refine.steps / 50);
  o.refine_alone.progress_every = std::max(1, o.refine_alone.steps / 50);
  progress_line progress;
  o.progress = std::ref(progress);
  o.log = print_capture_choice;
  std::fprintf(stderr, "capture: %zu images of %dx%d from %s, stages %s, %d threads\n", in.photos.size(), in.photos[0].width(),
               in.photos[0].height(), s.capture_file.c_str(), stages_text.c_str(), omp_get_max_threads());
  if (ranks.distributed())
    std::fprintf(stderr, "capture: %d processes (MPI ranks), the fine-tune's steps in shards of %d latent cells\n", ranks.size(),
                 o.finetune.shard_cells);
  const capture_result result = capture_material(in.cap, in.photos, nets, o, in.masks, in.start_maps ? &*in.start_maps : nullptr);
  progress.finish();
  if (o.kernel.auto_tolerance > 0)
    std::fprintf(stderr, "capture: kernel auto -> %s\n", kernel_analysis{result.features, 0, 0, 0}.describe().c_str());
  print_undetermined(result, o);

  // Every result file is staged under a temporary name and all are renamed into place together at
  // the end: a failure while producing any of them leaves the folder's earlier results as they were.
  const auto t_write = std::chrono::steady_clock::now();
  file_transaction files;
  const staged_capture staged = stage_capture_files(s, in, result, files);
  const double write_seconds = seconds_since(t_write);
  nlohmann::json report = capture_report(s, o, in, result, nets, staged.novel);
  report["timings"] = {{"load", load_seconds}, {"stages", result.stage_seconds()}, {"write", write_seconds}, {"total", seconds_since(start)}};
  report["peak_memory_bytes"] = peak_resident_bytes();
  if (staged.tile_change) report["tileable"] = tileable_json(*staged.tile_change, s.tile.overlap);
  files.stage(s.out / "report.json", report.dump(2) + "\n");
  files.commit();
  remove_stale_files(staged.stale_maps);
  cleanup.succeeded = true;
  std::error_code ec;
  fs::remove_all(s.out / ".checkpoint", ec);  // finished: nothing left to resume
  print_capture_summary(result, s.out, seconds_since(start), s.view);
  if (staged.tile_change) {
    print_tileable_change(*staged.tile_change);
    std::fprintf(stderr, "  seamless tile       %s/\n", (s.out / "tileable").c_str());
  }
  return report;
}

/// The options of a capture (shared with demo).
inline void add_capture_options(CLI::App* c, capture_settings& s) {
  c->add_option("-o,--out", s.out, "output folder");
  c->add_option(capture_flag("pipeline_stages"), s.stages, "stages to run: auto (all when the weights are there, else refine), all, or a list of estimate,encode,finetune,refine");
  add_model_options(c, s.models);
  c->add_flag(capture_flag("checkpoint_options::resume"), s.resume, "continue a killed run from OUT/.checkpoint");
  c->add_option("--checkpoint-every", s.checkpoint_seconds,
                "seconds between the fine-tune's check-points in OUT/.checkpoint (0: after every step; the estimate is "
                "check-pointed when it is done)")
      ->check(CLI::NonNegativeNumber);
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
  add_tileable_options(c, s->tileable, s->tile, "also write a seamless tile of the maps to OUT/tileable/");
  c->add_flag_callback("--no-uncertainty", [s] { s->options.uncertainty.reset(); },
                       "do not compute the per-texel standard deviations (uncertainty/, report.json's uncertainty)");
  c->callback([s, c] { naming_options(capture_field_flags, [&] { run_on_ranks([&] { run_capture_command(*s, c); }); }); });
}

}  // namespace anisocap::commands
