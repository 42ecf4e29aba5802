#pragma once
/// @file
/// Seamless tiles from a captured map set, for texturing surfaces larger than the sample.
///
/// Method: overlap cross-fade, one axis at a time. For an overlap of b texels along x the tile is
/// W - b texels wide; its first b columns blend column x of the maps (weight w = (x + 0.5) / b) with
/// column x + W - b (weight 1 - w), the rest are the maps' own columns. Across the wrap edge the
/// tile's last column W - b - 1 meets its first, which is (to within the weight 1/(2b)) the maps'
/// column W - b: neighbours in the capture, so the wrap is as smooth as the interior. Then the same
/// along y. Every map is blended with the same weights, in the space where blending is meaningful:
///   - albedos, F0 and the height map: per value;
///   - the lobe (sigma_x, sigma_y, alpha): log sigma_x and log sigma_y per value, and the direction
///     as the vector (log sigma_x - log sigma_y)(cos 2 alpha, sin 2 alpha) (the anisotropic part of
///     the lobe's log-tensor), whose angle halved is the blended rotation: a rotation near +pi/2
///     meets one near -pi/2 as the same direction, not through 0, and a nearly isotropic lobe
///     has little say in the direction;
///   - the normal: its slopes (n_x / n_z, n_y / n_z), normalised again after blending.
/// The overlap is searched around the requested one (from half to one and a half times it): the
/// one whose blended columns (rows) differ least, in each value's units of standard deviation. On a
/// periodic pattern (a weave) that is a multiple of the period, so threads are blended with threads
/// of the same phase instead of with the gaps between them.
/// Blending two unrelated values with weights w and 1 - w shrinks their spread by
/// sqrt(w^2 + (1 - w)^2) (to 0.71 at w = 1/2), which washes the overlap out. The blend is therefore
/// variance-preserving (after Heitz and Neyret 2018, "High-performance by-example noise using a
/// histogram-preserving blending operator"): m + (w a + (1 - w) b - m) / sqrt(w^2 + (1 - w)^2 +
/// 2 w (1 - w) rho), m the value's mean over the maps and rho the correlation of the blended pairs
/// (clamped to [0, 1]; 0 is Heitz and Neyret's operator, 1 a plain cross-fade of equal neighbours);
/// results are clamped to each map's domain.
///
/// `seam_statistics` measures a tile: the mean absolute step across its wrap edges against the mean
/// step between interior neighbours (per map, averaged over maps), and each map's mean and variance.
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"

namespace anisocap {

/// Options of make_tileable.
struct tileable_options {
  /// Overlap along each axis, as a fraction of that axis's texels (the tile is that much smaller).
  double overlap = 0.25;
  /// Search the overlap between 0.5 and 1.5 times `overlap` (at most half the side) for the one
  /// whose blended texels match best (file comment); false: exactly `overlap`.
  bool match_overlap = true;
};

namespace detail {

/// The per-texel values blended by make_tileable: one "channel" list per texel.
inline constexpr int tile_channels = 13;  // diffuse 3, specular 3, log widths 2, direction 2, F0, slopes 2
/// Whether a channel's blend preserves its variance (not the direction vector's: its length only
/// weighs the direction).
inline constexpr bool tile_preserve_variance(int c) { return c != 8 && c != 9; }

inline std::array<double, tile_channels> tile_values(const material_maps& m, std::size_t i) {
  std::array<double, tile_channels> v{};
  for (int c = 0; c < 3; ++c) v[c] = m.plane(diffuse_r + c)[i], v[3 + c] = m.plane(specular_r + c)[i];
  const double lx = std::log(std::max<double>(m.plane(lobe_x)[i], ward_limits::min_lobe));
  const double ly = std::log(std::max<double>(m.plane(lobe_y)[i], ward_limits::min_lobe));
  const double a = m.plane(rotation)[i];
  v[6] = lx, v[7] = ly;
  v[8] = std::abs(lx - ly) * std::cos(2 * a), v[9] = std::abs(lx - ly) * std::sin(2 * a);
  if (lx < ly) v[8] = -v[8], v[9] = -v[9];  // the wide axis is alpha + pi/2
  v[10] = m.plane(fresnel_f0)[i];
  const double nx = m.plane(normal_x)[i], ny = m.plane(normal_y)[i];
  const double nz = std::sqrt(std::max(1.0 - nx * nx - ny * ny, 1e-4));
  v[11] = nx / nz, v[12] = ny / nz;
  return v;
}

inline void store_tile_values(material_maps& m, std::size_t i, const std::array<double, tile_channels>& v) {
  for (int c = 0; c < 3; ++c) {
    m.plane(diffuse_r + c)[i] = float(std::clamp(v[c], 0.0, 1.0));
    m.plane(specular_r + c)[i] = float(std::clamp(v[3 + c], 0.0, 1.0));
  }
  // The wider blended width along the blended direction (canonical form: sigma_x >= sigma_y).
  double lx = std::max(v[6], v[7]), ly = std::min(v[6], v[7]);
  double alpha = 0.5 * std::atan2(v[9], v[8]);  // in [-pi/2, pi/2]
  if (alpha >= std::numbers::pi / 2) alpha -= std::numbers::pi;
  m.plane(lobe_x)[i] = float(std::clamp(std::exp(lx), double(ward_limits::min_lobe), 1.0));
  m.plane(lobe_y)[i] = float(std::clamp(std::exp(ly), double(ward_limits::min_lobe), 1.0));
  m.plane(rotation)[i] = float(alpha);
  m.plane(fresnel_f0)[i] = float(std::clamp(v[10], 0.0, 1.0));
  const double inv = 1 / std::sqrt(1 + v[11] * v[11] + v[12] * v[12]);
  m.plane(normal_x)[i] = float(v[11] * inv), m.plane(normal_y)[i] = float(v[12] * inv);
}

/// One axis of make_tileable on value arrays: `in` is w x h (row-major) texels of `channels` values;
/// returns (w - b) x h along x (transpose handled by the caller through strides).
inline std::vector<double> cross_fade_x(const std::vector<double>& in, int w, int h, int channels, int b) {
  const int out_w = w - b;
  std::vector<double> mean(channels, 0.0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < channels; ++c) mean[c] += in[(std::size_t(y) * w + x) * channels + c];
  for (double& m : mean) m /= double(w) * h;
  // Correlation of the blended pairs per channel (clamped to [0, 1]): the blend's spread is
  // sqrt(w^2 + (1 - w)^2 + 2 w (1 - w) rho) of theirs.
  std::vector<double> variance(channels, 0.0), covariance(channels, 0.0), rho(channels, 0.0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < b; ++x) {
      const double* own = &in[(std::size_t(y) * w + x) * channels];
      const double* far = &in[(std::size_t(y) * w + x + out_w) * channels];
      for (int c = 0; c < channels; ++c) {
        variance[c] += 0.5 * ((own[c] - mean[c]) * (own[c] - mean[c]) + (far[c] - mean[c]) * (far[c] - mean[c]));
        covariance[c] += (own[c] - mean[c]) * (far[c] - mean[c]);
      }
    }
  for (int c = 0; c < channels; ++c)
    rho[c] = variance[c] > 0 && tile_preserve_variance(c) ? std::clamp(covariance[c] / variance[c], 0.0, 1.0) : 1.0;
  std::vector<double> out(std::size_t(out_w) * h * channels);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < out_w; ++x) {
      const double* own = &in[(std::size_t(y) * w + x) * channels];
      double* o = &out[(std::size_t(y) * out_w + x) * channels];
      if (x >= b) {
        std::copy(own, own + channels, o);
        continue;
      }
      const double* far = &in[(std::size_t(y) * w + x + out_w) * channels];
      const double wt = (x + 0.5) / b;
      for (int c = 0; c < channels; ++c) {
        const double norm = 1 / std::sqrt(wt * wt + (1 - wt) * (1 - wt) + 2 * wt * (1 - wt) * rho[c]);
        o[c] = mean[c] + (wt * own[c] + (1 - wt) * far[c] - mean[c]) * norm;
      }
    }
  return out;
}

/// The overlap in [lo, hi] whose blended columns (x and x + w - b, x < b) differ least, the
/// difference of each channel in units of its standard deviation, every 2nd row.
inline int best_overlap_x(const std::vector<double>& in, int w, int h, int channels, int lo, int hi) {
  std::vector<double> mean(channels, 0.0), inv_var(channels, 0.0);
  for (std::size_t i = 0; i < std::size_t(w) * h; ++i)
    for (int c = 0; c < channels; ++c) mean[c] += in[i * channels + c];
  for (double& m : mean) m /= double(w) * h;
  for (std::size_t i = 0; i < std::size_t(w) * h; ++i)
    for (int c = 0; c < channels; ++c) inv_var[c] += (in[i * channels + c] - mean[c]) * (in[i * channels + c] - mean[c]);
  for (double& v : inv_var) v = v > 1e-12 * w * h ? double(w) * h / v : 0.0;
  int best = hi;
  double best_cost = 1e300;
  for (int b = lo; b <= hi; ++b) {
    double cost = 0;
    for (int y = 0; y < h; y += 2)
      for (int x = 0; x < b; ++x) {
        const double* own = &in[(std::size_t(y) * w + x) * channels];
        const double* far = &in[(std::size_t(y) * w + x + w - b) * channels];
        for (int c = 0; c < channels; ++c) cost += (own[c] - far[c]) * (own[c] - far[c]) * inv_var[c];
      }
    cost /= b;
    if (cost < best_cost) best_cost = cost, best = b;
  }
  return best;
}

inline std::vector<double> transpose(const std::vector<double>& in, int w, int h, int channels) {
  std::vector<double> out(in.size());
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < channels; ++c) out[(std::size_t(x) * h + y) * channels + c] = in[(std::size_t(y) * w + x) * channels + c];
  return out;
}

}  // namespace detail

/// Throws what make_tileable throws for a w x h map set and these options, without the maps: a
/// capture checks its --tileable before any work.
inline void validate_tileable(int w, int h, const tileable_options& options) {
  if (!(options.overlap > 0 && options.overlap <= 0.5))
    throw std::invalid_argument("tileable overlap must be in (0, 0.5], got " + std::to_string(options.overlap));
  if (std::lround(options.overlap * w) < 2 || std::lround(options.overlap * h) < 2)
    throw std::invalid_argument("map set of " + std::to_string(w) + "x" + std::to_string(h) + " is too small for a tileable overlap of " +
                                std::to_string(options.overlap) + " (fewer than 2 texels to blend)");
}

/// A seamless tile of `maps` (file comment): (W - bx) x (H - by) texels, bx = round(overlap W),
/// by = round(overlap H), or the best-matching overlaps near them (tileable_options::match_overlap),
/// in canonical form (brdf/canonical_maps.hpp). Throws std::invalid_argument when the overlap is not in (0, 0.5] or
/// leaves fewer than 2 texels to blend along an axis.
inline material_maps make_tileable(material_maps maps, const tileable_options& options = {}) {
  const int w = maps.width(), h = maps.height();
  validate_tileable(w, h, options);
  int bx = int(std::lround(options.overlap * w)), by = int(std::lround(options.overlap * h));
  canonicalise(maps);  // widths blend with widths along the same (wide or narrow) axis
  const int channels = detail::tile_channels + (maps.has_height() ? 1 : 0);
  std::vector<double> values(maps.texel_count() * channels);
  for (std::size_t i = 0; i < maps.texel_count(); ++i) {
    const auto v = detail::tile_values(maps, i);
    std::copy(v.begin(), v.end(), values.begin() + i * channels);
    if (maps.has_height()) values[i * channels + detail::tile_channels] = maps.height_map()[i];
  }
  auto search = [&](const std::vector<double>& v, int side, int rows, int b) {
    if (!options.match_overlap) return b;
    return detail::best_overlap_x(v, side, rows, channels, std::max(2, b / 2), std::min(side / 2, b + b / 2));
  };
  bx = search(values, w, h, bx);
  std::vector<double> along_x = detail::cross_fade_x(values, w, h, channels, bx);
  std::vector<double> t = detail::transpose(along_x, w - bx, h, channels);
  by = search(t, h, w - bx, by);
  std::vector<double> along_y = detail::cross_fade_x(t, h, w - bx, channels, by);
  std::vector<double> tile = detail::transpose(along_y, h - by, w - bx, channels);
  material_maps out(w - bx, h - by);
  if (maps.has_height()) out.enable_height_map();
  for (std::size_t i = 0; i < out.texel_count(); ++i) {
    std::array<double, detail::tile_channels> v;
    std::copy(tile.begin() + i * channels, tile.begin() + i * channels + detail::tile_channels, v.begin());
    detail::store_tile_values(out, i, v);
    if (maps.has_height()) out.height_map()[i] = float(tile[i * channels + detail::tile_channels]);
  }
  return out;
}

/// Seam and statistics of a map set repeated as a tile (file comment).
struct seam_statistics {
  /// Mean absolute step across the wrap edges (last column to first, last row to first) over the
  /// mean absolute step between interior neighbours, per parameter plane (planes without any
  /// interior variation: 1). The rotation's steps are taken modulo pi.
  std::array<double, parameter_count> seam_ratio{};
  std::array<double, parameter_count> mean{};      ///< per plane
  std::array<double, parameter_count> variance{};  ///< per plane
  /// seam_ratio averaged over the planes.
  double mean_seam_ratio() const {
    double s = 0;
    for (double r : seam_ratio) s += r;
    return s / parameter_count;
  }
};

/// Measures `maps` as a tile (file comment).
inline seam_statistics measure_seam(const material_maps& maps) {
  seam_statistics s;
  const int w = maps.width(), h = maps.height();
  for (int k = 0; k < parameter_count; ++k) {
    auto step = [&](int x0, int y0, int x1, int y1) {
      double d = std::abs(double(maps.at(k, x0, y0)) - maps.at(k, x1, y1));
      if (k == rotation) d = std::min(d, std::abs(d - std::numbers::pi));
      return d;
    };
    double interior = 0, edge = 0;
    std::size_t ni = 0, ne = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x + 1 < w; ++x) interior += step(x, y, x + 1, y), ++ni;
    for (int y = 0; y + 1 < h; ++y)
      for (int x = 0; x < w; ++x) interior += step(x, y, x, y + 1), ++ni;
    for (int y = 0; y < h; ++y) edge += step(w - 1, y, 0, y), ++ne;
    for (int x = 0; x < w; ++x) edge += step(x, h - 1, x, 0), ++ne;
    interior /= double(ni), edge /= double(ne);
    s.seam_ratio[k] = interior > 1e-9 ? edge / interior : (edge > 1e-9 ? edge / 1e-9 : 1.0);
    double m = 0, m2 = 0;
    for (std::size_t i = 0; i < maps.texel_count(); ++i) m += maps.plane(k)[i];
    m /= double(maps.texel_count());
    for (std::size_t i = 0; i < maps.texel_count(); ++i) m2 += (maps.plane(k)[i] - m) * (maps.plane(k)[i] - m);
    s.mean[k] = m, s.variance[k] = m2 / double(maps.texel_count());
  }
  return s;
}

/// What make_tileable changed, in the numbers a user checks: the seam (mean_seam_ratio) before and
/// after, and how far each map's statistics moved (the rotation, an angle, and planes without
/// variation left out).
struct tileable_change {
  int width_before = 0, height_before = 0, width_after = 0, height_after = 0;
  double seam_before = 1, seam_after = 1;  ///< seam_statistics::mean_seam_ratio
  double largest_mean_shift = 0;           ///< |mean after - mean before| / standard deviation before, largest over the planes
  double variance_ratio_low = 1, variance_ratio_high = 1;  ///< variance after / before, smallest and largest over the planes
};

/// Compares a map set with its tile (make_tileable's result).
inline tileable_change compare_tile(const material_maps& before, const material_maps& after) {
  const seam_statistics a = measure_seam(before), b = measure_seam(after);
  tileable_change c{before.width(), before.height(), after.width(), after.height(), a.mean_seam_ratio(), b.mean_seam_ratio()};
  bool any = false;
  for (int k = 0; k < parameter_count; ++k) {
    if (k == rotation || a.variance[k] < 1e-12) continue;
    const double ratio = b.variance[k] / a.variance[k];
    c.largest_mean_shift = std::max(c.largest_mean_shift, std::abs(b.mean[k] - a.mean[k]) / std::sqrt(a.variance[k]));
    c.variance_ratio_low = any ? std::min(c.variance_ratio_low, ratio) : ratio;
    c.variance_ratio_high = any ? std::max(c.variance_ratio_high, ratio) : ratio;
    any = true;
  }
  return c;
}

}  // namespace anisocap
