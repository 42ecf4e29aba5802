#pragma once
/// @file
/// `capture.json`, the description of a capture:
///
///     {"images": [{"file": "input_00.exr", "camera": [x, y, z], "light": [x, y, z], "intensity": 1.0}, ...]}
///
/// `intensity` is a number or [r, g, b]. Optional per image: `"mask": "mask_00.png"` (a PNG or EXR,
/// one channel or RGB, of the photograph's size, relative to this file: pixels zero in every
/// channel are left out of the loss), `"exposure": 2.0` (the photograph's linear values are
/// multiplied by it; data/photo_io.hpp reads both) and `"floor": 0.005` (the level, in the file's
/// own linear values, below which they are not measurements, such as a JPEG's darkest codes: the
/// image loss counts the photograph and the render as at least floor x exposure; render/renderer.hpp,
/// loss_targets) and `"encoding": "jpeg"` (how the photograph's file, or the one it was rectified
/// from, stored its values: "lossless", "eight_bit", "jpeg" or "jpeg_subsampled",
/// core/photo_encoding.hpp; it chooses the per-texel deviations' calibration, pipeline/uncertainty.hpp).
/// Positions are in units of the material's longest side, origin at its centre, z up, the
/// material in the plane z = 0 (docs/method.md section 4). The reader is strict so that a typo
/// cannot silently change an experiment: unknown fields, missing fields, wrong types, non-finite
/// numbers, cameras that cannot see the material, non-positive intensities and repeated files are
/// errors, each reported once with the file, the image index and the problem.
#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/core/image.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/core/text.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

namespace detail {

/// Describes image `index` for messages: `images[3] ("input_03.exr")`.
inline std::string capture_entry_name(std::size_t index, const std::string& file) {
  std::string s = "images[" + std::to_string(index) + "]";
  if (!file.empty()) s += " (\"" + file + "\")";
  return s;
}

/// Checks one image's configuration; throws io_error about `path` naming the entry and the problem.
inline void check_capture_image(const capture_image& im, std::size_t index, const std::filesystem::path& path) {
  const std::string where = capture_entry_name(index, im.file);
  auto fail = [&](const std::string& problem) { throw io_error(path, where + ": " + problem); };
  if (im.file.empty()) fail("\"file\" is empty");
  if (!is_readable_image(im.file)) fail(std::string("\"file\" must name an image of a supported type: ") + readable_image_types);
  if (!im.mask.empty() && !is_readable_image(im.mask)) fail(std::string("\"mask\" must name an image of a supported type: ") + readable_image_types);
  if (!(std::isfinite(im.exposure) && im.exposure > 0)) fail("exposure must be a positive finite number (got " + std::to_string(im.exposure) + ")");
  if (!(std::isfinite(im.floor) && im.floor >= 0)) fail("floor must be a finite number >= 0 (got " + std::to_string(im.floor) + ")");
  static constexpr const char* axis[] = {"x", "y", "z"};
  for (int k = 0; k < 3; ++k) {
    if (!std::isfinite(im.camera[k])) fail(std::string("camera ") + axis[k] + " is not finite");
    if (!std::isfinite(im.light[k])) fail(std::string("light ") + axis[k] + " is not finite");
    if (!std::isfinite(im.intensity[k])) fail("intensity is not finite");
    if (!(im.intensity[k] > 0)) fail("intensity must be > 0 (got " + std::to_string(im.intensity[k]) + ")");
  }
  if (!(im.camera[2] > 0))
    fail("camera z = " + std::to_string(im.camera[2]) +
         " is at or below the material plane z = 0; the camera must see the material from above");
  // A light below the plane lights nothing (max(0, n.l)), so its photograph says nothing about the
  // material; one in the plane sits on a texel (a singular 1/r^2) or grazes every texel.
  if (!(im.light[2] > 0))
    fail("light z = " + std::to_string(im.light[2]) +
         " is at or below the material plane z = 0; the light must shine on the material from above");
}

/// The fields every entry of "images" has, and those it may have.
inline constexpr std::array<const char*, 4> entry_fields = {"file", "camera", "light", "intensity"};
inline constexpr std::array<const char*, 4> optional_entry_fields = {"mask", "exposure", "floor", "encoding"};

/// Checks every image and that no file is used twice.
inline void check_capture(const capture& c, const std::filesystem::path& path) {
  if (c.images.empty()) throw io_error(path, "\"images\" is empty; a capture needs at least one image");
  for (std::size_t i = 0; i < c.images.size(); ++i) check_capture_image(c.images[i], i, path);
  for (std::size_t i = 0; i < c.images.size(); ++i) {
    const auto a = std::filesystem::path(c.images[i].file).lexically_normal();
    for (std::size_t j = 0; j < i; ++j) {
      if (std::filesystem::path(c.images[j].file).lexically_normal() == a)
        throw io_error(path, capture_entry_name(i, c.images[i].file) + ": duplicate file, already used by images[" +
                                 std::to_string(j) + "]");
    }
  }
}

/// A float as the shortest decimal that reads back to the same float, so files show 0.1, not
/// 0.100000001490116, and whole numbers without a decimal point.
inline json float_to_json(float f) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, f);
  double d = 0;
  std::from_chars(buf, r.ptr, d);
  if (d == std::trunc(d) && std::abs(d) < 1e15 && !std::signbit(d)) return json(std::int64_t(d));  // 1, not 1.0
  return json(d);
}

}  // namespace detail

/// Parses the text of a capture description; `path` names it in errors (io_error, or json_error
/// with line and column for malformed JSON). Does not read the images.
inline capture parse_capture(std::string_view text, const std::filesystem::path& path) {
  const json root = parse_json(text, path.string());
  if (!root.is_object()) throw io_error(path, std::string("expected a JSON object at the top, got ") + json_kind_name(root));
  for (const auto& [key, v] : root.items())
    if (key != "images") throw io_error(path, "unknown field \"" + key + "\" at the top level (expected only \"images\")");
  if (!root.contains("images")) throw io_error(path, "missing field \"images\"");
  const json& list = root.at("images");
  if (!list.is_array()) throw io_error(path, std::string("\"images\" must be an array, got ") + json_kind_name(list));
  capture result;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const json& o = list[i];
    if (!o.is_object()) throw io_error(path, detail::capture_entry_name(i, "") + ": expected an object, got " + json_kind_name(o));
    capture_image im;
    if (o.contains("file") && o.at("file").is_string()) im.file = o.at("file").get<std::string>();
    const std::string where = detail::capture_entry_name(i, im.file);
    auto fail = [&](const std::string& problem) { throw io_error(path, where + ": " + problem); };
    for (const auto& [key, v] : o.items())
      if (std::ranges::find(detail::entry_fields, key) == detail::entry_fields.end() &&
          std::ranges::find(detail::optional_entry_fields, key) == detail::optional_entry_fields.end())
        fail("unknown field \"" + key + "\" (expected \"" + join_names(detail::entry_fields, "\", \"") + "\", optional \"" +
             join_names(detail::optional_entry_fields, "\", \"") + "\")");
    for (const char* key : detail::entry_fields)
      if (!o.contains(key)) fail(std::string("missing field \"") + key + "\"");
    if (!o.at("file").is_string()) fail(std::string("\"file\" must be a string, got ") + json_kind_name(o.at("file")));
    // One number as a float, refusing values that do not fit (they would become infinite).
    auto to_float = [&](const json& v, const std::string& field) {
      if (!v.is_number()) fail("\"" + field + "\" must hold numbers, got " + json_kind_name(v));
      const float f = float(v.get<double>());
      if (!std::isfinite(f)) fail("\"" + field + "\" value " + v.dump() + " is not finite as a 32-bit float");
      return f;
    };
    auto to_vec3 = [&](const json& a, const std::string& field) {
      if (!a.is_array()) fail("\"" + field + "\" must be an array [x, y, z], got " + json_kind_name(a));
      if (a.size() != 3) fail("\"" + field + "\" must have 3 elements, got " + std::to_string(a.size()));
      return vec3f{to_float(a[0], field), to_float(a[1], field), to_float(a[2], field)};
    };
    im.camera = to_vec3(o.at("camera"), "camera");
    im.light = to_vec3(o.at("light"), "light");
    const json& intensity = o.at("intensity");
    if (intensity.is_number()) {
      const float f = to_float(intensity, "intensity");
      im.intensity = {f, f, f};
    } else if (intensity.is_array()) {
      im.intensity = to_vec3(intensity, "intensity");
    } else {
      fail(std::string("\"intensity\" must be a number or [r, g, b], got ") + json_kind_name(intensity));
    }
    if (o.contains("mask")) {
      const json& mask = o.at("mask");
      if (!mask.is_string() || mask.get<std::string>().empty()) fail("\"mask\" must be a non-empty file name");
      im.mask = mask.get<std::string>();
    }
    if (o.contains("exposure")) im.exposure = to_float(o.at("exposure"), "exposure");
    if (o.contains("floor")) im.floor = to_float(o.at("floor"), "floor");
    if (o.contains("encoding")) {
      const json& v = o.at("encoding");
      const std::optional<photo_encoding> e = v.is_string() ? photo_encoding_from_name(v.get<std::string>()) : std::nullopt;
      if (!e) fail("\"encoding\" must be " + photo_encoding_choices('"') + ", got " + v.dump());
      im.encoding = *e;
    }
    detail::check_capture_image(im, i, path);
    result.images.push_back(std::move(im));
  }
  detail::check_capture(result, path);
  return result;
}

/// Reads and validates `capture.json` (see the file comment); throws an error naming the file.
inline capture read_capture(const std::filesystem::path& path) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  return parse_capture(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()), path);
}

/// The JSON text of a capture (2-space indentation; intensity as one number when r = g = b).
/// Validates first, so a written file always reads back; throws io_error naming `path`.
inline std::string capture_to_json(const capture& c, const std::filesystem::path& path = "capture.json") {
  detail::check_capture(c, path);
  json images = json::array();
  for (const capture_image& im : c.images) {
    auto vec = [](const vec3f& v) { return json::array({detail::float_to_json(v[0]), detail::float_to_json(v[1]), detail::float_to_json(v[2])}); };
    const bool grey = im.intensity[0] == im.intensity[1] && im.intensity[1] == im.intensity[2];
    json entry = json::object();
    entry["file"] = im.file;
    entry["camera"] = vec(im.camera);
    entry["light"] = vec(im.light);
    entry["intensity"] = grey ? detail::float_to_json(im.intensity[0]) : vec(im.intensity);
    if (!im.mask.empty()) entry["mask"] = im.mask;
    if (im.exposure != 1.0f) entry["exposure"] = detail::float_to_json(im.exposure);
    if (im.floor != 0.0f) entry["floor"] = detail::float_to_json(im.floor);
    if (im.encoding != photo_encoding::lossless) entry["encoding"] = photo_encoding_name(im.encoding);
    images.push_back(std::move(entry));
  }
  json root = json::object();
  root["images"] = std::move(images);
  return root.dump(2) + "\n";
}

/// Writes `capture.json` atomically (temporary file, then rename); validates first.
inline void write_capture(const capture& c, const std::filesystem::path& path) {
  write_file_atomically(path, capture_to_json(c, path));
}

}  // namespace anisocap
