#pragma once
/// @file
/// A printable frame of AprilTag markers (family tag36h11) around the sample, and the sample's
/// corners found from the tags detected in a photograph (Debian's libapriltag: link `apriltag`).
///
/// The frame is a sheet with a window the size of the sample; the tags sit around the window at
/// known positions in sample coordinates (mm, origin at the window's centre, x along the top edge,
/// y towards the top edge). Each detected tag gives its centre in the photo; the homography from
/// the tags' known centres to their detected centres (direct linear transform over all tags, at
/// least four) maps the window's corners into the photo. The sample must fill the window and lie
/// in the sheet's plane; the window's top edge is the sample's top edge.
#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "anisocap/calibration/camera.hpp"
#include "anisocap/calibration/photos_description.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/data/photo_io.hpp"

namespace anisocap {

/// One tag of the frame.
struct frame_marker {
  int id = 0;                        ///< tag36h11 id
  Eigen::Vector2d centre{0, 0};      ///< centre in sample coordinates (mm)
};

/// The layout of a marker frame around a width x height (mm) sample.
struct marker_frame {
  double width_mm = 0, height_mm = 0;  ///< the window (the sample)
  double tag_mm = 0;                   ///< side of a tag's black square
  double gap_mm = 0;                   ///< from the window's edge to the tags' white border
  std::vector<frame_marker> markers;   ///< the tags, ids 0, 1, ... clockwise from the top-left

  /// Half the sheet's width and height (mm): window, gap, tag with its white border, and a margin.
  Eigen::Vector2d half_sheet() const {
    const double reach = gap_mm + tag_mm * 10.0 / 8.0 + tag_mm * 0.5;
    return {0.5 * width_mm + reach, 0.5 * height_mm + reach};
  }
};

/// Options of make_marker_frame.
struct marker_frame_options {
  double tag_mm = 0;   ///< tag side (0: a fifth of the sample's shorter side, 8 to 30 mm)
  double gap_mm = 3;   ///< gap between the window and the tags
};

/// Tags around the window: along each edge, as many as fit at 1.5 tag sides apart, corners included.
inline marker_frame make_marker_frame(double width_mm, double height_mm, const marker_frame_options& o = {}) {
  if (!(width_mm > 0 && height_mm > 0)) throw std::invalid_argument("marker frame: the sample's size must be positive");
  marker_frame f;
  f.width_mm = width_mm;
  f.height_mm = height_mm;
  f.tag_mm = o.tag_mm > 0 ? o.tag_mm : std::clamp(std::min(width_mm, height_mm) / 5, 8.0, 30.0);
  f.gap_mm = o.gap_mm;
  // Tag centres on a rectangle around the window, one white-border cell plus the gap out.
  const double out = f.gap_mm + f.tag_mm * 0.5 + f.tag_mm / 8.0;
  const double hx = 0.5 * width_mm + out, hy = 0.5 * height_mm + out;
  const double pitch = 1.5 * f.tag_mm * 10.0 / 8.0;
  auto edge = [&](Eigen::Vector2d a, Eigen::Vector2d b) {  // from a towards b, without b
    const int count = std::max(1, int(std::floor((b - a).norm() / pitch)));
    for (int i = 0; i < count; ++i) f.markers.push_back({int(f.markers.size()), a + (b - a) * (double(i) / count)});
  };
  const Eigen::Vector2d tl(-hx, hy), tr(hx, hy), br(hx, -hy), bl(-hx, -hy);
  edge(tl, tr);
  edge(tr, br);
  edge(br, bl);
  edge(bl, tl);
  if (int(f.markers.size()) > 587) throw std::invalid_argument("marker frame: more tags than tag36h11 holds; use a larger tag size");
  return f;
}

namespace marker_detail {

/// The tag36h11 family, owned.
struct family {
  apriltag_family_t* tags = tag36h11_create();
  ~family() { tag36h11_destroy(tags); }
  family() = default;
  family(const family&) = delete;
  family& operator=(const family&) = delete;
};

}  // namespace marker_detail

/// The printed sheet at `dots_per_mm` (e.g. 300 dpi: 300 / 25.4) as a 1-channel albedo image:
/// white paper, black tags, the window mid-grey with a thin black outline (cut along its inside).
inline image draw_marker_frame(const marker_frame& f, double dots_per_mm) {
  const Eigen::Vector2d half = f.half_sheet();
  const int w = int(std::ceil(2 * half.x() * dots_per_mm)), h = int(std::ceil(2 * half.y() * dots_per_mm));
  if (w < 1 || h < 1 || double(w) * h > 4e8) throw std::invalid_argument("marker frame: impossible sheet size in pixels");
  marker_detail::family fam;
  image sheet(w, h, 1);
  std::fill_n(sheet.plane(0), sheet.pixel_count(), 1.0f);
  const double cell = f.tag_mm / fam.tags->width_at_border;
  const int cells = fam.tags->total_width;
  for (const frame_marker& m : f.markers) {
    std::unique_ptr<image_u8_t, void (*)(image_u8_t*)> tag(apriltag_to_image(fam.tags, m.id), &image_u8_destroy);
    // The tag image, cells x cells, centred on m.centre; its rows run down the sheet (-y).
    const double x0 = m.centre.x() - 0.5 * cells * cell, y0 = m.centre.y() + 0.5 * cells * cell;
    const int px0 = int(std::floor((x0 + half.x()) * dots_per_mm)), px1 = int(std::ceil((x0 + cells * cell + half.x()) * dots_per_mm));
    const int py0 = int(std::floor((half.y() - y0) * dots_per_mm)), py1 = int(std::ceil((half.y() - y0 + cells * cell) * dots_per_mm));
    for (int py = std::max(0, py0); py < std::min(h, py1); ++py)
      for (int px = std::max(0, px0); px < std::min(w, px1); ++px) {
        const double sx = (px + 0.5) / dots_per_mm - half.x(), sy = half.y() - (py + 0.5) / dots_per_mm;
        const int cx = int(std::floor((sx - x0) / cell)), cy = int(std::floor((y0 - sy) / cell));
        if (cx < 0 || cy < 0 || cx >= cells || cy >= cells) continue;
        sheet.at(0, px, py) = tag->buf[cy * tag->stride + cx] > 127 ? 1.0f : 0.0f;
      }
  }
  const double line = std::max(0.3, 1.5 / dots_per_mm);  // the window's outline, at least 0.3 mm
  for (int py = 0; py < h; ++py)
    for (int px = 0; px < w; ++px) {
      const double sx = std::abs((px + 0.5) / dots_per_mm - half.x()), sy = std::abs(half.y() - (py + 0.5) / dots_per_mm);
      if (sx <= 0.5 * f.width_mm && sy <= 0.5 * f.height_mm)
        sheet.at(0, px, py) = (sx > 0.5 * f.width_mm - line || sy > 0.5 * f.height_mm - line) ? 0.0f : 0.5f;
    }
  return sheet;
}

/// Finds the sample's corners in `picture` from the frame's tags (see the file comment); throws
/// calibration_error naming `photo_name` when fewer than four of the frame's tags are found.
inline corner_pixels find_corners_from_markers(const photo& picture, const marker_frame& f, const std::string& photo_name) {
  const image& p = picture.pixels;
  std::vector<std::uint8_t> grey(std::size_t(p.width()) * p.height());
  float peak = 0;
  for (std::size_t i = 0; i < p.pixel_count(); ++i) peak = std::max(peak, p.plane(1)[i]);
  const float scale = peak > 0 ? 1.0f / peak : 1.0f;
  for (std::size_t i = 0; i < p.pixel_count(); ++i) {
    const double v = std::clamp(double(p.plane(0)[i] + p.plane(1)[i] + p.plane(2)[i]) / 3 * scale, 0.0, 1.0);
    grey[i] = static_cast<std::uint8_t>(std::lround(255 * std::pow(v, 1 / 2.2)));
  }
  image_u8_t im{p.width(), p.height(), p.width(), grey.data()};
  marker_detail::family fam;
  std::unique_ptr<apriltag_detector_t, void (*)(apriltag_detector_t*)> detector(apriltag_detector_create(), &apriltag_detector_destroy);
  apriltag_detector_add_family(detector.get(), fam.tags);
  detector->quad_decimate = 1.0f;
  detector->nthreads = 1;
  zarray_t* found = apriltag_detector_detect(detector.get(), &im);
  std::vector<Eigen::Vector2d> known, seen;
  for (int i = 0; i < zarray_size(found); ++i) {
    apriltag_detection_t* d = nullptr;
    zarray_get(found, i, &d);
    if (d->hamming > 1 || d->id < 0 || d->id >= int(f.markers.size())) continue;
    known.push_back(f.markers[std::size_t(d->id)].centre);
    seen.emplace_back(d->c[0], d->c[1]);
  }
  apriltag_detections_destroy(found);
  if (known.size() < 4)
    throw calibration_error(photo_name, "found " + std::to_string(known.size()) + " of the frame's " + std::to_string(f.markers.size()) +
                                            " markers, need at least 4: give \"corners\", or photograph the whole frame sharply");
  const Eigen::Matrix3d hm = homography_dlt(known, seen);
  corner_pixels corners;
  const auto points = sample_corners(f.width_mm, f.height_mm);
  for (int k = 0; k < 4; ++k) corners[std::size_t(k)] = (hm * Eigen::Vector3d(points[std::size_t(k)].x(), points[std::size_t(k)].y(), 1)).hnormalized();
  return corners;
}

}  // namespace anisocap
