#pragma once
/// @file
/// plan.json: the photographs `plan_photographs` proposes, as `anisocap plan` writes them and
/// `anisocap photograph --plan` reads them back (to render the proposed photographs of a
/// synthetic sample, closing the capture-plan-capture loop without a camera).
///
/// The file is one object:
///
///     {"result": "...", "noise": 0.02, "candidates": 130, "sample_mm": 100,
///      "photos": [{"kind": "lamp", "distance": 3, "elevation_degrees": 40, "azimuth_degrees": 180,
///                  "camera": [x, y, z], "light": [x, y, z], "intensity": [r, g, b],
///                  "gain": 0.26, "reason": "...", "camera_mm": [...], "light_mm": [...]}, ...]}
///
/// `camera` and `light` are in capture.json's units (the sample's longest side is 1, its centre
/// the origin, z up); `camera_mm` and `light_mm` (present when sample_mm > 0) the same in
/// millimetres. A "flash" photograph has its light at the camera (a phone's flash).
#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/calibration/photos_description.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/pipeline/plan.hpp"

namespace anisocap {

/// The JSON text of a plan (read_plan_photos reads its photographs back): `result` names the
/// capture folder it was made for, `sample_mm` the sample's longest side (0: unknown, positions
/// in sample lengths only).
inline std::string plan_to_json(const plan_result& plan, const std::string& result, double sample_mm) {
  nlohmann::ordered_json out = {{"result", result}, {"noise", plan.noise}, {"candidates", plan.candidates},
                                {"sample_mm", sample_mm}, {"photos", nlohmann::ordered_json::array()}};
  auto mm = [&](const vec3f& p) { return nlohmann::ordered_json{p[0] * sample_mm, p[1] * sample_mm, p[2] * sample_mm}; };
  for (const planned_photo& p : plan.photos) {
    const plan_candidate& c = p.candidate;
    nlohmann::ordered_json entry = {{"kind", c.flash ? "flash" : "lamp"}, {"distance", c.distance}, {"elevation_degrees", c.elevation},
                                    {"azimuth_degrees", c.azimuth}, {"camera", c.config.camera}, {"light", c.config.light},
                                    {"intensity", c.config.intensity}, {"gain", p.gain}, {"reason", p.reason}};
    if (sample_mm > 0) {
      entry["camera_mm"] = mm(c.config.camera);
      if (!c.flash) entry["light_mm"] = mm(c.config.light);
    }
    out["photos"].push_back(std::move(entry));
  }
  return out.dump(2) + "\n";
}

/// Parses the text of a plan.json (see the file comment); `path` names it in errors (io_error,
/// naming the entry: "photos[1]: ..."). Returns each proposed photograph's kind and configuration
/// (camera, light, intensity); the distance and angles where given. Refuses a plan without
/// photographs, an unknown kind, a camera or light at or below the sample's plane, and a flash
/// photograph whose light is not at its camera.
inline std::vector<plan_candidate> parse_plan_photos(std::string_view text, const std::filesystem::path& path) {
  using photos_detail::json;
  const json root = photos_detail::parse_file_text(text, path);
  const photos_detail::object_reader top{root, path, "top level"};
  if (!root.is_object()) top.fail(std::string("expected an object, got ") + root.type_name());
  const json* list = top.find("photos");
  if (!list || !list->is_array() || list->empty()) top.fail("\"photos\" must be a non-empty array (is this a plan.json of anisocap plan?)");
  std::vector<plan_candidate> out;
  for (std::size_t i = 0; i < list->size(); ++i) {
    const photos_detail::object_reader r{(*list)[i], path, "photos[" + std::to_string(i) + "]"};
    r.only({"kind", "distance", "elevation_degrees", "azimuth_degrees", "camera", "light", "intensity", "gain", "reason", "camera_mm",
            "light_mm"});
    plan_candidate c;
    const json* kind = r.find("kind");
    if (!kind || !kind->is_string() || (*kind != "flash" && *kind != "lamp")) r.fail("\"kind\" must be \"flash\" or \"lamp\"");
    c.flash = *kind == "flash";
    auto point = [&](const char* key) {
      const json* v = r.find(key);
      if (!v) r.fail(std::string("missing field \"") + key + "\"");
      const auto a = r.numbers<3>(*v, key);
      if (!(a[2] > 0)) r.fail(std::string("\"") + key + "\" is at or below the sample's plane (z must be > 0)");
      return vec3f{float(a[0]), float(a[1]), float(a[2])};
    };
    c.config.camera = point("camera");
    c.config.light = point("light");
    if (c.flash && c.config.light != c.config.camera) r.fail("a \"flash\" photograph's \"light\" must be its \"camera\"");
    if (const json* v = r.find("intensity")) {
      const auto a = r.numbers<3>(*v, "intensity");
      for (double f : a)
        if (!(f > 0)) r.fail("\"intensity\" must be positive");
      c.config.intensity = {float(a[0]), float(a[1]), float(a[2])};
    }
    if (const json* v = r.find("distance")) c.distance = r.number(*v, "distance");
    if (const json* v = r.find("elevation_degrees")) c.elevation = r.number(*v, "elevation_degrees");
    if (const json* v = r.find("azimuth_degrees")) c.azimuth = r.number(*v, "azimuth_degrees");
    c.config.file = "planned.exr";
    out.push_back(c);
  }
  return out;
}

/// Reads a plan.json (parse_plan_photos); throws io_error naming the file.
inline std::vector<plan_candidate> read_plan_photos(const std::filesystem::path& path) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  return parse_plan_photos(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()), path);
}

}  // namespace anisocap
