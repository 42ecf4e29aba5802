#pragma once
// `anisocap plan RESULT`: the next photographs to take for a capture (pipeline/plan.hpp), in
// millimetres around the sample, with a reason in words, and plan.json beside the result.
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/plan.hpp"
#include "anisocap/pipeline/plan_io.hpp"
#include "field_flags.hpp"

namespace anisocap::commands {

struct plan_settings {
  std::filesystem::path result;      ///< a capture's output folder
  std::filesystem::path out;         ///< plan.json (default: RESULT/plan.json)
  double sample_mm = 0;              ///< the sample's longest side in mm (0: print in sample lengths)
  plan_options options;
};

/// A position in capture units as text, in millimetres when the sample's size is known.
inline std::string plan_position(const vec3f& p, double sample_mm) {
  char text[96];
  auto zero = [](double v) { return std::abs(v) < 1e-6 ? 0.0 : v; };  // no "-0"
  const vec3f q{float(zero(p[0])), float(zero(p[1])), float(zero(p[2]))};
  if (sample_mm > 0) std::snprintf(text, sizeof text, "[%.0f, %.0f, %.0f] mm", q[0] * sample_mm + 0.0, q[1] * sample_mm + 0.0, q[2] * sample_mm + 0.0);
  else std::snprintf(text, sizeof text, "[%.2f, %.2f, %.2f] sample lengths", q[0] + 0.0, q[1] + 0.0, q[2] + 0.0);
  return text;
}

/// Runs `plan`: reads the result's maps, report.json and the photographs it was captured from,
/// prints the proposed photographs and writes plan.json.
inline void run_plan_command(const plan_settings& s) {
  namespace fs = std::filesystem;
  s.options.validate();
  const fs::path report_file = s.result / "report.json";
  std::ifstream report_in(report_file);
  if (!report_in) throw io_error(report_file, "cannot read (is " + s.result.string() + " a capture's output folder?)");
  nlohmann::json report;
  try {
    report = nlohmann::json::parse(report_in);
  } catch (const nlohmann::json::exception& e) {
    throw io_error(report_file, std::string("not valid JSON: ") + e.what());
  }
  if (!report.contains("capture") || !report["capture"].is_string() || !report.contains("exposure_scale"))
    throw io_error(report_file, "has no \"capture\" and \"exposure_scale\": not written by anisocap capture");
  photo_options po;
  po.saturation = report.value("saturation", 0.0f);
  po.exclude_clipped = report.value("clipped_excluded", true);
  capture_photographs input = read_capture_photographs(report["capture"].get<std::string>(), po);
  const material_maps maps = read_maps(s.result);
  const std::vector<image> photos = input.pixels();
  if (photos[0].width() != maps.width() || photos[0].height() != maps.height())
    throw std::invalid_argument(s.result.string() + ": the maps' size differs from the photographs' in " + report["capture"].get<std::string>());
  if (report.contains("photos") && report["photos"].size() == input.description.images.size())
    for (std::size_t i = 0; i < input.description.images.size(); ++i)  // the floors the capture used (--floor)
      input.description.images[i].floor = report["photos"][i].value("floor", input.description.images[i].floor);
  const fitted_photographs fitted = fitted_targets(input.description, photos, input.masks(), report["exposure_scale"].get<double>());
  const capture& cap = fitted.configurations;
  const loss_targets& targets = fitted.targets;
  const uncertainty_options uo;
  const double noise = report.contains("uncertainty") ? report["uncertainty"].value("noise", 0.0)
                                                      : std::max(uo.min_noise, residual_rms(maps, cap, targets));
  std::fprintf(stderr, "plan: %zu photographs of %dx%d texels, measurement noise %.4f; weighing candidates\n", photos.size(),
               maps.width(), maps.height(), noise);
  const plan_result plan = plan_photographs(maps, cap, targets, noise > 0 ? noise : uo.min_noise, s.options, uo);

  std::printf("The next %zu photograph%s (positions from the sample's centre: x along its top edge to the right, y towards\n"
              "the top edge, z up; azimuth counter-clockwise from x):\n", plan.photos.size(), plan.photos.size() == 1 ? "" : "s");
  int index = 1;
  for (const planned_photo& p : plan.photos) {
    const plan_candidate& c = p.candidate;
    char distance[48];
    if (s.sample_mm > 0) std::snprintf(distance, sizeof distance, "%.0f mm", c.distance * s.sample_mm);
    else std::snprintf(distance, sizeof distance, "%g sample lengths", c.distance);
    std::printf("%d. %s: camera %s from the centre, %.0f degrees above the sample, at azimuth %.0f degrees, at %s; ", index++,
                c.flash ? "phone with its flash" : "camera and a lamp", distance, c.elevation, c.azimuth,
                plan_position(c.config.camera, s.sample_mm).c_str());
    if (c.flash) std::printf("the flash beside the lens.\n");
    else std::printf("the lamp as far away and as high on the opposite side, at %s.\n", plan_position(c.config.light, s.sample_mm).c_str());
    std::printf("   Why: it %s.\n", p.reason.c_str());
  }
  const fs::path file = s.out.empty() ? s.result / "plan.json" : s.out;
  write_file_atomically(file, plan_to_json(plan, fs::absolute(s.result).string(), s.sample_mm));
  std::fprintf(stderr, "plan: written to %s; add the photographs to photos.json, rectify them with the others and capture again\n",
               file.c_str());
}

/// The plan_options fields `plan` sets by flags.
inline constexpr option_name plan_field_flags[] = {{"plan_options::photos", "--photos"}};

/// Registers `plan`.
inline void add_plan_command(CLI::App& app) {
  auto s = std::make_shared<plan_settings>();
  auto* c = app.add_subcommand("plan", "the next 1-4 photographs that most lower a capture's uncertainty, with the reason");
  c->add_option("result", s->result, "a capture's output folder (its maps, report.json and the photographs it names)")->required();
  c->add_option("-o,--out", s->out, "plan file to write (default: RESULT/plan.json)");
  c->add_option(flag_of(plan_field_flags, "plan_options::photos"), s->options.photos, "how many photographs to propose (1-4)")->capture_default_str()->check(CLI::Range(1, 4));
  c->add_option("--sample-mm", s->sample_mm, "the sample's longest side in mm: positions in millimetres (default: in sample lengths)")
      ->check(CLI::NonNegativeNumber);
  c->add_flag_callback("--flash-only", [s] { s->options.lamp = false; }, "propose only phone-with-flash photographs");
  c->add_flag_callback("--lamp-only", [s] { s->options.flash = false; }, "propose only camera-and-lamp photographs");
  c->callback([s] { naming_options(plan_field_flags, [&] { run_plan_command(*s); }); });
}

}  // namespace anisocap::commands
