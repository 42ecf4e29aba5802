#pragma once
/// @file
/// The estimate stage (docs/method.md section 8.1): the estimation network over sliding windows, or
/// without networks a first guess from the photographs alone.
///
/// Sliding windows: the estimator sees windows of the photographs (by default 256 x 256 with an
/// overlap of up to 192 texels, stride 64: estimate_options); the window estimates are blended back to full size
/// with weights that fall off towards each window's border. Materials smaller than a window are
/// mirrored out to the window size and the estimate cropped back.
#include <algorithm>
#include <cmath>
#include <chrono>
#include <functional>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/distributed.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/parallel.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap {

/// Start offsets of windows of `window` texels with step `stride` covering [0, size): the last
/// window ends exactly at size. A size below the window gives one window at 0 (padding needed).
inline std::vector<int> window_starts(int size, int window, int stride) {
  if (size <= 0 || window <= 0 || stride <= 0) throw std::invalid_argument("window_starts: sizes must be positive");
  std::vector<int> s;
  if (size <= window) return {0};
  for (int x = 0;; x += stride) {
    if (x + window >= size) { s.push_back(size - window); break; }
    s.push_back(x);
  }
  return s;
}

/// Mirror index (reflection without repeating the edge texel): ..., 2, 1, 0, 1, 2, ..., n-1, n-2, ...
inline int mirror_index(int i, int n) {
  if (n == 1) return 0;
  const int period = 2 * (n - 1);
  i %= period;
  if (i < 0) i += period;
  return i < n ? i : period - i;
}

/// Writes the window of `src` starting at (x0, y0), of out's size, into `out` (which must have
/// src's channel count), mirrored where it leaves the image.
inline void crop_mirrored_into(const image& src, int x0, int y0, image& out) {
  if (out.channels() != src.channels()) throw std::invalid_argument("crop_mirrored_into: the images' channel counts differ");
  for (int c = 0; c < src.channels(); ++c)
    for (int y = 0; y < out.height(); ++y) {
      const int sy = mirror_index(y0 + y, src.height());
      for (int x = 0; x < out.width(); ++x) out.at(c, x, y) = src.at(c, mirror_index(x0 + x, src.width()), sy);
    }
}

/// The window [x0, x0 + w) x [y0, y0 + h) of `src`, mirrored where it leaves the image.
inline image crop_mirrored(const image& src, int x0, int y0, int w, int h) {
  image out(w, h, src.channels());
  crop_mirrored_into(src, x0, y0, out);
  return out;
}

/// Blending weight of texel i of a window of n texels: a tent that is 1 in the middle and falls to
/// `floor` at the border, so that overlapping windows hand over smoothly and a texel that only one
/// window covers (the material's own border) still gets a valid weight.
inline float window_weight(int i, int n, float floor = 0.05f) {
  const float d = std::min(float(i) + 0.5f, float(n) - float(i) - 0.5f) / (0.5f * float(n));
  return std::max(floor, d);
}

/// Blends per-window map estimates into one map set of `width` x `height`. `estimate_window`
/// receives the window's crops of every photograph (size window x window, mirrored where the
/// material is smaller) and returns their map set. Linear parameters are averaged with the window
/// weights; the normal's (x, y) too, renormalised into the unit disc; the rotation alpha, which is
/// pi-periodic, is averaged as the doubled angle (cos 2 alpha, sin 2 alpha) weighted by the lobe
/// anisotropy |sx - sy| / max(sx, sy), so windows that cannot see it do not decide it.
/// With `comm` of N ranks the windows are dealt out in rounds of N (window i to rank i mod N), each
/// round's estimates gathered on every rank and blended in window order: every rank returns the
/// single process's maps, bit for bit.
inline material_maps estimate_by_windows(const std::vector<image>& photos, int window, int stride,
                                         const std::function<material_maps(const std::vector<image>&)>& estimate_window,
                                         const std::function<void(int, int)>& progress = {},
                                         const communicator& comm = serial_communicator()) {
  if (photos.empty()) throw std::invalid_argument("estimate_by_windows: no photographs");
  const int W = photos[0].width(), H = photos[0].height();
  const auto xs = window_starts(W, window, stride), ys = window_starts(H, window, stride);
  std::vector<double> sum(std::size_t(parameter_count) * W * H, 0.0), weight(std::size_t(W) * H, 0.0);
  std::vector<double> rot_c(std::size_t(W) * H, 0.0), rot_s(std::size_t(W) * H, 0.0);
  const int total = int(xs.size() * ys.size());
  const int ranks = comm.size();
  int done = 0;
  material_maps m(window, window);
  const std::size_t floats = m.plane_stride() * parameter_count;
  std::vector<float> own, round;  // kept across rounds: their memory is reused, not asked for again
  std::vector<image> crops;        // the same: each window's crops are written into these
  for (const auto& p : photos) crops.emplace_back(window, window, p.channels());
  for (int base = 0; base < total; base += ranks) {
    // This round's windows: rank r estimates window base + r, then all are gathered.
    const int mine = base + comm.rank();
    own.clear();
    if (mine < total) {
      const int y0 = ys[std::size_t(mine) / xs.size()], x0 = xs[std::size_t(mine) % xs.size()];
      for_each_index_in_parallel(photos.size(), [&](std::size_t i) { crop_mirrored_into(photos[i], x0, y0, crops[i]); });
      const material_maps e = estimate_window(crops);
      if (e.width() != window || e.height() != window)
        throw std::runtime_error("estimate_by_windows: the window estimate has the wrong size");
      own.assign(e.data(), e.data() + floats);
    }
    std::vector<std::size_t> counts;
    for (int r = 0; r < ranks; ++r) counts.push_back(base + r < total ? floats : 0);
    comm.all_gather<float>(own, round, counts);
    for (int index = base; index < std::min(base + ranks, total); ++index) {
      const int y0 = ys[std::size_t(index) / xs.size()], x0 = xs[std::size_t(index) % xs.size()];
      std::copy_n(round.data() + std::size_t(index - base) * floats, floats, m.data());
      // Rows in parallel: each texel still takes the windows in order, so the sums are the same bits.
      const int rows = std::min(window, H - y0);
#pragma omp parallel for schedule(static) if (std::size_t(rows) * window >= (std::size_t(1) << 14))
      for (int y = 0; y < rows; ++y)
        for (int x = 0; x < std::min(window, W - x0); ++x) {
          const double wgt = double(window_weight(x, window)) * window_weight(y, window);
          const std::size_t i = std::size_t(y0 + y) * W + (x0 + x);
          for (int k = 0; k < parameter_count; ++k)
            if (k != rotation) sum[std::size_t(k) * W * H + i] += wgt * m.at(k, x, y);
          const double sx = m.at(lobe_x, x, y), sy = m.at(lobe_y, x, y);
          const double aniso = std::abs(sx - sy) / std::max({sx, sy, 1e-6}) + 1e-3;
          const double a = 2.0 * m.at(rotation, x, y);
          rot_c[i] += wgt * aniso * std::cos(a);
          rot_s[i] += wgt * aniso * std::sin(a);
          weight[i] += wgt;
        }
      if (progress) progress(++done, total);
    }
  }
  material_maps out(W, H);
#pragma omp parallel for schedule(static) if (std::size_t(W) * H >= (std::size_t(1) << 14))
  for (std::ptrdiff_t t = 0; t < std::ptrdiff_t(W) * H; ++t) {
    const std::size_t i = std::size_t(t);
    for (int k = 0; k < parameter_count; ++k)
      if (k != rotation) out.plane(k)[i] = float(sum[std::size_t(k) * W * H + i] / weight[i]);
    float& nx = out.plane(normal_x)[i];
    float& ny = out.plane(normal_y)[i];
    const float r = std::sqrt(nx * nx + ny * ny);
    if (r > 0.999f) { nx *= 0.999f / r; ny *= 0.999f / r; }
    out.plane(rotation)[i] = float(0.5 * std::atan2(rot_s[i], rot_c[i]));
  }
  return out;
}

/// Options of `estimate`.
struct estimate_options {
  int window = 256;  ///< estimation window side, texels (the network sees window x window crops)
  int stride = 64;   ///< window step (overlap window - stride)

  /// Calls `f(name, field)` for each field, by the name the capture's fingerprint, the program's
  /// report and the library's messages give it (`o` an estimate_options, const or not).
  template <class Self, class F>
  static void visit_fields(Self& o, F&& f) {
    f("window", o.window), f("stride", o.stride);
  }
  /// Throws std::invalid_argument unless 0 < stride <= window (a larger step would leave texels
  /// that no window covers).
  void validate() const {
    if (window <= 0 || stride <= 0)
      throw std::invalid_argument("estimate_options::window (" + std::to_string(window) + ") and estimate_options::stride (" +
                                  std::to_string(stride) + ") must be positive");
    if (stride > window)
      throw std::invalid_argument("estimate_options::stride (" + std::to_string(stride) + ") is larger than estimate_options::window (" +
                                  std::to_string(window) + "): texels between the windows would have no estimate");
  }
};

/// The estimate of the map set from the photographs (docs/method.md section 8.1): `estimator`
/// (anything with `material_maps estimate(const std::vector<image>&)`) over sliding windows,
/// blended. `progress`, when set, hears after every window (step = windows done). `comm`: the ranks
/// that share the windows (estimate_by_windows); every rank returns the same maps.
template <class Estimator>
material_maps estimate(const std::vector<image>& photos, Estimator& estimator, const estimate_options& options = {},
                       const std::function<void(const optimisation_progress&)>& progress = {},
                       const communicator& comm = serial_communicator()) {
  const auto start = std::chrono::steady_clock::now();
  return estimate_by_windows(photos, options.window, options.stride,
                             [&](const std::vector<image>& crops) { return estimator.estimate(crops); },
                             [&](int done, int total) {
                               if (progress) progress(optimisation_progress::at(done, total, 0.0, seconds_since(start)));
                             },
                             comm);
}

/// A first guess from the photographs alone, where no estimation network runs: the diffuse albedo
/// of each texel is the smallest value of B / (cos(theta_l) I / (pi r^2)) over the images that
/// light it (the image where the specular lobe adds least), clamped to [0.02, 0.95]; the other
/// parameters start at mid-range values (a'_s 0.3, sigma 0.15, F0 0.5, flat normal, alpha 0).
/// Pixels that `masks` (optional, one 1-channel image per photograph, 0 = left out, e.g. clipped
/// pixels: data/photo_io.hpp) leave out are not used.
inline material_maps initial_guess(const capture& cap, const std::vector<image>& photos, const tile_placement& placement = {},
                                   const std::vector<image>& masks = {}) {
  if (photos.empty() || photos.size() != cap.images.size())
    throw std::invalid_argument("initial_guess: need one photograph per configuration");
  if (!masks.empty() && masks.size() != photos.size()) throw std::invalid_argument("initial_guess: need one mask per photograph");
  const int w = photos[0].width(), h = photos[0].height();
  material_maps maps(w, h);
  const float start[parameter_count] = {0.5f, 0.5f, 0.5f, 0.3f, 0.3f, 0.3f, 0.15f, 0.15f, 0.5f, 0.0f, 0.0f, 0.0f};
  maps.fill(start);
  tile_placement tp = placement;
  if (tp.full_width == 0) tp = {w, h, 0, 0};
#pragma omp parallel for schedule(static)
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const auto p = texel_position(tp.x0 + x, tp.y0 + y, tp.full_width, tp.full_height);
      float best[3] = {1e30f, 1e30f, 1e30f};
      for (std::size_t k = 0; k < cap.images.size(); ++k) {
        const auto& im = cap.images[k];
        const float lx = im.light[0] - p[0], ly = im.light[1] - p[1], lz = im.light[2];
        const float r2 = std::max(lx * lx + ly * ly + lz * lz, 1e-6f);
        const float cos_l = lz / std::sqrt(r2);
        if (cos_l < 0.05f || im.camera[2] <= 0 || (!masks.empty() && masks[k].at(0, x, y) == 0.0f)) continue;
        for (int c = 0; c < 3; ++c) {
          const float irradiance = cos_l * im.intensity[c] / (std::numbers::pi_v<float> * r2);
          best[c] = std::min(best[c], photos[k].at(c, x, y) / irradiance);
        }
      }
      for (int c = 0; c < 3; ++c)
        if (best[c] < 1e29f) maps.at(diffuse_r + c, x, y) = std::clamp(best[c], 0.02f, 0.95f);
    }
  return maps;
}

}  // namespace anisocap
