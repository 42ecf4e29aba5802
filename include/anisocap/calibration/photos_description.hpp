#pragma once
/// @file
/// `photos.json`, the description of perspective photographs of a flat rectangular sample, all
/// lengths in millimetres:
///
///     {"sample": {"width_mm": 100, "height_mm": 80},
///      "camera": {"focal_length_px": 3000},
///      "photos": [{"file": "IMG_0001.jpg",
///                  "corners": [[x, y], [x, y], [x, y], [x, y]],
///                  "light": {"flash_offset_mm": [dx, dy, dz]},
///                  "intensity": 1.0}]}
///
/// `camera` gives `focal_length_px`, or `focal_length_mm` with `sensor_width_mm`, and optionally
/// `principal_point_px` (default: the image centre); a photo may carry its own `camera` (a zoom).
/// `corners`: pixel coordinates (pixel centres at integers, y down) of the sample's corners in
/// texture order: top-left, top-right, bottom-right, bottom-left; when absent, `rectify` looks for
/// the printed marker frame. `light` is either `flash_offset_mm` (a light fixed to the camera, in
/// camera coordinates: x right, y down, z forward; [0, 0, 0] = co-located) or `position_mm` (in
/// sample coordinates: origin at the centre, x along the top edge to the right, y towards the top
/// edge, z out of the surface). `intensity` (a number or [r, g, b], default 1) is the light's
/// intensity times the exposure in any unit shared by all photos; the albedos come out relative to
/// it. The reader is strict: unknown fields, wrong types and non-finite numbers are errors naming
/// the file and the entry.
#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/calibration/camera.hpp"
#include "anisocap/core/text.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// Where the light of one photograph is: exactly one of the two is set.
struct photo_light {
  std::optional<std::array<double, 3>> flash_offset_mm;  ///< offset from the camera, camera coordinates
  std::optional<std::array<double, 3>> position_mm;      ///< position in sample coordinates
};

/// One photograph of the sample.
struct photo_entry {
  std::string file;                       ///< image file, relative to photos.json's folder
  std::optional<corner_pixels> corners;   ///< the sample's corners in texture order (absent: detect markers)
  photo_light light;                      ///< where the light was
  vec3f intensity{1, 1, 1};               ///< light intensity times exposure, per colour channel
  std::optional<camera_description> camera;  ///< this photo's own camera (default: the shared one)
};

/// The whole description.
struct photos_description {
  double width_mm = 0;            ///< sample width (along its top edge)
  double height_mm = 0;           ///< sample height
  camera_description camera;      ///< the camera shared by all photos
  std::vector<photo_entry> photos;
};

namespace photos_detail {

using json = nlohmann::json;

inline const char* type_name(const json& v) { return v.type_name(); }

/// Reads fields of one JSON object, refusing unknown ones; errors name `where`.
struct object_reader {
  const json& object;
  std::filesystem::path path;
  std::string where;

  [[noreturn]] void fail(const std::string& problem) const { throw io_error(path, where + ": " + problem); }

  void only(std::initializer_list<const char*> keys) const {
    if (!object.is_object()) fail(std::string("expected an object, got ") + type_name(object));
    for (const auto& [key, value] : object.items()) {
      bool known = false;
      for (const char* k : keys) known |= key == k;
      if (!known) fail("unknown field \"" + key + "\" (expected \"" + join_names(keys, "\", \"") + "\")");
    }
  }
  const json* find(const char* key) const {
    const auto it = object.find(key);
    return it == object.end() ? nullptr : &*it;
  }
  double number(const json& v, const std::string& field) const {
    if (!v.is_number()) fail("\"" + field + "\" must be a number, got " + type_name(v));
    const double d = v.get<double>();
    if (!std::isfinite(d)) fail("\"" + field + "\" is not finite");
    return d;
  }
  template <std::size_t N>
  std::array<double, N> numbers(const json& v, const std::string& field) const {
    if (!v.is_array() || v.size() != N) fail("\"" + field + "\" must be an array of " + std::to_string(N) + " numbers");
    std::array<double, N> a{};
    for (std::size_t i = 0; i < N; ++i) a[i] = number(v[i], field);
    return a;
  }
  std::optional<double> optional_number(const char* key) const {
    const json* v = find(key);
    if (!v) return std::nullopt;
    return number(*v, key);
  }
};

inline camera_description parse_camera(const json& v, const std::filesystem::path& path, const std::string& where) {
  const object_reader r{v, path, where};
  r.only({"focal_length_px", "focal_length_mm", "sensor_width_mm", "principal_point_px"});
  camera_description c;
  c.focal_length_px = r.optional_number("focal_length_px");
  c.focal_length_mm = r.optional_number("focal_length_mm");
  c.sensor_width_mm = r.optional_number("sensor_width_mm");
  if (const json* p = r.find("principal_point_px")) c.principal_point_px = r.numbers<2>(*p, "principal_point_px");
  return c;
}

inline json camera_to_json(const camera_description& c) {
  json o = json::object();
  if (c.focal_length_px) o["focal_length_px"] = *c.focal_length_px;
  if (c.focal_length_mm) o["focal_length_mm"] = *c.focal_length_mm;
  if (c.sensor_width_mm) o["sensor_width_mm"] = *c.sensor_width_mm;
  if (c.principal_point_px) o["principal_point_px"] = *c.principal_point_px;
  return o;
}

}  // namespace photos_detail

namespace photos_detail {

/// Parses the JSON text of the file `path`; malformed JSON is an io_error naming it.
inline json parse_file_text(std::string_view text, const std::filesystem::path& path) {
  try {
    return json::parse(text);
  } catch (const json::parse_error& e) {
    throw io_error(path, std::string("malformed JSON: ") + e.what());
  }
}

}  // namespace photos_detail

/// Parses the text of photos.json; `path` names it in errors (io_error). Does not read the images.
inline photos_description parse_photos_description(std::string_view text, const std::filesystem::path& path) {
  using photos_detail::json;
  const json root = photos_detail::parse_file_text(text, path);
  const photos_detail::object_reader top{root, path, "top level"};
  top.only({"sample", "camera", "photos"});
  for (const char* key : {"sample", "camera", "photos"})
    if (!top.find(key)) top.fail(std::string("missing field \"") + key + "\"");
  photos_description d;
  const photos_detail::object_reader sample{*top.find("sample"), path, "sample"};
  sample.only({"width_mm", "height_mm"});
  for (const char* key : {"width_mm", "height_mm"})
    if (!sample.find(key)) sample.fail(std::string("missing field \"") + key + "\"");
  d.width_mm = sample.number(*sample.find("width_mm"), "width_mm");
  d.height_mm = sample.number(*sample.find("height_mm"), "height_mm");
  if (!(d.width_mm > 0 && d.height_mm > 0)) sample.fail("width_mm and height_mm must be positive");
  d.camera = photos_detail::parse_camera(*top.find("camera"), path, "camera");
  const json& list = *top.find("photos");
  if (!list.is_array() || list.empty()) top.fail("\"photos\" must be a non-empty array");
  for (std::size_t i = 0; i < list.size(); ++i) {
    photo_entry e;
    std::string where = "photos[" + std::to_string(i) + "]";
    if (list[i].is_object() && list[i].contains("file") && list[i]["file"].is_string())
      where += " (\"" + list[i]["file"].get<std::string>() + "\")";
    const photos_detail::object_reader r{list[i], path, where};
    r.only({"file", "corners", "light", "intensity", "camera"});
    const json* file = r.find("file");
    if (!file) r.fail("missing field \"file\"");
    if (!file->is_string() || file->get<std::string>().empty()) r.fail("\"file\" must be a non-empty string");
    e.file = file->get<std::string>();
    if (const json* c = r.find("corners")) {
      if (!c->is_array() || c->size() != 4) r.fail("\"corners\" must hold 4 points [x, y] (top-left, top-right, bottom-right, bottom-left)");
      corner_pixels corners;
      for (int k = 0; k < 4; ++k) {
        const auto p = r.numbers<2>((*c)[std::size_t(k)], "corners");
        corners[std::size_t(k)] = {p[0], p[1]};
      }
      e.corners = corners;
    }
    const json* light = r.find("light");
    if (!light) r.fail("missing field \"light\" (give {\"flash_offset_mm\": [0, 0, 0]} for a co-located flash)");
    const photos_detail::object_reader l{*light, path, where + " light"};
    l.only({"flash_offset_mm", "position_mm"});
    if (const json* v = l.find("flash_offset_mm")) e.light.flash_offset_mm = l.numbers<3>(*v, "flash_offset_mm");
    if (const json* v = l.find("position_mm")) e.light.position_mm = l.numbers<3>(*v, "position_mm");
    if (e.light.flash_offset_mm.has_value() == e.light.position_mm.has_value())
      l.fail("give exactly one of \"flash_offset_mm\" and \"position_mm\"");
    if (const json* v = r.find("intensity")) {
      if (v->is_number()) {
        const float f = float(r.number(*v, "intensity"));
        e.intensity = {f, f, f};
      } else {
        const auto a = r.numbers<3>(*v, "intensity");
        e.intensity = {float(a[0]), float(a[1]), float(a[2])};
      }
      for (float f : e.intensity)
        if (!(f > 0 && std::isfinite(f))) r.fail("\"intensity\" must be positive and finite");
    }
    if (const json* c = r.find("camera")) e.camera = photos_detail::parse_camera(*c, path, where + " camera");
    d.photos.push_back(std::move(e));
  }
  return d;
}

/// Reads and checks photos.json (see the file comment); throws io_error naming the file.
inline photos_description read_photos_description(const std::filesystem::path& path) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  return parse_photos_description(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()), path);
}

/// The JSON text of a description (parse_photos_description reads it back unchanged).
inline std::string photos_description_to_json(const photos_description& d) {
  using photos_detail::json;
  json photos = json::array();
  for (const photo_entry& e : d.photos) {
    json o = {{"file", e.file}};
    if (e.corners) {
      json c = json::array();
      for (const auto& p : *e.corners) c.push_back({p.x(), p.y()});
      o["corners"] = c;
    }
    if (e.light.flash_offset_mm) o["light"] = {{"flash_offset_mm", *e.light.flash_offset_mm}};
    else o["light"] = {{"position_mm", *e.light.position_mm}};
    if (e.intensity[0] == e.intensity[1] && e.intensity[1] == e.intensity[2]) o["intensity"] = e.intensity[0];
    else o["intensity"] = e.intensity;
    if (e.camera) o["camera"] = photos_detail::camera_to_json(*e.camera);
    photos.push_back(std::move(o));
  }
  const json root = {{"sample", {{"width_mm", d.width_mm}, {"height_mm", d.height_mm}}},
                     {"camera", photos_detail::camera_to_json(d.camera)},
                     {"photos", std::move(photos)}};
  return root.dump(2) + "\n";
}

}  // namespace anisocap
