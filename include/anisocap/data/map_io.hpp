#pragma once
/// @file
/// Map sets: a folder of float32 RGB EXR files holding the 12 appearance
/// parameters of docs/method.md section 1, plus sRGB PNG previews beside them.
///
/// | file           | R          | G          | B                      | preview (8-bit PNG)             |
/// |----------------|------------|------------|------------------------|---------------------------------|
/// | `diffuse.exr`  | a_d r      | a_d g      | a_d b                  | sRGB                            |
/// | `specular.exr` | a'_s r     | a'_s g     | a'_s b                 | sRGB                            |
/// | `lobes.exr`    | sigma_x    | sigma_y    | 0                      | values as they are              |
/// | `fresnel.exr`  | F0         | F0         | F0                     | sRGB                            |
/// | `normal.exr`   | n_x        | n_y        | n_z = sqrt(1-n_x²-n_y²)| 0.5 + 0.5 n                     |
/// | `rotation.exr` | alpha (rad)| alpha      | alpha                  | alpha/pi + 0.5                  |
/// | `height.exr`   | H          | H          | H                      | (H - min) / (max - min)         |
///
/// `height.exr` is optional. Readers use R (and G for lobes, R and G for normals; n_z is
/// recomputed). Data previews (lobes, normal, rotation, height) store the mapped value directly
/// as the 8-bit code (no sRGB curve), as normal-map tools do, so a code reads as the value.
///
/// Validation on read and write (errors name the file, the first bad texel and its value):
/// all six required files present, equal sizes, finite values; albedos and F0 in [0,1], lobe
/// widths in (0,1], n_x² + n_y² <= 1, each within `map_tolerance` (values that far outside
/// are clamped; lobe widths below `min_lobe_width` are raised to it; normals slightly longer
/// than 1 are rescaled). alpha is pi-periodic (docs/method.md section 1), so values outside [-pi/2, pi/2] are
/// wrapped modulo pi into that range rather than refused.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/parallel.hpp"
#include "anisocap/core/text.hpp"
#include "anisocap/data/image_io.hpp"

namespace anisocap {

/// How far outside its range a map value may lie (rounding in other tools) before it is an error.
inline constexpr float map_tolerance = 1e-4f;

/// The files of a map set, in the order of the parameter planes they hold; `height.exr` is last
/// and optional.
inline constexpr std::array<std::string_view, 7> map_file_names = {
    "diffuse.exr", "specular.exr", "lobes.exr", "fresnel.exr", "normal.exr", "rotation.exr", "height.exr"};

namespace detail {

inline constexpr double map_pi = 3.14159265358979323846;

/// Which map file holds parameter plane k (for messages).
inline std::string_view map_file_of_plane(int k) {
  if (k <= diffuse_b) return map_file_names[0];
  if (k <= specular_b) return map_file_names[1];
  if (k <= lobe_y) return map_file_names[2];
  if (k == fresnel_f0) return map_file_names[3];
  if (k <= normal_y) return map_file_names[4];
  return map_file_names[5];
}

/// Formats a float for messages.
inline std::string map_number(double v) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

/// Throws io_error about `file` for the first texel `i` (row-major) of a width-wide map.
[[noreturn]] inline void map_value_error(const std::filesystem::path& file, std::size_t i, int width, const char* channel,
                                         double value, const std::string& problem, std::size_t bad) {
  std::string message = "texel (x=" + std::to_string(i % std::size_t(width)) + ", y=" + std::to_string(i / std::size_t(width)) +
                        ") channel " + channel + " = " + map_number(value) + ": " + problem;
  if (bad > 1) message += " (" + std::to_string(bad) + " bad texels in all)";
  throw io_error(file, message);
}

/// Checks and canonicalises one plane in place: finite, within [lo - tol, hi + tol] (then
/// clamped to [clamp_lo, hi]); lo_open makes the lower bound exclusive (lobe widths).
inline void check_plane(float* p, std::size_t n, int width, const std::filesystem::path& file, const char* channel,
                        float lo, float hi, bool lo_open, float clamp_lo, const char* range) {
  std::size_t bad = 0, first = n;
  for (std::size_t i = 0; i < n; ++i) {
    const float v = p[i];
    const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo - map_tolerance) && v <= hi + map_tolerance;
    if (!ok) {
      if (bad++ == 0) first = i;
      continue;
    }
    p[i] = std::clamp(v, clamp_lo, hi);
  }
  if (bad) {
    const float v = p[first];
    map_value_error(file, first, width, channel, v, std::isfinite(v) ? std::string("outside ") + range : "not finite", bad);
  }
}

/// Checks every plane of `maps` (and the height map) and brings values within the tolerance into
/// range, wraps alpha modulo pi; errors name the map file in `dir`.
inline void check_and_canonicalise(material_maps& maps, const std::filesystem::path& dir) {
  const std::size_t n = maps.texel_count();
  const int w = maps.width();
  static constexpr const char* rgb[] = {"R", "G", "B"};
  for (int k = diffuse_r; k <= specular_b; ++k)
    check_plane(maps.plane(k), n, w, dir / map_file_of_plane(k), rgb[k % 3], 0.0f, 1.0f, false, 0.0f, "[0, 1]");
  check_plane(maps.plane(lobe_x), n, w, dir / map_file_names[2], "R (sigma_x)", 0.0f, 1.0f, true, min_lobe_width, "(0, 1]");
  check_plane(maps.plane(lobe_y), n, w, dir / map_file_names[2], "G (sigma_y)", 0.0f, 1.0f, true, min_lobe_width, "(0, 1]");
  check_plane(maps.plane(fresnel_f0), n, w, dir / map_file_names[3], "R (F0)", 0.0f, 1.0f, false, 0.0f, "[0, 1]");
  {  // normals: n_x^2 + n_y^2 <= 1; slightly longer ones are rescaled to unit length (n_z = 0)
    float* x = maps.plane(normal_x);
    float* y = maps.plane(normal_y);
    std::size_t bad = 0, first = n;
    for (std::size_t i = 0; i < n; ++i) {
      const double r2 = double(x[i]) * x[i] + double(y[i]) * y[i];
      if (!std::isfinite(x[i]) || !std::isfinite(y[i]) || r2 > 1.0 + 2.0 * map_tolerance) {
        if (bad++ == 0) first = i;
        continue;
      }
      if (r2 > 1.0) {
        const double s = 1.0 / std::sqrt(r2);
        x[i] = float(x[i] * s), y[i] = float(y[i] * s);
      }
    }
    if (bad) {
      const std::filesystem::path file = dir / map_file_names[4];
      if (!std::isfinite(x[first])) map_value_error(file, first, w, "R (n_x)", x[first], "not finite", bad);
      if (!std::isfinite(y[first])) map_value_error(file, first, w, "G (n_y)", y[first], "not finite", bad);
      map_value_error(file, first, w, "R (n_x)", x[first],
                      "n_x^2 + n_y^2 = " + map_number(double(x[first]) * x[first] + double(y[first]) * y[first]) +
                          " exceeds 1 (not a unit normal)",
                      bad);
    }
  }
  {  // alpha is pi-periodic: wrap into [-pi/2, pi/2]
    // Bounds are pi/2 rounded to float, so that float(+-pi/2) itself is kept, not flipped in sign.
    constexpr float half_pi = float(map_pi / 2);
    float* a = maps.plane(rotation);
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(a[i])) map_value_error(dir / map_file_names[5], i, w, "R (alpha)", a[i], "not finite", 1);
      if (a[i] < -half_pi || a[i] > half_pi) {
        const double wrapped = double(a[i]) - map_pi * std::round(double(a[i]) / map_pi);
        a[i] = std::clamp(float(wrapped), -half_pi, half_pi);
      }
    }
  }
  if (maps.has_height()) {
    const float* h = maps.height_map();
    for (std::size_t i = 0; i < n; ++i)
      if (!std::isfinite(h[i])) map_value_error(dir / map_file_names[6], i, w, "R (height)", h[i], "not finite", 1);
  }
}

/// Checks that every pixel of one read file is finite (channels the reader ignores included,
/// since a NaN anywhere means a broken file).
inline void check_finite_file(const image& img, const std::filesystem::path& file) {
  static constexpr const char* rgb[] = {"R", "G", "B"};
  for (int c = 0; c < img.channels(); ++c) {
    const float* p = img.plane(c);
    for (std::size_t i = 0; i < img.pixel_count(); ++i)
      if (!std::isfinite(p[i])) map_value_error(file, i, img.width(), rgb[c % 3], p[i], "not finite", 1);
  }
}

/// The seven images (the last only with a height map) of a map set, in map_file_names order.
inline std::vector<image> map_images(const material_maps& m) {
  const int w = m.width(), h = m.height();
  const std::size_t n = m.texel_count();
  std::vector<image> out;
  auto planes3 = [&](const float* r, const float* g, const float* b) {
    image img(w, h, 3);
    std::copy(r, r + n, img.plane(0));
    std::copy(g, g + n, img.plane(1));
    if (b) std::copy(b, b + n, img.plane(2));  // else stays 0
    return img;
  };
  out.push_back(planes3(m.plane(diffuse_r), m.plane(diffuse_g), m.plane(diffuse_b)));
  out.push_back(planes3(m.plane(specular_r), m.plane(specular_g), m.plane(specular_b)));
  out.push_back(planes3(m.plane(lobe_x), m.plane(lobe_y), nullptr));
  out.push_back(planes3(m.plane(fresnel_f0), m.plane(fresnel_f0), m.plane(fresnel_f0)));
  image normal = planes3(m.plane(normal_x), m.plane(normal_y), nullptr);
  for (std::size_t i = 0; i < n; ++i) {
    const float x = normal.plane(0)[i], y = normal.plane(1)[i];
    normal.plane(2)[i] = std::sqrt(std::max(0.0f, 1.0f - x * x - y * y));
  }
  out.push_back(std::move(normal));
  out.push_back(planes3(m.plane(rotation), m.plane(rotation), m.plane(rotation)));
  if (m.has_height()) out.push_back(planes3(m.height_map(), m.height_map(), m.height_map()));
  return out;
}

/// The preview of map file `index` (see the table in the file comment) and its encoding.
inline image map_preview(const image& img, std::size_t index, png_encoding& encoding) {
  encoding = index == 0 || index == 1 || index == 3 ? png_encoding::srgb : png_encoding::linear;
  if (index <= 3) return img;
  image p(img.width(), img.height(), 3);
  const std::size_t n = img.pixel_count();
  float lo = 0, hi = 0;
  if (index == 6) {
    lo = *std::min_element(img.plane(0), img.plane(0) + n);
    hi = *std::max_element(img.plane(0), img.plane(0) + n);
  }
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < n; ++i) {
      const float v = img.plane(c)[i];
      float& q = p.plane(c)[i];
      if (index == 4) q = 0.5f + 0.5f * v;
      else if (index == 5) q = float(v / map_pi + 0.5);
      else q = hi > lo ? (v - lo) / (hi - lo) : 0.5f;
    }
  return p;
}

/// "diffuse.exr" -> "diffuse.png".
inline std::filesystem::path preview_name(const std::filesystem::path& dir, std::string_view exr_name) {
  return dir / std::filesystem::path(exr_name).replace_extension(".png");
}

}  // namespace detail

/// Reads and validates the map set in folder `dir` (see the file comment for files, ranges and
/// what is wrapped or clamped). Throws io_error naming the folder or the offending file.
inline material_maps read_maps(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_directory(dir, ec)) throw io_error(dir, "map set folder not found");
  std::vector<std::string_view> missing;
  for (std::size_t f = 0; f < 6; ++f)
    if (!std::filesystem::exists(dir / map_file_names[f], ec)) missing.push_back(map_file_names[f]);
  if (!missing.empty())
    throw io_error(dir, "map set is missing " + join_names(missing, ", ") +
                            " (needed: diffuse, specular, lobes, fresnel, normal, rotation .exr; height.exr optional)");
  const bool has_height = std::filesystem::exists(dir / map_file_names[6], ec);
  std::vector<image> images;
  for (std::size_t f = 0; f < (has_height ? 7u : 6u); ++f) {
    const std::filesystem::path file = dir / map_file_names[f];
    images.push_back(read_exr(file));
    if (images.back().width() != images[0].width() || images.back().height() != images[0].height())
      throw io_error(file, "size " + std::to_string(images.back().width()) + "x" + std::to_string(images.back().height()) +
                               " differs from diffuse.exr (" + std::to_string(images[0].width()) + "x" +
                               std::to_string(images[0].height()) + "); all maps of a set must have the same size");
    detail::check_finite_file(images.back(), file);
  }
  material_maps m(images[0].width(), images[0].height());
  const std::size_t n = m.texel_count();
  auto copy = [&](const image& img, int channel, float* dst) { std::copy(img.plane(channel), img.plane(channel) + n, dst); };
  for (int c = 0; c < 3; ++c) copy(images[0], c, m.plane(diffuse_r + c));
  for (int c = 0; c < 3; ++c) copy(images[1], c, m.plane(specular_r + c));
  copy(images[2], 0, m.plane(lobe_x));
  copy(images[2], 1, m.plane(lobe_y));
  copy(images[3], 0, m.plane(fresnel_f0));
  copy(images[4], 0, m.plane(normal_x));
  copy(images[4], 1, m.plane(normal_y));
  {  // a normal pointing into the material is not a shading normal of a surface seen from above
    const float* z = images[4].plane(2);
    for (std::size_t i = 0; i < n; ++i)
      if (z[i] < -map_tolerance)
        detail::map_value_error(dir / map_file_names[4], i, m.width(), "B (n_z)", z[i], "normal points below the surface", 1);
  }
  copy(images[5], 0, m.plane(rotation));
  if (has_height) {
    m.enable_height_map();
    copy(images[6], 0, m.height_map());
  }
  detail::check_and_canonicalise(m, dir);
  return m;
}

/// The staging half of write_maps: validates `maps` (as read_maps does, with the same clamping and
/// wrapping), creates `dir` and adds to `encodes` the jobs that stage the set's EXRs (and PNG
/// previews when `previews`) into `transaction`; they hold their own copy of the maps, and
/// `transaction` must live until `encodes` has run. Returns the files of an earlier set in `dir`
/// that the new set makes stale (a height.exr the new set lacks, previews when `previews` is
/// false): remove them with remove_stale_files once the transaction is committed.
inline std::vector<std::filesystem::path> stage_maps(const material_maps& maps, const std::filesystem::path& dir,
                                                     file_transaction& transaction, job_batch& encodes, bool previews = true) {
  if (maps.texel_count() == 0) throw io_error(dir, "cannot write an empty map set");
  material_maps canonical = maps;
  detail::check_and_canonicalise(canonical, dir);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir, ec)) throw io_error(dir, "cannot create the map set folder");
  const auto images = std::make_shared<const std::vector<image>>(detail::map_images(canonical));
  file_transaction* files = &transaction;
  for (std::size_t f = 0; f < images->size(); ++f) {  // each file encoded on a thread of its own
    const double cost = double((*images)[f].pixel_count()) * (*images)[f].channels();
    encodes.add([images, f, dir, files] { write_exr((*images)[f], dir / map_file_names[f], *files); }, cost);
    if (previews)
      encodes.add([images, f, dir, files] {
        png_encoding encoding;
        const image preview = detail::map_preview((*images)[f], f, encoding);
        write_png(preview, detail::preview_name(dir, map_file_names[f]), *files, 0.0f, encoding);
      }, cost);
  }
  std::vector<std::filesystem::path> stale;
  if (!canonical.has_height()) {
    stale.push_back(dir / map_file_names[6]);
    stale.push_back(detail::preview_name(dir, map_file_names[6]));
  }
  if (!previews)
    for (std::size_t f = 0; f < 6; ++f) stale.push_back(detail::preview_name(dir, map_file_names[f]));
  return stale;
}

/// stage_maps with the files encoded and staged before it returns, on every thread.
inline std::vector<std::filesystem::path> stage_maps(const material_maps& maps, const std::filesystem::path& dir,
                                                     file_transaction& transaction, bool previews = true) {
  job_batch encodes;
  std::vector<std::filesystem::path> stale = stage_maps(maps, dir, transaction, encodes, previews);
  encodes.run();
  return stale;
}

/// Removes those of `files` that exist; io_error naming the first that cannot be removed.
inline void remove_stale_files(const std::vector<std::filesystem::path>& files) {
  for (const auto& file : files) {
    std::error_code ec;
    std::filesystem::remove(file, ec);
    if (ec) throw io_error(file, "cannot remove the stale file of an earlier map set: " + ec.message());
  }
}

/// Writes `maps` as a map set into folder `dir` (created if needed), with PNG previews beside the
/// EXRs when `previews` (stage_maps). Every file is written under a temporary name before any is
/// renamed into place, so an error leaves an existing set untouched. A stale height.exr (and stale
/// previews when `previews` is false) from an earlier set is removed so the folder holds one
/// consistent set.
inline void write_maps(const material_maps& maps, const std::filesystem::path& dir, bool previews = true) {
  file_transaction transaction;
  const std::vector<std::filesystem::path> stale = stage_maps(maps, dir, transaction, previews);
  transaction.commit();
  remove_stale_files(stale);
}

}  // namespace anisocap
