#pragma once
/// @file
/// A contact sheet: one PNG a person can look at to judge a capture. Rows of labelled thumbnails:
/// the input photographs, their re-renders from the estimated maps, the differences, and the maps
/// side by side (estimate, and the truth when known).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/data/image_io.hpp"

#ifndef ANISOCAP_STB_EASY_FONT_INCLUDED
#define ANISOCAP_STB_EASY_FONT_INCLUDED
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#endif
#include <stb/stb_easy_font.h>
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif
#endif

namespace anisocap {

/// One labelled tile of a contact sheet: a 3-channel image already in display units (linear,
/// displayed through sRGB after clamping to [0, 1]).
struct sheet_tile {
  image picture;
  std::string label;
};

namespace detail {

/// Box-filtered (minification) or nearest (magnification) resize of a 3-channel image to w x h.
inline image resize_for_sheet(const image& src, int w, int h) {
  image out(w, h, 3);
  const double sx = double(src.width()) / w, sy = double(src.height()) / h;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int x0 = int(x * sx), x1 = std::max(x0 + 1, int((x + 1) * sx));
      const int y0 = int(y * sy), y1 = std::max(y0 + 1, int((y + 1) * sy));
      for (int c = 0; c < 3; ++c) {
        double s = 0;
        for (int yy = y0; yy < std::min(y1, src.height()); ++yy)
          for (int xx = x0; xx < std::min(x1, src.width()); ++xx) s += src.at(std::min(c, src.channels() - 1), xx, yy);
        out.at(c, x, y) = float(s / double((std::min(y1, src.height()) - y0) * (std::min(x1, src.width()) - x0)));
      }
    }
  return out;
}

/// Draws `text` with stb_easy_font (a tiny built-in bitmap font) at (x, y), white, in linear units.
inline void draw_label(image& img, int x, int y, const std::string& text) {
  std::vector<char> buffer(text.size() * 300 + 64);
  std::string copy = text;
  const int quads = stb_easy_font_print(float(x), float(y), copy.data(), nullptr, buffer.data(), int(buffer.size()));
  struct vertex { float x, y, z; unsigned char c[4]; };
  const auto* v = reinterpret_cast<const vertex*>(buffer.data());
  for (int q = 0; q < quads; ++q) {
    const int qx0 = int(v[4 * q].x), qy0 = int(v[4 * q].y), qx1 = int(v[4 * q + 2].x), qy1 = int(v[4 * q + 2].y);
    for (int yy = std::max(qy0, 0); yy < std::min(qy1, img.height()); ++yy)
      for (int xx = std::max(qx0, 0); xx < std::min(qx1, img.width()); ++xx)
        for (int c = 0; c < 3; ++c) img.at(c, xx, yy) = 1.0f;
  }
}

}  // namespace detail

/// Lays out rows of tiles (each row left to right) with labels above every tile; tiles are scaled
/// to `tile_size` pixels on their longest side. Returns the sheet in linear display units.
inline image make_contact_sheet(const std::vector<std::vector<sheet_tile>>& rows, int tile_size = 160) {
  const int label_h = 12, gap = 4;
  int columns = 0;
  int tile_w = tile_size, tile_h = tile_size;
  for (const auto& r : rows) {
    columns = std::max(columns, int(r.size()));
    for (const auto& t : r)
      if (!t.picture.empty()) {
        const double aspect = double(t.picture.width()) / t.picture.height();
        tile_w = aspect >= 1 ? tile_size : std::max(1, int(std::lround(tile_size * aspect)));
        tile_h = aspect >= 1 ? std::max(1, int(std::lround(tile_size / aspect))) : tile_size;
      }
  }
  if (columns == 0) throw std::invalid_argument("make_contact_sheet: nothing to show");
  const int cell_w = tile_w + gap, cell_h = tile_h + label_h + gap;
  image sheet(columns * cell_w + gap, int(rows.size()) * cell_h + gap, 3);
  for (int c = 0; c < 3; ++c) std::fill(sheet.plane(c), sheet.plane(c) + sheet.pixel_count(), 0.02f);
  for (std::size_t r = 0; r < rows.size(); ++r)
    for (std::size_t k = 0; k < rows[r].size(); ++k) {
      const sheet_tile& t = rows[r][k];
      const int ox = gap + int(k) * cell_w, oy = gap + int(r) * cell_h;
      detail::draw_label(sheet, ox, oy + 1, t.label);
      if (t.picture.empty()) continue;
      const image small = detail::resize_for_sheet(t.picture, tile_w, tile_h);
      for (int c = 0; c < 3; ++c)
        for (int y = 0; y < tile_h; ++y)
          for (int x = 0; x < tile_w; ++x) sheet.at(c, ox + x, oy + label_h + y) = small.at(c, x, y);
    }
  return sheet;
}

/// The maps of a map set as displayable tiles: diffuse, specular (a'_s), lobes (R = sx, G = sy),
/// F0, normal (0.5 + 0.5 n), rotation (alpha / pi + 0.5, grey).
inline std::vector<sheet_tile> map_tiles(const material_maps& m, const std::string& prefix) {
  const int w = m.width(), h = m.height();
  std::vector<sheet_tile> tiles;
  auto make = [&](const std::string& name, auto&& f) {
    image img(w, h, 3);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        float rgb[3];
        f(x, y, rgb);
        for (int c = 0; c < 3; ++c) img.at(c, x, y) = rgb[c];
      }
    tiles.push_back({std::move(img), prefix + name});
  };
  // Maps are shown as data: their values go to the PNG after sRGB encoding, so linearise first to
  // keep the displayed code value equal to the map value.
  auto lin = [](float v) { return float(srgb_to_linear(std::clamp(double(v), 0.0, 1.0))); };
  make("diffuse", [&](int x, int y, float* o) { for (int c = 0; c < 3; ++c) o[c] = m.at(diffuse_r + c, x, y); });
  make("specular", [&](int x, int y, float* o) { for (int c = 0; c < 3; ++c) o[c] = m.at(specular_r + c, x, y); });
  make("lobes", [&](int x, int y, float* o) { o[0] = lin(m.at(lobe_x, x, y)); o[1] = lin(m.at(lobe_y, x, y)); o[2] = 0; });
  make("F0", [&](int x, int y, float* o) { o[0] = o[1] = o[2] = lin(m.at(fresnel_f0, x, y)); });
  make("normal", [&](int x, int y, float* o) {
    const float nx = m.at(normal_x, x, y), ny = m.at(normal_y, x, y);
    const float nz = std::sqrt(std::max(0.0f, 1 - nx * nx - ny * ny));
    o[0] = lin(0.5f + 0.5f * nx); o[1] = lin(0.5f + 0.5f * ny); o[2] = lin(0.5f + 0.5f * nz);
  });
  make("rotation", [&](int x, int y, float* o) { o[0] = o[1] = o[2] = lin(m.at(rotation, x, y) / std::numbers::pi_v<float> + 0.5f); });
  return tiles;
}

/// Scale that maps the 99th percentile of the images' values to 1 (display exposure).
inline float display_scale(const std::vector<image>& images) {
  std::vector<float> v;
  for (const auto& im : images)
    for (int c = 0; c < im.channels(); ++c)
      for (std::size_t i = 0; i < im.pixel_count(); i += 7) v.push_back(im.plane(c)[i]);
  if (v.empty()) return 1.0f;
  const std::size_t k = v.size() * 99 / 100;
  std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(k), v.end());
  return v[k] > 0 ? 1.0f / v[k] : 1.0f;
}

/// The capture contact sheet: inputs, re-renders, |difference| x 4, estimated maps, and the true
/// maps when given.
inline image make_capture_sheet(const std::vector<image>& inputs, const std::vector<image>& renders, const material_maps& estimate,
                                const material_maps* truth = nullptr, int tile_size = 160) {
  const float scale = display_scale(inputs);
  auto scaled = [&](const image& im, float s) {
    image out(im.width(), im.height(), 3);
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < im.pixel_count(); ++i) out.plane(c)[i] = im.plane(c)[i] * s;
    return out;
  };
  std::vector<std::vector<sheet_tile>> rows(3);
  for (std::size_t i = 0; i < inputs.size(); ++i) {
    rows[0].push_back({scaled(inputs[i], scale), "input " + std::to_string(i)});
    rows[1].push_back({scaled(renders[i], scale), "re-render " + std::to_string(i)});
    image d(inputs[i].width(), inputs[i].height(), 3);
    for (int c = 0; c < 3; ++c)
      for (std::size_t p = 0; p < d.pixel_count(); ++p) d.plane(c)[p] = 4 * scale * std::abs(inputs[i].plane(c)[p] - renders[i].plane(c)[p]);
    rows[2].push_back({std::move(d), "|diff| x4 " + std::to_string(i)});
  }
  rows.push_back(map_tiles(estimate, "estimate "));
  if (truth) rows.push_back(map_tiles(*truth, "truth "));
  return make_contact_sheet(rows, tile_size);
}

/// make_capture_sheet written as an sRGB PNG (atomically).
inline void write_capture_sheet(const std::filesystem::path& path, const std::vector<image>& inputs,
                                const std::vector<image>& renders, const material_maps& estimate,
                                const material_maps* truth = nullptr, int tile_size = 160) {
  write_png(make_capture_sheet(inputs, renders, estimate, truth, tile_size), path);
}

}  // namespace anisocap
