#pragma once
/// @file
/// The networks' value space (docs/method.md section 1 and 5): the 12 appearance parameters mapped to [-1, 1]
/// (what the estimator's and the auto-encoder's tanh outputs produce), the photographs mapped by
/// eq. 7, and the chain rule that turns the render loss's dL/d(maps) into dL/d(network outputs).
///
/// Per channel (k = parameter_index, the same order as the networks' 9 + 3 output channels):
/// - a_d, a'_s, F0: u = 2 v - 1 (linear).
/// - sigma_x, sigma_y: log space, u = 2 (log sigma - log s0) / (-log s0) - 1 with s0 = 1e-4
///   (min_lobe_width), so u = -1 is sigma = 1e-4 and u = 1 is sigma = 1; widths below s0 clamp to -1.
///   **decision** (docs/method.md section 1 leaves the map open): equal steps in u are equal ratios of sigma,
///   which is how the lobe's appearance changes.
/// - n_x, n_y: as they are; a decoded pair with x^2 + y^2 > 0.999^2 is scaled back onto that circle
///   (radius 0.999 keeps n_z > 0.04, so the tangent frame stays defined), and the chain rule
///   follows the scaling.
/// - alpha: u = alpha / (pi / 2); the encoder wraps alpha into [-pi/2, pi/2] first (alpha is
///   pi-periodic, docs/method.md section 1).
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/tensor.hpp"

namespace anisocap::network_space {

/// log(min_lobe_width): the lower end of the lobe widths' log range.
inline const double log_min_lobe = log_min_lobe_width;
/// Largest |(n_x, n_y)| a decoded normal may have.
inline constexpr double max_normal_xy = 0.999;

/// The map from network value u to parameter value v of a channel where it is affine (every
/// channel but the lobe widths): v = scale u + offset. to_network (its inverse), from_network,
/// network_to_maps and the chain rule (add_network_gradient, whose factor is `scale`) all read it
/// here.
struct affine_channel {
  double scale = 1, offset = 0;
};

/// Channel k's affine map (k not a lobe width): normals as they are, the rotation times pi / 2,
/// the albedos and F0 (u + 1) / 2.
constexpr affine_channel affine_of(int k) {
  switch (k) {
    case normal_x:
    case normal_y: return {1, 0};
    case rotation: return {std::numbers::pi / 2, 0};
    default: return {0.5, 0.5};
  }
}

/// Parameter value v of channel k in network space (the rotation wrapped into [-pi/2, pi/2] first).
inline double to_network(int k, double v) {
  if (k == lobe_x || k == lobe_y) {
    const double s = std::max(v, double(min_lobe_width));
    return 2 * (std::log(s) - log_min_lobe) / (-log_min_lobe) - 1;
  }
  if (k == rotation) v -= std::numbers::pi * std::nearbyint(v / std::numbers::pi);
  const affine_channel a = affine_of(k);
  return (v - a.offset) / a.scale;
}

/// Parameter value of channel k for network value u (normals not yet limited to the disc).
inline double from_network(int k, double u) {
  if (k == lobe_x || k == lobe_y) return std::exp(log_min_lobe + (u + 1) / 2 * (-log_min_lobe));
  const affine_channel a = affine_of(k);
  return a.scale * u + a.offset;
}

/// Writes the map set in network space into entry `b` of `out` (same height and width).
template <class T>
void maps_to_network(const material_maps& maps, tensor<parameter_count, T>& out, int b) {
  if (out.height() != maps.height() || out.width() != maps.width() || b < 0 || b >= out.batch())
    throw std::invalid_argument("maps_to_network: the tensor is " + std::to_string(out.height()) + "x" +
                                std::to_string(out.width()) + ", the maps " + std::to_string(maps.height()) + "x" +
                                std::to_string(maps.width()));
  for (int y = 0; y < maps.height(); ++y)
    for (int x = 0; x < maps.width(); ++x) {
      T* p = out.pixel(b, y, x);
      for (int k = 0; k < parameter_count; ++k) p[k] = T(to_network(k, maps.at(k, x, y)));
    }
}

namespace detail {

/// Rows of at least this many texels in all run in parallel (network_to_maps, add_network_gradient).
inline constexpr std::size_t parallel_texels = 16384;

/// The lobe widths from_network gives for channels lobe_x and lobe_y of the `width` texels from
/// `row` (parameter_count values per texel): sigma_x at `lobes[x]`, sigma_y at `lobes[padded + x]`,
/// where `padded` (width rounded up to whole SIMD batches) is the size of each half of `lobes`. The
/// same double-precision sums as from_network, with the exponential taken a batch at a time: the
/// one transcendental of the network space, and most of its time when taken texel by texel.
template <class T>
void lobe_widths(const T* row, int width, std::vector<double>& lobes, std::size_t& padded) {
  using V = simd::batch<double>;
  padded = (std::size_t(width) + V::size - 1) / V::size * V::size;
  lobes.assign(2 * padded, -1.0);  // padding: u = -1, the narrowest lobe (a finite exponential)
  for (int x = 0; x < width; ++x) {
    lobes[std::size_t(x)] = double(row[std::size_t(x) * parameter_count + lobe_x]);
    lobes[padded + std::size_t(x)] = double(row[std::size_t(x) * parameter_count + lobe_y]);
  }
  const V base(log_min_lobe), range(-log_min_lobe), one(1.0), half(0.5);
  for (std::size_t i = 0; i < 2 * padded; i += V::size) {
    const V u = V::load_unaligned(lobes.data() + i);
    simd::exp(base + (u + one) * half * range).store_unaligned(lobes.data() + i);
  }
}

/// Calls `row_fn(y, row, lobes, padded)` for each row y of entry `b` of u: `row` its values,
/// `lobes` and `padded` its lobe widths as lobe_widths lays them out. Rows run in parallel from
/// parallel_texels texels on.
template <class T, class RowFn>
void rows_with_lobe_widths(const tensor<parameter_count, T>& u, int b, RowFn&& row_fn) {
#pragma omp parallel if (std::size_t(u.height()) * u.width() >= parallel_texels)
  {
    std::vector<double> lobes;
    std::size_t padded = 0;
#pragma omp for schedule(static)
    for (int y = 0; y < u.height(); ++y) {
      lobe_widths(u.pixel(b, y, 0), u.width(), lobes, padded);
      row_fn(y, u.pixel(b, y, 0), static_cast<const double*>(lobes.data()), padded);
    }
  }
}

}  // namespace detail

/// Writes the map set of entry `b` of network outputs u into `maps` (the inverse of
/// maps_to_network, normals limited to |(x, y)| <= max_normal_xy), resizing it only when its size
/// differs: a loop that calls this every step (the fine-tune) reuses one map set.
template <class T>
void network_to_maps(const tensor<parameter_count, T>& u, int b, material_maps& maps) {
  if (maps.width() != u.width() || maps.height() != u.height()) maps = material_maps(u.width(), u.height());
  const int width = u.width();
  detail::rows_with_lobe_widths(u, b, [&](int y, const T* row, const double* lobes, std::size_t padded) {
    // Channel by channel (from_network's cases, each a loop the compiler vectorises), then the
    // normals limited to the disc.
    for (int k = 0; k < parameter_count; ++k) {
      float* out = &maps.at(k, 0, y);
      const T* in = row + k;
      if (k == lobe_x || k == lobe_y) {
        const double* l = lobes + (k == lobe_y ? padded : 0);
        for (int x = 0; x < width; ++x) out[x] = float(l[x]);
      } else {
        const affine_channel a = affine_of(k);
        for (int x = 0; x < width; ++x) out[x] = float(a.scale * double(in[std::size_t(x) * parameter_count]) + a.offset);
      }
    }
    float* out_x = &maps.at(normal_x, 0, y);
    float* out_y = &maps.at(normal_y, 0, y);
    for (int x = 0; x < width; ++x) {
      const double nx = row[std::size_t(x) * parameter_count + normal_x], ny = row[std::size_t(x) * parameter_count + normal_y];
      const double r = std::sqrt(nx * nx + ny * ny);
      if (r > max_normal_xy) {
        out_x[x] = float(nx * max_normal_xy / r);
        out_y[x] = float(ny * max_normal_xy / r);
      }
    }
  });
}

/// The map set of entry `b` of network outputs u (the inverse of maps_to_network, normals limited
/// to |(x, y)| <= max_normal_xy).
template <class T>
material_maps network_to_maps(const tensor<parameter_count, T>& u, int b) {
  material_maps maps(u.width(), u.height());
  network_to_maps(u, b, maps);
  return maps;
}

/// The network values `u` (a decoder's output) shifted by `r` (same height and width; entry 0 of
/// each): u + r, clamped to [-1, 1] in every channel but the rotation, which is pi-periodic and
/// stays as it is. The fine-tune's residual start (docs/method.md section 8.3) renders these; its
/// gradient passes the shift unchanged (a straight-through clamp).
template <class T>
tensor<parameter_count, T> shifted(const tensor<parameter_count, T>& u, const tensor<parameter_count, float>& r) {
  if (u.height() != r.height() || u.width() != r.width())
    throw std::invalid_argument("network_space::shifted: the values are " + std::to_string(u.height()) + "x" + std::to_string(u.width()) +
                                ", the shift " + std::to_string(r.height()) + "x" + std::to_string(r.width()));
  tensor<parameter_count, T> out(1, u.height(), u.width());
#pragma omp parallel for schedule(static) if (std::size_t(u.height()) * u.width() >= detail::parallel_texels)
  for (int y = 0; y < u.height(); ++y)
    for (int x = 0; x < u.width(); ++x) {
      const T* a = u.pixel(0, y, x);
      const float* d = r.pixel(0, y, x);
      T* o = out.pixel(0, y, x);
      for (int k = 0; k < parameter_count; ++k) o[k] = k == rotation ? T(a[k] + d[k]) : std::clamp(T(a[k] + d[k]), T(-1), T(1));
    }
  return out;
}

/// The shift that takes network values `u` (a decoder's output, entry 0) to the map set `target`
/// (same size): to_network(target) - u, with the rotation's difference wrapped into [-1, 1] (a
/// rotation of pi is none).
template <class T>
tensor<parameter_count, float> shift_to(const tensor<parameter_count, T>& u, const material_maps& target) {
  tensor<parameter_count, float> r(1, target.height(), target.width());
  maps_to_network(target, r, 0);
  if (u.height() != r.height() || u.width() != r.width())
    throw std::invalid_argument("network_space::shift_to: the values and the maps differ in size");
  for (int y = 0; y < r.height(); ++y)
    for (int x = 0; x < r.width(); ++x) {
      float* d = r.pixel(0, y, x);
      const T* a = u.pixel(0, y, x);
      for (int k = 0; k < parameter_count; ++k) d[k] -= float(a[k]);
      d[rotation] -= 2.0f * std::nearbyint(d[rotation] / 2.0f);
    }
  return r;
}

/// Chain rule of network_to_maps: adds scale * dL/du to entry b of grad_u, given dL/d(maps) in
/// `grad_maps` at the network values u.
template <class T>
void add_network_gradient(const tensor<parameter_count, T>& u, int b, const material_maps& grad_maps, double scale,
                          tensor<parameter_count, T>& grad_u) {
  const double lobe_factor = -log_min_lobe / 2;
  const int width = u.width();
  detail::rows_with_lobe_widths(u, b, [&](int y, const T* row, const double* lobes, std::size_t padded) {
    T* grad_row = grad_u.pixel(b, y, 0);
    const float* gm[parameter_count];
    for (int k = 0; k < parameter_count; ++k) gm[k] = grad_maps.plane(k) + std::size_t(y) * grad_maps.width();
    // Channel by channel, each a loop the compiler vectorises: d(map)/du times dL/d(map).
    for (int k = 0; k < parameter_count; ++k) {
      T* g = grad_row + k;
      const float* in = gm[k];
      if (k == lobe_x || k == lobe_y) {  // d exp(a + c u)/du = c exp(...)
        const double* l = lobes + (k == lobe_y ? padded : 0);
        for (int x = 0; x < width; ++x) g[std::size_t(x) * parameter_count] += T(scale * double(in[x]) * (l[x] * lobe_factor));
      } else {
        // The affine channels' scale (normals: 1, corrected below where they were scaled onto the circle).
        const double d = affine_of(k).scale;
        for (int x = 0; x < width; ++x) g[std::size_t(x) * parameter_count] += T(scale * double(in[x]) * d);
      }
    }
    for (int x = 0; x < width; ++x) {
      const T* p = row + std::size_t(x) * parameter_count;
      const double nx = p[normal_x], ny = p[normal_y], r = std::sqrt(nx * nx + ny * ny);
      if (r > max_normal_xy) {
        // n = s u with s = m / |u|: dn/du = (m / r) (I - u u^T / r^2).
        T* g = grad_row + std::size_t(x) * parameter_count;
        const double gx = gm[normal_x][x], gy = gm[normal_y][x];
        const double dot = nx * gx + ny * gy, f = max_normal_xy / r;
        g[normal_x] += T(scale * (f * (gx - nx * dot / (r * r)) - gx));
        g[normal_y] += T(scale * (f * (gy - ny * dot / (r * r)) - gy));
      }
    }
  });
}

/// Eq. 7 followed by the scaling to [-1, 1]: x -> 2 (log(x + 0.01) - log 0.01) / (log 1.01 - log 0.01) - 1.
/// Radiance 0 maps to -1, radiance 1 to +1 (brighter values go above 1, as in the paper).
inline double input_value(double radiance) {
  static const double l0 = std::log(0.01), range = std::log(1.01) - std::log(0.01);
  return 2 * (std::log(std::max(radiance, 0.0) + 0.01) - l0) / range - 1;
}

/// Input channels 3, 4 and 5 of entry b of `out` (an estimator preset with 6 input channels,
/// `estimator_compact_orientation`), computed from its channels 0-2 (eq. 7 space, as written by
/// photo_to_network): the local orientation of the image as the structure tensor J of the
/// channels' mean v, J = sum over a 7 x 7 window of (v_x^2, v_x v_y, v_y^2) with central
/// differences (edges clamped):
///
///     c3 = (J_xx - J_yy) / (J_xx + J_yy + 1e-6),   c4 = 2 J_xy / (J_xx + J_yy + 1e-6)
///     c5 = 2 (log(J_xx + J_yy + 1e-4) - log 1e-4) / (-log 1e-4) - 1
///
/// (c3, c4) is the direction of twice the angle of the strongest change, scaled by how much
/// stronger it is than the change across it (0 where the image has no orientation); c5 the
/// window's contrast, -1 where it is flat. Streaks such as a brushed metal's make them the
/// brushing direction, which convolutions learnt from the photographs alone did not pick up
/// (studies/README.md, "Can the estimator learn the rotation?").
///
/// The interior of each pass runs without the edge clamps, so that it vectorises; every sum adds
/// its terms in the same order as at the edges (from 0, window offsets -3 to 3), so the channels
/// do not depend on how a pixel was reached.
template <int C, class T>
void orientation_channels(tensor<C, T>& out, int b) {
  static_assert(C == 6, "orientation_channels: the tensor needs 3 photo channels and 3 orientation channels");
  const int H = out.height(), W = out.width();
  const std::size_t n = std::size_t(H) * W;
  std::vector<double> v(n), j[3];
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const T* p = out.pixel(b, y, x);
      v[std::size_t(y) * W + x] = (double(p[0]) + p[1] + p[2]) / 3;
    }
  for (auto& k : j) k.resize(n);
  for (int y = 0; y < H; ++y) {
    const double* row = v.data() + std::size_t(y) * W;
    const double* up = v.data() + std::size_t(std::max(y - 1, 0)) * W;
    const double* down = v.data() + std::size_t(std::min(y + 1, H - 1)) * W;
    double* jxx = j[0].data() + std::size_t(y) * W;
    double* jxy = j[1].data() + std::size_t(y) * W;
    double* jyy = j[2].data() + std::size_t(y) * W;
    auto gradient = [&](int x, double left, double right) {
      const double gx = (right - left) / 2, gy = (down[x] - up[x]) / 2;
      jxx[x] = gx * gx, jxy[x] = gx * gy, jyy[x] = gy * gy;
    };
    if (W == 1) {
      gradient(0, row[0], row[0]);
      continue;
    }
    gradient(0, row[0], row[1]);
    for (int x = 1; x < W - 1; ++x) gradient(x, row[x - 1], row[x + 1]);
    gradient(W - 1, row[W - 2], row[W - 1]);
  }
  // Box sums over 7 x 7 windows, rows then columns, edges clamped.
  constexpr int r = 3;
  std::vector<double> rows(n);
  for (auto& k : j) {
    for (int y = 0; y < H; ++y) {
      const double* in = k.data() + std::size_t(y) * W;
      double* o = rows.data() + std::size_t(y) * W;
      auto clamped = [&](int x) {
        double sum = 0;
        for (int d = -r; d <= r; ++d) sum += in[std::clamp(x + d, 0, W - 1)];
        o[x] = sum;
      };
      const int x0 = std::min(r, W), x1 = std::max(x0, W - r);
      for (int x = 0; x < x0; ++x) clamped(x);
      for (int x = x0; x < x1; ++x) o[x] = 0;
      for (int d = -r; d <= r; ++d)
        for (int x = x0; x < x1; ++x) o[x] += in[x + d];
      for (int x = x1; x < W; ++x) clamped(x);
    }
    for (int y = 0; y < H; ++y) {
      double* o = k.data() + std::size_t(y) * W;
      std::fill(o, o + W, 0.0);
      for (int d = -r; d <= r; ++d) {
        const double* in = rows.data() + std::size_t(std::clamp(y + d, 0, H - 1)) * W;
        for (int x = 0; x < W; ++x) o[x] += in[x];
      }
    }
  }
  static const double floor = 1e-4, log_floor = std::log(1e-4);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const std::size_t i = std::size_t(y) * W + x;
      const double trace = j[0][i] + j[2][i];
      T* p = out.pixel(b, y, x);
      p[3] = T((j[0][i] - j[2][i]) / (trace + 1e-6));
      p[4] = T(2 * j[1][i] / (trace + 1e-6));
      p[5] = T(2 * (std::log(trace + floor) - log_floor) / -log_floor - 1);
    }
}

/// Writes photograph `photo` (3-channel planar) in eq. 7 space into channels 0-2 of entry b of
/// `out`, whose size may exceed the photograph's: the extra rows and columns mirror the image
/// (reflection without repeating the edge), so a network that needs sizes in multiples of 64 sees
/// no hard border. With 6 channels, channels 3-5 are its orientation_channels.
template <int C, class T>
void photo_to_network(const image& photo, tensor<C, T>& out, int b) {
  static_assert(C == 3 || C == 6, "photo_to_network: 3 channels, or 6 with the orientation channels");
  const int W = photo.width(), H = photo.height();
  if (photo.channels() != 3) throw std::invalid_argument("photo_to_network: the image must have 3 channels");
  if (out.width() < W || out.height() < H || out.width() > 2 * W || out.height() > 2 * H)
    throw std::invalid_argument("photo_to_network: the tensor must be 1 to 2 times the image's size");
  auto mirror = [](int i, int n) { return i < n ? i : std::max(0, 2 * n - 2 - i); };
  for (int y = 0; y < out.height(); ++y)
    for (int x = 0; x < out.width(); ++x) {
      const int sx = mirror(x, W), sy = mirror(y, H);
      T* p = out.pixel(b, y, x);
      for (int c = 0; c < 3; ++c) p[c] = T(input_value(photo.at(c, sx, sy)));
    }
  if constexpr (C == 6) orientation_channels(out, b);
}

}  // namespace anisocap::network_space
