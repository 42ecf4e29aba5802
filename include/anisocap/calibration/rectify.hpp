#pragma once
/// @file
/// From perspective photographs of a flat rectangular sample to a capture in texture space
/// (docs/method.md section 4): each photo's camera pose from the sample's corners
/// (calibration/camera.hpp), each photo resampled onto the texture grid, camera and light
/// positions converted to the capture's units (the sample's longest side, origin at its centre, z
/// out of the surface), and a per-image mask of texels the loss must ignore (seen outside the
/// photo, or covering clipped pixels), weighted by how sharply the photo saw each texel.
///
/// Texel (x, y) of a w x h texture (longest side n) covers the sample square whose centre is
/// `texel_position(x, y, w, h)` times the sample's longest side in mm (render/capture.hpp), so the
/// texture's rows run from the sample's top edge (largest y) down, exactly as the renderer places
/// them. Resampling integrates each texel's footprint: s_u x s_v sample points spread over the
/// texel, as many per axis as the texel spans photo pixels along that axis, each read with
/// bilinear interpolation of the linear photo. A photo with more pixels than the texture is thus
/// area-averaged (no aliasing), one with fewer is interpolated.
///
/// A sensor reports no negative light, so where the sample is black its pixels are noise clipped
/// at 0, and their area average is biased up (by sigma / sqrt(2 pi) for noise of standard
/// deviation sigma); the fit reads that as diffuse albedo, which shows on polished metals
/// photographed under a separate light (black but for the highlight). The median of the pixels the
/// samples lie in is not biased so for a texel that is uniform at the texture's scale, but it
/// picks one side of structure finer than a texel (aliasing). `footprint_statistic::automatic`,
/// the default, takes per channel the median where the area average is at most `dark_level`
/// (there the clipped noise dominates, and the two differ by about `dark_level` at most) and the area
/// average elsewhere (studies/README.md, "Rectified photographs, step by step", measures all three).
///
/// A photo pixel near a texel's border also records its neighbour (the pixel's own area and the
/// bilinear reading reach about 1.5 pixels), so the footprint is shrunk by `margin_px` photo pixels
/// on each side, down to the texel's centre. Texels spanning few photo pixels cannot avoid their
/// neighbours, and their rectified values stray further from the texel's own the fewer pixels
/// they span: each texel gets a confidence in (0, 1], (d / `full_confidence_px`)^2 capped at 1,
/// with d the photo pixels across the texel along its narrower axis. The confidence is the texel's
/// weight in the image loss (written as the mask, render/renderer.hpp's loss_targets): a grazing
/// photo's far half, seen at less than a pixel per texel, still counts, but less. The defaults
/// are measured by studies/rectify_residuals.cpp (studies/README.md).
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "anisocap/calibration/camera.hpp"
#include "anisocap/calibration/photos_description.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// How a texel's footprint samples combine into its value.
enum class footprint_statistic {
  mean,    ///< the mean of bilinear readings: the footprint's area average
  median,  ///< per channel, the median of the pixels the samples lie in: robust to sensor noise clipped at black
  automatic,  ///< per channel, the median where the mean is at most resampling_options::dark_level, else the mean
};

/// How rectify_photo reads a texel's footprint from the photo (see the file comment).
struct resampling_options {
  int max_samples_per_axis = 16;  ///< cap on a texel's footprint samples per axis (keeps grazing views bounded)
  double margin_px = 1;           ///< photo pixels left out along each side of the footprint
  double full_confidence_px = 2.5;  ///< photo pixels across a texel's narrower axis that earn full confidence (0: always 1)
  footprint_statistic statistic = footprint_statistic::automatic;  ///< how a footprint's samples become the texel's value
  double dark_level = 0.01;       ///< automatic: the linear level (photo units, 1 = the format's white) up to which the median is used
};

/// Options of rectify.
struct rectify_options {
  int resolution = 0;         ///< texels along the sample's longest side (0: what the photos support, supported_resolution)
  resampling_options resampling;  ///< how each texel's footprint is read
  float saturation = 0;       ///< values at or above this linear level are clipped (0: only the format's largest code)
  /// The floor written into capture.json for every photo (capture_image::floor; linear, in the
  /// photo's values, 1 = an 8/16-bit format's white; 0: none): the level below which a photo's
  /// values are sensor noise rather than measurements. Where a sample is dark, its pixels are noise
  /// clipped at black, whose mean lies above the truth; JPEG compression smooths that noise so
  /// that even the footprint's median does. The L1 fit follows the sign of every such pixel and
  /// reads the bias as lobe tails: sigma and a'_s of metals lit by a separate light suffered most.
  float floor = 0.005f;
  pose_options pose;          ///< pose refinement
  /// Called after each photo is rectified with (photos done, photos in all, that photo's report).
  std::function<void(std::size_t, std::size_t, const std::string&)> progress;
};

/// One rectified photograph.
struct rectified_photo {
  image radiance;          ///< 3-channel linear texture-space image (0 outside the photo; clipped texels keep their clipped values, for the estimator)
  image mask;              ///< 1-channel: 1 = use, 0 = ignore (outside the photo or clipped)
  image confidence;        ///< 1-channel: the texel's confidence in (0, 1] from its sampling density (0 where masked)
  pinhole_camera camera;   ///< the photo's intrinsics
  planar_pose pose;        ///< sample -> camera
  double outside_fraction = 0;  ///< texels not fully inside the photo
  double clipped_fraction = 0;  ///< texels covering clipped pixels
  /// Texels inside the photo that span less than one photo pixel along their narrower side (the
  /// far rows of a grazing view): the photo does not resolve them, so their values are blurred
  /// and their confidence low. A share of a few tens of per cent asks for a closer or sharper photo,
  /// or a lower resolution.
  double underresolved_fraction = 0;
};

/// All photographs in texture space and the capture that describes them.
struct rectified_capture {
  capture configurations;              ///< camera, light, intensity and mask per image (rectified_NN.exr, mask_NN.png)
  std::vector<rectified_photo> photos; ///< one per photograph, in the description's order
  int width = 0, height = 0;           ///< texture size
};

/// The texture size for a longest side of `resolution` texels: the other side keeps the sample's
/// aspect ratio (rounded, at least 1).
inline std::array<int, 2> texture_size(double width_mm, double height_mm, int resolution) {
  if (width_mm >= height_mm) return {resolution, std::max(1, int(std::lround(resolution * height_mm / width_mm)))};
  return {std::max(1, int(std::lround(resolution * width_mm / height_mm))), resolution};
}

/// Sample position in mm of the continuous texture coordinate (u, v) (texel (x, y) spans
/// [x, x+1) x [y, y+1)), consistent with texel_position: longest side n texels = longest_mm.
inline Eigen::Vector3d texture_to_sample(double u, double v, int width, int height, double longest_mm) {
  const double n = std::max(width, height);
  return {(u - 0.5 * width) / n * longest_mm, (0.5 * height - v) / n * longest_mm, 0.0};
}

/// The resolution a photo supports: the sample's longest side in texels such that one texel
/// covers about one photo pixel, from the area of the sample's image: sqrt(area * L^2 / (W H)).
inline double supported_resolution(const pinhole_camera& camera, const planar_pose& pose, double width_mm, double height_mm) {
  const auto corners = sample_corners(width_mm, height_mm);
  double area = 0;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d a = project(camera, pose, corners[std::size_t(i)]), b = project(camera, pose, corners[std::size_t((i + 1) % 4)]);
    area += a.x() * b.y() - a.y() * b.x();
  }
  const double longest = std::max(width_mm, height_mm);
  return std::sqrt(std::abs(0.5 * area) * longest * longest / (width_mm * height_mm));
}

namespace detail {
/// The median of `v` (the mean of the two middle values for an even count); reorders `v`.
inline double median_of(std::vector<float>& v) {
  const std::size_t m = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(m), v.end());
  if (v.size() % 2 == 1) return v[m];
  return 0.5 * (double(v[m]) + double(*std::max_element(v.begin(), v.begin() + std::ptrdiff_t(m))));
}

/// A texel's footprint in the photo: its extent in pixels along u and v, half the sampled extent in
/// texels once the margin is left out, and the samples per axis.
struct texel_footprint {
  double pu = 0, pv = 0, hu = 0, hv = 0;
  int su = 1, sv = 1;
};

/// The footprint of texel (x, y), `to_pixel(u, v)` mapping texture coordinates to pixels.
template <class ToPixel>
texel_footprint footprint_of(const ToPixel& to_pixel, int x, int y, const resampling_options& resampling) {
  texel_footprint f;
  // The texel's extent in pixels along u and v (finite differences across the texel).
  const Eigen::Vector2d du = to_pixel(x + 1.0, y + 0.5) - to_pixel(x, y + 0.5);
  const Eigen::Vector2d dv = to_pixel(x + 0.5, y + 1.0) - to_pixel(x + 0.5, y);
  f.pu = du.norm(), f.pv = dv.norm();
  f.hu = std::max(0.0, 0.5 - resampling.margin_px / std::max(f.pu, 1e-9));
  f.hv = std::max(0.0, 0.5 - resampling.margin_px / std::max(f.pv, 1e-9));
  f.su = std::clamp(int(std::ceil(2 * f.hu * f.pu)), 1, resampling.max_samples_per_axis);
  f.sv = std::clamp(int(std::ceil(2 * f.hv * f.pv)), 1, resampling.max_samples_per_axis);
  return f;
}

/// One footprint sample at pixel position p (inside the photo): adds its bilinear reading to `raw`
/// and its reading over usable pixels (their weights renormalised) to `sum`, and where `median`
/// the nearest pixel's values to `values`. Sets `clip` when the pixel it lies in is unusable or
/// none of its neighbours is usable.
inline void add_footprint_sample(const image& photo, const image& usable, const Eigen::Vector2d& p, bool median, double (&raw)[3],
                                 double (&sum)[3], std::vector<float> (&values)[3], bool& clip) {
  const int pw = photo.width(), ph = photo.height();
  const int x0 = std::min(int(p.x()), pw - 2 < 0 ? 0 : pw - 2), y0 = std::min(int(p.y()), ph - 2 < 0 ? 0 : ph - 2);
  const int x1 = std::min(x0 + 1, pw - 1), y1 = std::min(y0 + 1, ph - 1);
  const double fx = p.x() - x0, fy = p.y() - y0;
  const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
  const std::size_t k[4] = {std::size_t(y0) * pw + x0, std::size_t(y0) * pw + x1, std::size_t(y1) * pw + x0, std::size_t(y1) * pw + x1};
  // The sample is clipped when the pixel it lies in is; its neighbours' clipped values are left out
  // of the bilinear reading (the weights of the usable ones renormalised).
  const std::size_t nearest = std::size_t(std::lround(p.y())) * pw + std::size_t(std::lround(p.x()));
  if (!usable.empty() && usable.plane(0)[nearest] == 0.0f) clip = true;
  double kept = 0, part[3] = {0, 0, 0};
  for (int t = 0; t < 4; ++t) {
    if (w[t] <= 0) continue;
    const bool ok = usable.empty() || usable.plane(0)[k[t]] != 0.0f;
    for (int c = 0; c < 3; ++c) {
      raw[c] += w[t] * photo.plane(c)[k[t]];
      if (ok) part[c] += w[t] * photo.plane(c)[k[t]];
    }
    if (ok) kept += w[t];
  }
  if (kept > 0) {
    for (int c = 0; c < 3; ++c) sum[c] += part[c] / kept;
    if (median)  // a clipped nearest pixel has set `clip`: the texel is left out, its median unused
      for (int c = 0; c < 3; ++c) values[c].push_back(photo.plane(c)[nearest]);
  } else {
    clip = true;
  }
}
}  // namespace detail

/// Resamples one linear photo onto a width x height texture of a sample whose longest side is
/// `longest_mm` (see the file comment). Texels with any footprint sample outside the photo get
/// mask 0 and radiance 0. A footprint sample lying in a pixel whose `usable` mask (1 channel, 0 =
/// clipped or excluded) is 0 gives its texel mask 0; such texels keep their resampled values (the
/// loss ignores them, and the estimation network, which sees whole images, sees a bright highlight
/// there rather than a black hole). The other texels' bilinear readings leave unusable neighbours
/// out (the usable ones' weights renormalised), so a clipped pixel reaches no used texel and masks
/// only the texels whose footprint it covers. An empty `usable` image uses every pixel.
inline rectified_photo rectify_photo(const image& photo, const image& usable, const pinhole_camera& camera,
                                     const planar_pose& pose, int width, int height, double longest_mm,
                                     const resampling_options& resampling = {}) {
  rectified_photo out;
  out.camera = camera;
  out.pose = pose;
  out.radiance = image(width, height, 3);
  out.mask = image(width, height, 1);
  out.confidence = image(width, height, 1);
  // The homography from sample (X, Y, 1) in mm to homogeneous pixels: K [r1 r2 t].
  Eigen::Matrix3d h;
  h.col(0) = pose.rotation.col(0);
  h.col(1) = pose.rotation.col(1);
  h.col(2) = pose.translation;
  h = camera.matrix() * h;
  const int pw = photo.width(), ph = photo.height();
  auto to_pixel = [&](double u, double v) {
    const Eigen::Vector3d s = texture_to_sample(u, v, width, height, longest_mm);
    const Eigen::Vector3d q = h * Eigen::Vector3d(s.x(), s.y(), 1.0);
    return Eigen::Vector2d(q.x() / q.z(), q.y() / q.z());
  };
  std::size_t outside = 0, clipped_count = 0, underresolved = 0;
  const bool median = resampling.statistic != footprint_statistic::mean;
  const bool always_median = resampling.statistic == footprint_statistic::median;
#pragma omp parallel for schedule(dynamic, 4) reduction(+ : outside, clipped_count, underresolved)
  for (int y = 0; y < height; ++y) {
    std::vector<float> values[3];  // the median's samples per channel, reused along the row
    for (int x = 0; x < width; ++x) {
      const detail::texel_footprint f = detail::footprint_of(to_pixel, x, y, resampling);
      const int su = f.su, sv = f.sv;
      const double full = resampling.full_confidence_px;
      const double narrow = full > 0 ? std::min(1.0, std::min(f.pu, f.pv) / full) : 1.0;
      const double confidence = narrow * narrow;
      double sum[3] = {0, 0, 0}, raw[3] = {0, 0, 0};
      bool inside = true, clip = false;
      for (auto& v : values) v.clear();
      for (int j = 0; j < sv && inside; ++j)
        for (int i = 0; i < su && inside; ++i) {
          const Eigen::Vector2d p = to_pixel(x + 0.5 + f.hu * (2.0 * (i + 0.5) / su - 1.0), y + 0.5 + f.hv * (2.0 * (j + 0.5) / sv - 1.0));
          if (!(p.x() >= 0 && p.y() >= 0 && p.x() <= pw - 1 && p.y() <= ph - 1)) {
            inside = false;
            break;
          }
          detail::add_footprint_sample(photo, usable, p, median, raw, sum, values, clip);
        }
      if (median && inside && !clip)
        for (int c = 0; c < 3; ++c)
          if (always_median || sum[c] <= resampling.dark_level * (su * sv)) sum[c] = detail::median_of(values[c]) * (su * sv);
      const std::size_t index = std::size_t(y) * width + x;
      const bool use = inside && !clip;
      if (!inside) ++outside;
      else if (clip) ++clipped_count;
      if (inside && std::min(f.pu, f.pv) < 1.0) ++underresolved;
      out.mask.plane(0)[index] = use ? 1.0f : 0.0f;
      out.confidence.plane(0)[index] = use ? float(confidence) : 0.0f;
      for (int c = 0; c < 3; ++c) out.radiance.plane(c)[index] = !inside ? 0.0f : float((use ? sum[c] : raw[c]) / (su * sv));
    }
  }
  const double texels = double(width) * height;
  out.outside_fraction = double(outside) / texels;
  out.clipped_fraction = double(clipped_count) / texels;
  out.underresolved_fraction = double(underresolved) / texels;
  return out;
}

/// The light position of `entry`, in sample coordinates (mm), for a camera at `pose`.
inline Eigen::Vector3d light_position(const photo_entry& entry, const planar_pose& pose) {
  if (entry.light.position_mm) {
    const auto& p = *entry.light.position_mm;
    return {p[0], p[1], p[2]};
  }
  const auto& o = *entry.light.flash_offset_mm;
  return pose.to_sample(Eigen::Vector3d(o[0], o[1], o[2]));
}

/// The file name of rectified image i (rectified_00.exr, ...) and of its mask (mask_00.png, ...).
inline std::string rectified_file_name(std::size_t i, const char* stem = "rectified", const char* ext = ".exr") {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%s_%02zu%s", stem, i, ext);
  return buffer;
}

/// Finds corners for photos that give none; set by calibration/markers.hpp when it is included.
using corner_finder = std::function<corner_pixels(const photo&, const photos_description&, const std::string& photo_name)>;

/// Rectifies every photo of `description` (files relative to `base_dir`). A photo without corners
/// needs `find_corners` (e.g. the marker detector), else it is an error naming it. Throws
/// calibration_error or io_error naming the photo and the problem.
inline rectified_capture rectify(const photos_description& description, const std::filesystem::path& base_dir,
                                 const rectify_options& options = {}, const corner_finder& find_corners = {}) {
  if (options.resolution < 0) throw std::invalid_argument("rectify: resolution must be >= 0 (0: what the photos support)");
  if (!(options.floor >= 0 && std::isfinite(options.floor))) throw std::invalid_argument("rectify: the floor must be a finite number >= 0");
  if (description.photos.empty()) throw std::invalid_argument("rectify: no photos");
  struct prepared {
    photo picture;
    pinhole_camera camera;
    planar_pose pose;
  };
  std::vector<prepared> all;
  std::vector<double> supported;
  for (std::size_t i = 0; i < description.photos.size(); ++i) {
    const photo_entry& e = description.photos[i];
    const std::string name = "photos[" + std::to_string(i) + "] (" + e.file + ")";
    prepared p;
    photo_options po;
    po.saturation = options.saturation;
    p.picture = read_photo(base_dir / e.file, po);
    p.camera = make_camera(e.camera ? *e.camera : description.camera, p.picture.pixels.width(), p.picture.pixels.height(), name);
    corner_pixels corners;
    if (e.corners) corners = *e.corners;
    else if (find_corners) corners = find_corners(p.picture, description, name);
    else throw calibration_error(name, "no \"corners\" given (and no marker detection available)");
    p.pose = estimate_pose(p.camera, corners, description.width_mm, description.height_mm, name, options.pose);
    if (!(light_position(e, p.pose).z() > 0))
      throw calibration_error(name, "the light is at or below the sample's surface (z <= 0 in sample coordinates); check \"light\"");
    supported.push_back(supported_resolution(p.camera, p.pose, description.width_mm, description.height_mm));
    all.push_back(std::move(p));
  }
  int resolution = options.resolution;
  if (resolution == 0) {
    std::vector<double> s = supported;
    std::nth_element(s.begin(), s.begin() + std::ptrdiff_t(s.size() / 2), s.end());
    resolution = std::clamp(int(std::lround(s[s.size() / 2])), 16, 4096);
  }
  const auto [width, height] = texture_size(description.width_mm, description.height_mm, resolution);
  const double longest = std::max(description.width_mm, description.height_mm);
  rectified_capture result;
  result.width = width;
  result.height = height;
  for (std::size_t i = 0; i < all.size(); ++i) {
    const photo_entry& e = description.photos[i];
    rectified_photo r = rectify_photo(all[i].picture.pixels, all[i].picture.mask, all[i].camera, all[i].pose, width, height,
                                      longest, options.resampling);
    const Eigen::Vector3d camera = all[i].pose.camera_centre() / longest;
    const Eigen::Vector3d light = light_position(e, all[i].pose) / longest;
    capture_image im;
    im.file = rectified_file_name(i);
    im.camera = {float(camera.x()), float(camera.y()), float(camera.z())};
    im.light = {float(light.x()), float(light.y()), float(light.z())};
    im.intensity = e.intensity;
    im.mask = rectified_file_name(i, "mask", ".png");
    im.floor = options.floor;
    im.encoding = all[i].picture.encoding;  // the source's JPEG error stays in the resampled values
    result.configurations.images.push_back(im);
    if (options.progress) {
      char line[256];
      std::snprintf(line, sizeof line,
                    "%s: camera (%.3f, %.3f, %.3f), light (%.3f, %.3f, %.3f), %.1f%% outside the photo, %.1f%% clipped, "
                    "%.1f%% under one photo pixel",
                    e.file.c_str(), camera.x(), camera.y(), camera.z(), light.x(), light.y(), light.z(), 100 * r.outside_fraction,
                    100 * r.clipped_fraction, 100 * r.underresolved_fraction);
      options.progress(i + 1, all.size(), line);
    }
    result.photos.push_back(std::move(r));
  }
  return result;
}

/// The mask file's values of a rectified photo: its confidence where the mask uses the texel, at
/// least 1/255 so that 8 bits keep every used texel; 0 where it is ignored.
inline image mask_weights(const rectified_photo& r) {
  image m(r.mask.width(), r.mask.height(), 1);
  for (std::size_t k = 0; k < m.pixel_count(); ++k)
    m.plane(0)[k] = r.mask.plane(0)[k] == 0.0f ? 0.0f : std::clamp(r.confidence.plane(0)[k], 1.0f / 255.0f, 1.0f);
  return m;
}

/// Writes the rectified images (linear EXR), their masks (8-bit PNG, linear codes: 0 = ignore, else
/// the texel's weight in the loss, 255 = 1; mask_weights) and capture.json into `out` (created if
/// needed), all or nothing.
inline void write_rectified_capture(const rectified_capture& r, const std::filesystem::path& out) {
  std::filesystem::create_directories(out);
  file_transaction files;
  for (std::size_t i = 0; i < r.photos.size(); ++i) {
    write_exr(r.photos[i].radiance, out / r.configurations.images[i].file, files);
    write_png(mask_weights(r.photos[i]), out / r.configurations.images[i].mask, files, 0.0f, png_encoding::linear);
  }
  files.stage(out / "capture.json", capture_to_json(r.configurations, out / "capture.json"));
  files.commit();
}

}  // namespace anisocap
