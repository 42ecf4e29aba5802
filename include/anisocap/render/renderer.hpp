#pragma once
/// @file
/// The renderer of docs/method.md section 4 and the fused image loss of docs/method.md section 5 with its gradient.
///
/// Texel-space rendering: pixel p of image i is the radiance leaving texel p towards camera c_i,
/// lit by a point light at l_i with intensity I_i:
///   R_i(p) = f(p; v, l) * max(0, n_s.l) * I_i / |l_i - p|^2,   zero where n_s.v <= 0.
/// Work is SIMD over texels (16 consecutive texels of one parameter plane per AVX-512 register) and
/// OpenMP over blocks of texels. The fused pass `loss_and_gradient` evaluates
///   L = sum_i mean_{p,c} |log(R_i(p)_c + 0.01) - log(B_i(p)_c + 0.01)|
/// and dL/d(maps) without materialising any rendered image.
///
/// Derivatives: the specular lobe's log E and the geometry term G = max(0, n.l) I / r^2 carry
/// gradients over the active non-linear parameters (sx, sy, F0, nx, ny, alpha: as many as the
/// compile-time `brdf_features` enable). E's derivatives in sx, sy, F0 and alpha are written in
/// closed form (see `detail::shade`); the normal's two components reach E and G by the chain rule
/// through h_z, the tangent frame and n.l; albedos enter linearly. The results are arrays over
/// the active parameters (G's an `ad::dual`). Gradients are formed as (dL/dR * R) * dE, which
/// stays finite when R is huge or tiny.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// The epsilon of the log image loss (docs/method.md section 5, paper eq. 5).
inline constexpr float loss_epsilon = 0.01f;

/// Where a map set lies inside the whole material: texels render at their global positions
/// (docs/method.md section 4), so a tile of a larger material renders exactly as it would in place.
struct tile_placement {
  int full_width = 0;   ///< whole material width in texels (0: the maps are the whole material)
  int full_height = 0;  ///< whole material height in texels
  int x0 = 0;           ///< column of the tile's first texel in the whole material
  int y0 = 0;           ///< row of the tile's first texel in the whole material
};

/// Options of the renderer and the fused loss.
struct render_options {
  /// Cull the specular lobe where it is negligible: a lane is culled when
  /// a'_s * exp(E) * G * I < cull_tolerance * 0.01, which changes that pixel's log loss term by at
  /// most cull_tolerance (|log(x + d + 0.01) - log(x + 0.01)| <= d / 0.01). The exp() and the
  /// specular gradient are skipped for a block of texels when every lane is culled. 0 disables.
  float cull_tolerance = 0.0f;
  /// Flush denormals to zero in the kernels' threads (see simd::flush_denormals_scope); changes
  /// results only below 1.2e-38, far under the loss epsilon 0.01.
  bool flush_denormals = true;
  /// Evaluate the fused loss and its gradient in double arithmetic (maps, targets and gradients
  /// stay float; the loss is always summed in double). The reference for float: about 2x slower.
  bool double_precision = false;
};

/// Texels are grouped in runs of this many (in flat row-major order) for `texel_groups`.
inline constexpr std::size_t texel_group_size = 64;

/// Lets the fused loss skip texels whose parameters no longer change (refine's "only texels whose
/// loss still moves"). The loss is a sum of independent per-texel terms, so a group of
/// `texel_group_size` texels whose maps are unchanged has the loss it had when last evaluated.
struct texel_groups {
  /// One entry per group: 0 skips the group (its loss is read from `loss`, its gradient entries are
  /// left as they are), non-zero evaluates it. Null: evaluate every group.
  const std::uint8_t* active = nullptr;
  /// One entry per group: each evaluated group's loss is written here. Must not be null when
  /// `active` is set.
  double* loss = nullptr;
  /// Number of groups of `texels` texels: ceil(texels / texel_group_size).
  static std::size_t count(std::size_t texels) { return (texels + texel_group_size - 1) / texel_group_size; }
  /// Number of groups for a map set.
  static std::size_t count(const material_maps& maps) { return count(maps.texel_count()); }
};

namespace detail {

/// Slots of the active non-linear parameters in the dual vectors, fixed by the features.
template <brdf_features F>
struct parameter_slots {
  static constexpr int sx = 0;
  static constexpr int sy = F.anisotropic ? 1 : -1;
  static constexpr int f0 = F.fresnel ? (F.anisotropic ? 2 : 1) : -1;
  static constexpr int nx_ = F.normal_map ? 1 + int(F.anisotropic) + int(F.fresnel) : -1;
  static constexpr int ny_ = F.normal_map ? nx_ + 1 : -1;
  static constexpr int alpha = F.anisotropic ? 1 + int(F.anisotropic) + int(F.fresnel) + 2 * int(F.normal_map) : -1;
  static constexpr std::size_t count = 1 + 2 * std::size_t(F.anisotropic) + std::size_t(F.fresnel) + 2 * std::size_t(F.normal_map);
  /// Map-plane index of each slot.
  static constexpr std::array<int, count> plane = [] {
    std::array<int, count> a{};
    a[sx] = lobe_x;
    if constexpr (F.anisotropic) { a[sy] = lobe_y; a[alpha] = rotation; }
    if constexpr (F.fresnel) a[f0] = fresnel_f0;
    if constexpr (F.normal_map) { a[nx_] = normal_x; a[ny_] = normal_y; }
    return a;
  }();
};

/// One light/camera configuration, pre-converted for the kernels.
struct configuration_constants {
  float cx, cy, cz;        ///< camera
  float lx, ly, lz;        ///< light
  float intensity[3];      ///< light intensity per channel
};

inline std::vector<configuration_constants> to_constants(const capture& cap) {
  std::vector<configuration_constants> out;
  out.reserve(cap.images.size());
  for (const auto& im : cap.images)
    out.push_back({im.camera[0], im.camera[1], im.camera[2], im.light[0], im.light[1], im.light[2],
                   {im.intensity[0], im.intensity[1], im.intensity[2]}});
  return out;
}

/// Per-texel quantities that do not depend on the configuration, computed once per block, with the
/// per-texel factors of the lobe's closed-form gradient (see `shade`).
template <brdf_features F, class V, std::size_t N>
struct texel_state {
  V px, py;                       ///< texel centre position
  V diffuse[3], specular[3];
  V nx, ny, nz;                   ///< shading normal
  V inv_s;                        ///< 1 / sqrt(1 - nx^2) (tangent normalisation)
  /// dnz/dnx, dnz/dny and d(inv_s)/dnx (inv_s does not depend on ny); 0 where clamped. The normal's
  /// two components are the only parameters that reach the lobe through the shading frame and the
  /// geometry term through n.l.
  V dnz_dnx, dnz_dny, dinv_s_dnx;
  V cos_a, sin_a;                 ///< rotation
  V inv_sx, inv_sy;               ///< 1 / sigma (inv_sy = inv_sx without anisotropy)
  V inv_sx2, inv_sy2;             ///< 1 / sigma^2
  V log_norm;                     ///< -log(pi sx sy)
  V inv_f0m1;                     ///< 1 / F0 - 1
  V d_inv_f0m1;                   ///< d(1 / F0 - 1) / dF0 = -1 / F0^2
  V d_rotation;                   ///< dE/dalpha = d_rotation * hxl * hyl / h_z^2

  /// Multiplies a sum over configurations of `shading::lobe_gradient` terms by the per-texel
  /// factors `shade` leaves out of them: 1/sx, 1/sy, d(1/F0 - 1)/dF0 and d_rotation. A zero sum
  /// stays +0 (the product plus +0), as a masked texel's gradient must be.
  template <std::size_t M>
  void apply_lobe_factors(std::array<V, M>& g) const {
    using slots = parameter_slots<F>;
    if constexpr (M > 0) {
      auto scale = [&](int p, const V& factor) { g[std::size_t(p)] = simd::fma(g[std::size_t(p)], factor, V(0)); };
      scale(slots::sx, inv_sx);
      if constexpr (F.anisotropic) {
        scale(slots::sy, inv_sy);
        scale(slots::alpha, d_rotation);
      }
      if constexpr (F.fresnel) scale(slots::f0, d_inv_f0m1);
    }
  }

  /// Loads texel parameters at flat index i (lanes i..i+lanes-1).
  void load(const material_maps& maps, std::size_t i, V px_, V py_) {
    using namespace ward_limits;
    px = px_; py = py_;
    for (int c = 0; c < 3; ++c) {
      diffuse[c] = simd::load<V>(maps.plane(diffuse_r + c) + i);
      specular[c] = simd::load<V>(maps.plane(specular_r + c) + i);
    }
    // Clamped parameters (sx below min_lobe, ...) get the gradient of the clamped value, which
    // points back into the valid range; optimisers keep parameters inside by construction.
    auto clamped = [&](int plane, V lower) { return simd::max(simd::load<V>(maps.plane(plane) + i), lower); };
    const V sx = clamped(lobe_x, V(min_lobe));
    V sy = sx;
    if constexpr (F.anisotropic) sy = clamped(lobe_y, V(min_lobe));
    inv_sx = V(1) / sx;
    inv_sy = F.anisotropic ? V(1) / sy : inv_sx;
    inv_sx2 = inv_sx * inv_sx;
    inv_sy2 = inv_sy * inv_sy;
    log_norm = -simd::log(V(std::numbers::pi_v<float>) * sx * sy);
    d_rotation = V(-2) * (inv_sx2 - inv_sy2);
    if constexpr (F.fresnel) {
      const V inv_f0 = V(1) / clamped(fresnel_f0, V(min_f0));
      inv_f0m1 = inv_f0 - V(1);
      d_inv_f0m1 = -inv_f0 * inv_f0;
    }
    if constexpr (F.normal_map) {
      nx = clamped(normal_x, V(-1));
      ny = clamped(normal_y, V(-1));
      const V z2 = V(1) - nx * nx - ny * ny, s2 = V(1) - nx * nx;
      nz = simd::sqrt(simd::max(z2, V(min_normal_z2)));
      inv_s = V(1) / simd::sqrt(simd::max(s2, V(min_normal_z2)));
      const V inv_nz = V(1) / nz;
      dnz_dnx = simd::select(z2 > V(min_normal_z2), -nx * inv_nz, V(0));
      dnz_dny = simd::select(z2 > V(min_normal_z2), -ny * inv_nz, V(0));
      dinv_s_dnx = simd::select(s2 > V(min_normal_z2), nx * inv_s * inv_s * inv_s, V(0));
    } else {
      nx = V(0); ny = V(0); nz = V(1); inv_s = V(1);
      dnz_dnx = dnz_dny = dinv_s_dnx = V(0);
    }
    if constexpr (F.anisotropic) {
      const V a = clamped(rotation, V(-1e30f));
      cos_a = simd::cos(a);
      sin_a = simd::sin(a);
    }
  }
};

/// The result of one texel block under one configuration.
template <class V, std::size_t N>
struct shading {
  V valid;                    ///< 1 where the texel is lit and seen, else 0
  V lobe;                     ///< exp(E): specular lobe times Fresnel ratio (0 if culled/invalid)
  /// The gradient of E = log(lobe) (E itself is not formed). In the slots of sx, sy, F0 and alpha
  /// it is dE/dp divided by the texel's factor (texel_state::apply_lobe_factors), which the caller
  /// applies once to its sum over configurations.
  std::array<V, N> lobe_gradient;
  /// G = max(0, n.l) / r^2 with its gradient (intensity not included); only the normal slots of
  /// the gradient are set (G depends on no other parameter), the others are left unset.
  ad::dual<V, N> geometry;
  bool specular_culled;       ///< every lane's lobe was negligible: lobe == 0, skip its gradient
};

/// Shades one block of texels under one configuration (docs/method.md sections 3-4).
///
/// The lobe's gradient is written in closed form rather than carried through forward-mode duals
/// over all N parameters: with E = log(h.h F/F0 / h_z^4) - log(pi sx sy) - q / h_z^2 and
/// q = hxl^2 / sx^2 + hyl^2 / sy^2 (hxl, hyl: h in the rotated tangent frame),
///   dE/dsx = (2 (hxl^2 / sx^2) / h_z^2 - 1) / sx     (same for sy; isotropic: 2 q / h_z^2 - 2)
///   dE/dF0 = d(1/F0 - 1)/dF0 (1 - v.h')^5 / (F/F0)
///   dE/dalpha = -2 (1/sx^2 - 1/sy^2) hxl hyl / h_z^2  (dhxl/dalpha = hyl, dhyl/dalpha = -hxl)
/// and the normal's two components go through h_z, the tangent frame and n.l by the chain rule
/// with the per-texel dnz/dn and d(inv_s)/dnx.
template <brdf_features F, class V, std::size_t N>
ANISOCAP_ALWAYS_INLINE shading<V, N> shade(const texel_state<F, V, N>& t, const configuration_constants& k, float cull_log_bound) {
  using slots = parameter_slots<F>;
  using namespace ward_limits;
  shading<V, N> s;
  // Directions to light and camera.
  const V lx = V(k.lx) - t.px, ly = V(k.ly) - t.py, lz = V(k.lz);
  const V r2 = simd::max(lx * lx + ly * ly + lz * lz, V(min_distance2));
  const V inv_r = simd::inverse_sqrt(r2);
  const V vx0 = V(k.cx) - t.px, vy0 = V(k.cy) - t.py, vz0 = V(k.cz);
  const V inv_v = simd::inverse_sqrt(simd::max(vx0 * vx0 + vy0 * vy0 + vz0 * vz0, V(min_distance2)));
  const V ux = lx * inv_r, uy = ly * inv_r, uz = lz * inv_r;      // unit l
  const V wx = vx0 * inv_v, wy = vy0 * inv_v, wz = vz0 * inv_v;  // unit v
  const V hx = ux + wx, hy = uy + wy, hz = uz + wz;               // h = l + v (world)
  const V hh = simd::max(hx * hx + hy * hy + hz * hz, V(1e-12f));

  // n.l, n.v, h_z = n.h, and the derivatives of n.l and h_z in (nx, ny).
  V cos_l = uz, cos_v = wz, hn = hz;
  V dcos_l[2] = {V(0), V(0)}, dhn[2] = {V(0), V(0)};
  if constexpr (F.normal_map) {
    cos_l = t.nx * ux + t.ny * uy + t.nz * uz;
    cos_v = t.nx * wx + t.ny * wy + t.nz * wz;
    hn = t.nx * hx + t.ny * hy + t.nz * hz;
    if constexpr (N > 0) {
      dcos_l[0] = simd::fma(uz, t.dnz_dnx, ux);
      dcos_l[1] = simd::fma(uz, t.dnz_dny, uy);
      dhn[0] = simd::fma(hz, t.dnz_dnx, hx);
      dhn[1] = simd::fma(hz, t.dnz_dny, hy);
    }
  }
  const auto lit = (cos_l > V(0)) & (cos_v > V(0));
  s.valid = simd::select(lit, V(1), V(0));
  // G = max(0, n.l) / r^2.
  const V inv_r2 = simd::select(lit, inv_r * inv_r, V(0));
  s.geometry.value = cos_l * inv_r2;
  if constexpr (N > 0 && F.normal_map) {
    s.geometry.grad[slots::nx_] = dcos_l[0] * inv_r2;
    s.geometry.grad[slots::ny_] = dcos_l[1] * inv_r2;
  }
  // Exponent q = h_x^2/sx^2 + h_y^2/sy^2 in the shading frame.
  const auto hn_above = hn > V(min_hz);
  const V hn_safe = simd::select(hn_above, hn, V(min_hz));
  const V inv_hn = simd::reciprocal(hn_safe);
  const V inv_hn2 = inv_hn * inv_hn;
  V q, qx(0), qy(0), hxl(0), hyl(0);
  V ht = hx, hb = hy, dht[2] = {V(0), V(0)}, dhb[2] = {V(0), V(0)};
  if constexpr (F.anisotropic) {
    if constexpr (F.normal_map) {
      // t = ((1,0,0) - nx n)/s, b = n x t = (0, nz, -ny)/s with s = sqrt(1 - nx^2).
      const V ht0 = hx - t.nx * hn, hb0 = t.nz * hy - t.ny * hz;
      ht = ht0 * t.inv_s;
      hb = hb0 * t.inv_s;
      if constexpr (N > 0) {
        dht[0] = simd::fma(ht0, t.dinv_s_dnx, -simd::fma(t.nx, dhn[0], hn) * t.inv_s);
        dht[1] = -(t.nx * dhn[1]) * t.inv_s;
        dhb[0] = simd::fma(hb0, t.dinv_s_dnx, t.dnz_dnx * hy * t.inv_s);
        dhb[1] = simd::fma(t.dnz_dny, hy, -hz) * t.inv_s;
      }
    }
    hxl = t.cos_a * ht + t.sin_a * hb;
    hyl = t.cos_a * hb - t.sin_a * ht;
    qx = hxl * hxl * t.inv_sx2;
    qy = hyl * hyl * t.inv_sy2;
    q = qx + qy;
  } else {
    // Isotropic: h_x^2 + h_y^2 in the shading frame = |h|^2 - h_z^2 = |h x n|^2, no tangent frame
    // needed; the cross product avoids the cancellation of |h|^2 - h_z^2 when h is near n.
    if constexpr (F.normal_map) {
      const V cx = hy * t.nz - hz * t.ny, cy = hz * t.nx - hx * t.nz, cz = hx * t.ny - hy * t.nx;
      q = (cx * cx + cy * cy + cz * cz) * t.inv_sx2;
    } else {
      q = (hx * hx + hy * hy) * t.inv_sx2;
    }
  }
  // Fresnel ratio F/F0 = 1 + (1/F0 - 1)(1 - v.h')^5, with v.h' = |l + v| / 2 for unit l and v.
  V log_arg = hh * inv_hn2 * inv_hn2, ratio(1), m5(0);
  if constexpr (F.fresnel) {
    const V m = simd::max(V(1) - V(0.5) * simd::sqrt(hh), V(0));
    const V m2 = m * m;
    m5 = m2 * m2 * m;
    ratio = V(1) + t.inv_f0m1 * m5;
    log_arg = log_arg * ratio;
  }
  // E = -q / h_z^2 + log((h.h) * F/F0 / h_z^4) - log(pi sx sy), and the lobe exp(E) taken as
  // (h.h) F/F0 / h_z^4 * exp(-log(pi sx sy) - q / h_z^2): one exp and no log. The product stays
  // below 2e36 (h.h <= 4, h_z >= 1e-6, F0 >= 1e-4, sx, sy >= 1e-4), and E >= max_log_lobe reads as
  // the lobe at or past exp(max_log_lobe).
  const V lobe_raw = log_arg * simd::exp(t.log_norm - q * inv_hn2);
  const auto e_below = lobe_raw < V(max_lobe);
  const V lobe = simd::select(e_below, lobe_raw, V(max_lobe));
  if constexpr (N > 0) {
    // Zero where E is clamped at max_log_lobe.
    const V gate = simd::select(e_below, V(1), V(0));
    const V gate_hn2 = gate * inv_hn2;
    if constexpr (F.anisotropic) {
      s.lobe_gradient[slots::sx] = simd::fma(V(2) * gate_hn2, qx, -gate);
      s.lobe_gradient[slots::sy] = simd::fma(V(2) * gate_hn2, qy, -gate);
      s.lobe_gradient[slots::alpha] = gate_hn2 * hxl * hyl;
    } else {
      s.lobe_gradient[slots::sx] = simd::fma(V(2) * gate_hn2, q, V(-2) * gate);
    }
    if constexpr (F.fresnel) s.lobe_gradient[slots::f0] = gate * m5 / ratio;
    if constexpr (F.normal_map) {
      // dE/dh_z through log(1 / h_z^4) and -q / h_z^2 (zero where h_z is clamped), and dE/dq.
      V de_dhn = simd::select(hn_above, gate * inv_hn * simd::fma(V(2) * q, inv_hn2, V(-4)), V(0));
      const V de_dq = -gate_hn2;
      V de_dht(0), de_dhb(0);
      if constexpr (F.anisotropic) {
        // dq/dht and dq/dhb through the rotation into (hxl, hyl).
        const V ax = V(2) * hxl * t.inv_sx2, ay = V(2) * hyl * t.inv_sy2;
        de_dht = de_dq * (ax * t.cos_a - ay * t.sin_a);
        de_dhb = de_dq * (ax * t.sin_a + ay * t.cos_a);
      } else {
        // q = (h.h - h_z^2) / sx^2 depends on the unclamped h_z.
        de_dhn = simd::fma(de_dq * V(-2) * t.inv_sx2, hn, de_dhn);
      }
      for (int p = 0; p < 2; ++p) {
        V g = de_dhn * dhn[p];
        if constexpr (F.anisotropic) g = simd::fma(de_dht, dht[p], simd::fma(de_dhb, dhb[p], g));
        s.lobe_gradient[p == 0 ? slots::nx_ : slots::ny_] = g;
      }
    }
  }
  // Culling test: a'_s <= 1, so the lobe's contribution is below exp(E) * G per unit intensity.
  s.specular_culled = false;
  if (cull_log_bound > -1e30f) {
    const auto negligible = simd::log(simd::max(lobe * s.geometry.value, V(1e-30f))) < V(cull_log_bound);
    if (simd::all(negligible | !lit)) {
      s.specular_culled = true;
      s.lobe = V(0);
      return s;
    }
  }
  s.lobe = simd::select(lit, lobe, V(0));
  return s;
}

}  // namespace detail

/// The target images as the fused loss reads them, B' = max(B, f) + 0.01 (f: the image's floor,
/// below), computed once per capture, with the pixels each image's loss uses.
///
/// Masks: a pixel with mask 0 is left out of the loss exactly: it adds 0 to the loss and 0 to every
/// gradient entry, whatever its target holds. A mask value m in (0, 1] weighs the pixel's terms by
/// m (a pixel the photograph saw less sharply, calibration/rectify.hpp's confidence); values above
/// 1 count as 1. Image i's loss is the m-weighted mean over its pixels (and channels), so that each
/// photograph weighs the same however much of it is masked: its terms carry the weight
/// m(p) T / U_i, with T the texels and U_i the sum of m over the whole image. A crop keeps the whole
/// image's weights, so crops' losses add up, by area, to the whole image's.
///
/// Floors: an image's floor f >= 0 is the level below which its values are not measurements (a
/// JPEG's darkest codes, where compression has smoothed the sensor noise clipped at black and
/// left it biased upwards). Both the photograph and the render count as max(value, f): a pixel
/// whose photograph and render both lie below f adds nothing, and a render below f gets no
/// gradient. f = 0 is the plain loss.
struct loss_targets {
  /// One 3-channel planar image per capture image: max(B, f) + 0.01, every value >= 0.01 (a masked
  /// pixel holds 0.01; its value never enters the loss). The loss compares log(R + 0.01) with log B'.
  std::vector<image> images;
  /// Empty: every pixel is used with weight 1. Otherwise one 1-channel image per capture image of
  /// per-pixel weights in [0, 1]: 0 = left out.
  std::vector<image> masks;
  /// With masks, per capture image k and texel group g (entry k * groups + g, groups =
  /// texel_groups' count for the targets' size): non-zero where image k's mask is 1 on every texel
  /// of group g, so that the loss skips reading it there (the results are the same bits). Empty, or
  /// 0 for an entry: that part of the mask is read. make_loss_targets and crop_loss_targets set it;
  /// a photograph's mask is all ones away from its clipped or masked pixels.
  std::vector<std::uint8_t> mask_all_ones;
  /// Per capture image, T / U_i (1 without masks); empty means 1 for every image.
  std::vector<double> weights;
  /// Per capture image, its floor in the photographs' units (see above); empty means 0 for every image.
  std::vector<float> floors;
  int width = 0, height = 0;
};

namespace detail {

/// loss_targets::mask_all_ones of a set of masks of `texels` texels each (values already in [0, 1]).
inline std::vector<std::uint8_t> all_ones_mask_groups(const std::vector<image>& masks, std::size_t texels) {
  const std::size_t groups = texel_groups::count(texels);
  std::vector<std::uint8_t> flags(masks.size() * groups, 0);
  for (std::size_t k = 0; k < masks.size(); ++k) {
    const float* m = masks[k].plane(0);
    for (std::size_t g = 0; g < groups; ++g)
      flags[k * groups + g] = std::all_of(m + g * texel_group_size, m + std::min(texels, (g + 1) * texel_group_size),
                                          [](float v) { return v == 1.0f; });
  }
  return flags;
}

}  // namespace detail

/// The targets of the window [x0, x0 + width) x [y0, y0 + height) of `from`, written into `out`
/// (whose images are reused when they already have that size): the targets of a tile, for a loss
/// evaluated with the matching tile_placement.
inline void crop_loss_targets(const loss_targets& from, int x0, int y0, int width, int height, loss_targets& out) {
  if (x0 < 0 || y0 < 0 || width <= 0 || height <= 0 || x0 + width > from.width || y0 + height > from.height)
    throw std::invalid_argument("crop_loss_targets: window outside the targets");
  if (out.width != width || out.height != height || out.images.size() != from.images.size() ||
      out.masks.size() != from.masks.size()) {
    out.images.assign(from.images.size(), image(width, height, 3));
    out.masks.assign(from.masks.size(), image(width, height, 1));
    out.width = width;
    out.height = height;
  }
  out.weights = from.weights;
  out.floors = from.floors;
  auto copy_window = [&](const image& src, image& dst, int c) {
    for (int y = 0; y < height; ++y)
      std::copy_n(src.plane(c) + std::size_t(y0 + y) * from.width + x0, width, dst.plane(c) + std::size_t(y) * width);
  };
  for (std::size_t k = 0; k < from.images.size(); ++k)
    for (int c = 0; c < 3; ++c) copy_window(from.images[k], out.images[k], c);
  for (std::size_t k = 0; k < from.masks.size(); ++k) copy_window(from.masks[k], out.masks[k], 0);
  // The window's texel groups are not the source's: its flags are taken from its own masks.
  out.mask_all_ones = detail::all_ones_mask_groups(out.masks, std::size_t(width) * std::size_t(height));
}

/// Precomputes the loss targets from the input photographs (all of the maps' size, 3 channels) and
/// their masks (empty: every pixel used; else one 1-channel image per photograph of its size,
/// 0 = left out, a value in (0, 1) = used with that weight, above 1 = 1) and floors (empty: none;
/// else one level >= 0 per photograph, in its units: see loss_targets). Throws
/// std::invalid_argument on a NaN or infinite pixel where the mask uses it, on masks or floors of
/// the wrong number or size, on a negative or non-finite floor, and on an image whose every pixel
/// is masked; negative values count as 0. Masked pixels get the target 0.01 (their value never
/// enters the loss).
inline loss_targets make_loss_targets(const std::vector<image>& photos, const std::vector<image>& masks = {},
                                      const std::vector<float>& floors = {}) {
  loss_targets t;
  if (photos.empty()) throw std::invalid_argument("make_loss_targets: no images");
  t.width = photos[0].width();
  t.height = photos[0].height();
  if (!masks.empty() && masks.size() != photos.size())
    throw std::invalid_argument("make_loss_targets: " + std::to_string(masks.size()) + " masks for " + std::to_string(photos.size()) + " images");
  if (!floors.empty() && floors.size() != photos.size())
    throw std::invalid_argument("make_loss_targets: " + std::to_string(floors.size()) + " floors for " + std::to_string(photos.size()) + " images");
  for (std::size_t i = 0; i < floors.size(); ++i)
    if (!(floors[i] >= 0.0f && std::isfinite(floors[i])))
      throw std::invalid_argument("make_loss_targets: the floor of image " + std::to_string(i) + " must be finite and >= 0 (got " +
                                  std::to_string(floors[i]) + ")");
  if (std::any_of(floors.begin(), floors.end(), [](float f) { return f > 0.0f; })) t.floors = floors;
  for (std::size_t i = 0; i < photos.size(); ++i) {
    const image& p = photos[i];
    if (p.width() != t.width || p.height() != t.height || p.channels() != 3)
      throw std::invalid_argument("make_loss_targets: image " + std::to_string(i) + " has a different size or channel count");
    const float* mask = nullptr;
    double weight = 1.0;
    if (!masks.empty()) {
      const image& m = masks[i];
      if (m.width() != t.width || m.height() != t.height || m.channels() != 1)
        throw std::invalid_argument("make_loss_targets: mask " + std::to_string(i) + " is not a 1-channel image of the photographs' size");
      mask = m.plane(0);
      image stored(t.width, t.height, 1);
      double used = 0;
      for (std::size_t k = 0; k < m.pixel_count(); ++k) {
        if (!(mask[k] >= 0.0f) || !std::isfinite(mask[k]))
          throw std::invalid_argument("make_loss_targets: mask " + std::to_string(i) + " has a negative or non-finite value (" +
                                      std::to_string(mask[k]) + ") at pixel (" + std::to_string(k % std::size_t(m.width())) + ", " +
                                      std::to_string(k / std::size_t(m.width())) + ")");
        stored.plane(0)[k] = std::min(mask[k], 1.0f);
        used += stored.plane(0)[k];
      }
      if (used == 0) throw std::invalid_argument("make_loss_targets: every pixel of image " + std::to_string(i) + " is masked");
      weight = double(m.pixel_count()) / used;
      t.masks.push_back(std::move(stored));
    }
    t.weights.push_back(weight);
    const float floor = t.floors.empty() ? 0.0f : t.floors[i];
    image l(p.width(), p.height(), 3);
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < p.pixel_count(); ++k) {
        if (mask && mask[k] == 0.0f) {
          l.plane(c)[k] = loss_epsilon;
          continue;
        }
        const float v = p.plane(c)[k];
        if (!std::isfinite(v))
          throw std::invalid_argument("make_loss_targets: image " + std::to_string(i) + " has a non-finite value (" +
                                      std::to_string(v) + ") at pixel (" + std::to_string(k % std::size_t(p.width())) + ", " +
                                      std::to_string(k / std::size_t(p.width())) + "), channel " + std::to_string(c));
        l.plane(c)[k] = std::max(v, floor) + loss_epsilon;
      }
    t.images.push_back(std::move(l));
  }
  if (!t.masks.empty()) t.mask_all_ones = detail::all_ones_mask_groups(t.masks, std::size_t(t.width) * std::size_t(t.height));
  return t;
}

namespace detail {

inline tile_placement resolve(const tile_placement& t, const material_maps& maps) {
  tile_placement r = t;
  if (r.full_width == 0) { r.full_width = maps.width(); r.full_height = maps.height(); r.x0 = 0; r.y0 = 0; }
  if (r.x0 < 0 || r.y0 < 0 || r.x0 + maps.width() > r.full_width || r.y0 + maps.height() > r.full_height)
    throw std::invalid_argument("tile_placement: the tile lies outside the material");
  return r;
}

/// Texel positions (global, docs/method.md section 4) for the lanes starting at flat index i.
template <class V>
inline void texel_positions(std::size_t i, int width, const tile_placement& t, V& px, V& py) {
  using S = simd::scalar_t<V>;
  const float n = float(std::max(t.full_width, t.full_height));
  alignas(simd::alignment) S xs[simd::lanes_v<V>], ys[simd::lanes_v<V>];
  for (std::size_t l = 0; l < simd::lanes_v<V>; ++l) {
    const std::size_t k = i + l;
    const int x = int(k % std::size_t(width)) + t.x0, y = int(k / std::size_t(width)) + t.y0;
    xs[l] = (S(x) + S(0.5) - S(0.5) * S(t.full_width)) / S(n);
    ys[l] = (S(0.5) * S(t.full_height) - (S(y) + S(0.5))) / S(n);
  }
  px = simd::load<V>(xs);
  py = simd::load<V>(ys);
}

inline float cull_log_bound(const render_options& o) {
  return o.cull_tolerance > 0 ? std::log(o.cull_tolerance * loss_epsilon) : -1e31f;
}

}  // namespace detail

/// Sets the parameters a kernel without some features ignores to the values under which the full
/// kernel renders exactly as that kernel: without anisotropy sy = sx and alpha = 0; without
/// Fresnel F0 = 1 (F / F0 = 1); without a normal map flat normals. Optimisers that ran a reduced
/// kernel call this on their result so that every renderer agrees with what was fitted.
inline void restrict_to_features(material_maps& maps, const brdf_features& f) {
  const std::size_t n = maps.texel_count();
  if (!f.anisotropic)
    for (std::size_t i = 0; i < n; ++i) { maps.plane(lobe_y)[i] = maps.plane(lobe_x)[i]; maps.plane(rotation)[i] = 0.0f; }
  if (!f.fresnel)
    for (std::size_t i = 0; i < n; ++i) maps.plane(fresnel_f0)[i] = 1.0f;
  if (!f.normal_map)
    for (std::size_t i = 0; i < n; ++i) maps.plane(normal_x)[i] = maps.plane(normal_y)[i] = 0.0f;
}

/// Renders every configuration of `cap` for the map set (one 3-channel image per configuration).
/// V picks the path: `simd::batch<float>` (default), `float` (the scalar build of the same template),
/// or `simd::batch<double>` / `double` (arithmetic in double, maps and images stay float).
template <brdf_features F = all_features, class V = simd::batch<float>>
std::vector<image> render(const material_maps& maps, const capture& cap, const tile_placement& placement = {},
                          const render_options& options = {}) {
  constexpr std::size_t L = simd::lanes_v<V>;
  const tile_placement tp = detail::resolve(placement, maps);
  const auto configs = detail::to_constants(cap);
  std::vector<image> out;
  for (std::size_t i = 0; i < configs.size(); ++i) out.emplace_back(maps.width(), maps.height(), 3);
  const std::size_t texels = maps.texel_count();
  const std::size_t blocks = (texels + L - 1) / L;
  const float cull = detail::cull_log_bound(options);
  const float inv_pi = 1.0f / std::numbers::pi_v<float>;
#pragma omp parallel
  {
  const simd::flush_denormals_scope denormals(options.flush_denormals);
#pragma omp for schedule(static)
  for (std::ptrdiff_t b = 0; b < std::ptrdiff_t(blocks); ++b) {
    const std::size_t i = std::size_t(b) * L;
    V px, py;
    detail::texel_positions<V>(i, maps.width(), tp, px, py);
    detail::texel_state<F, V, 0> t;
    t.load(maps, i, px, py);
    for (std::size_t k = 0; k < configs.size(); ++k) {
      const auto s = detail::shade<F, V, 0>(t, configs[k], cull);
      for (int c = 0; c < 3; ++c) {
        const V brdf = t.diffuse[c] * V(inv_pi) + t.specular[c] * s.lobe;
        // Padded tail lanes write into the plane's padding (plane_stride is a multiple of 16).
        simd::store<V>(out[k].plane(c) + i, brdf * s.geometry.value * V(configs[k].intensity[c]));
      }
    }
  }
  }  // omp parallel
  return out;
}

/// The fused pass: image loss (docs/method.md section 5) of the map set against the targets and, when `gradient`
/// is not null, dL/d(maps) written into it (same size as maps; planes a feature disables get 0).
/// No rendered image is materialised. Returns the loss
///   sum_i mean_{p, c} |log(R_i(p)_c + 0.01) - log(B_i(p)_c + 0.01)|,
/// the mean over the pixels each image's mask uses (loss_targets: masked pixels add exact zeros),
/// R and B taken as max(R, f_i) and max(B, f_i) where image i has a floor f_i.
/// `groups` (optional) skips unchanged texel groups and reports per-group losses (texel_groups).
/// With `options.double_precision`, a float V dispatches to the double kernel.
template <brdf_features F = all_features, class V = simd::batch<float>>
double loss_and_gradient(const material_maps& maps, const capture& cap, const loss_targets& targets,
                         material_maps* gradient, const tile_placement& placement = {},
                         const render_options& options = {}, const texel_groups* groups = nullptr) {
  using slots = detail::parameter_slots<F>;
  constexpr std::size_t L = simd::lanes_v<V>;
  constexpr std::size_t N = slots::count;
  static_assert(texel_group_size % L == 0, "a texel group holds whole blocks");
  if constexpr (std::is_same_v<simd::scalar_t<V>, float>) {
    if (options.double_precision) {
      using W = std::conditional_t<(L > 1), simd::batch<double>, double>;
      render_options o = options;
      o.double_precision = false;
      return loss_and_gradient<F, W>(maps, cap, targets, gradient, placement, o, groups);
    }
  }
  if (targets.images.size() != cap.images.size())
    throw std::invalid_argument("loss_and_gradient: " + std::to_string(cap.images.size()) + " configurations but " +
                                std::to_string(targets.images.size()) + " target images");
  if (targets.width != maps.width() || targets.height != maps.height())
    throw std::invalid_argument("loss_and_gradient: target images and maps differ in size");
  if ((!targets.masks.empty() && targets.masks.size() != cap.images.size()) ||
      (!targets.weights.empty() && targets.weights.size() != cap.images.size()) ||
      (!targets.floors.empty() && targets.floors.size() != cap.images.size()))
    throw std::invalid_argument("loss_and_gradient: the targets' masks, weights or floors do not match the configurations");
  const std::size_t group_count = texel_groups::count(maps);
  if (!targets.mask_all_ones.empty() && targets.mask_all_ones.size() != targets.masks.size() * group_count)
    throw std::invalid_argument("loss_and_gradient: the targets' mask_all_ones has " + std::to_string(targets.mask_all_ones.size()) +
                                " entries, not one per image and texel group (" + std::to_string(targets.masks.size() * group_count) + ")");
  if (gradient && (gradient->width() != maps.width() || gradient->height() != maps.height()))
    throw std::invalid_argument("loss_and_gradient: gradient maps differ in size");
  if (groups && groups->active && !groups->loss)
    throw std::invalid_argument("loss_and_gradient: texel_groups.active needs texel_groups.loss");
  const tile_placement tp = detail::resolve(placement, maps);
  const auto configs = detail::to_constants(cap);
  const std::size_t texels = maps.texel_count();
  const float cull = detail::cull_log_bound(options);
  using S = simd::scalar_t<V>;
  const S inv_pi = S(1) / std::numbers::pi_v<S>;
  // Mean over pixels and the 3 channels of each image.
  const S scale = S(1) / (S(3) * S(texels));
  const std::uint8_t* active = groups ? groups->active : nullptr;
  double* group_loss = groups ? groups->loss : nullptr;
  double loss = 0;
  // Prefetch distance: the next block, at least one cache line (16 floats) on.
  constexpr std::size_t prefetch_ahead = L < 16 ? 16 : L;
  const std::uint8_t* all_ones = targets.mask_all_ones.empty() ? nullptr : targets.mask_all_ones.data();
#pragma omp parallel
  {
  const simd::flush_denormals_scope denormals(options.flush_denormals);
#pragma omp for schedule(static) reduction(+ : loss)
  for (std::ptrdiff_t g = 0; g < std::ptrdiff_t(group_count); ++g) {
    if (active && !active[g]) {
      loss += group_loss[g];
      continue;
    }
    V loss_acc(0);
    const std::size_t group_end = std::min(texels, std::size_t(g + 1) * texel_group_size);
    for (std::size_t i = std::size_t(g) * texel_group_size; i < group_end; i += L) {
    V px, py;
    detail::texel_positions<V>(i, maps.width(), tp, px, py);
    // Lanes past the last texel (padding of the final block) get weight 0.
    const bool partial = i + L > texels;
    const auto in_range = partial ? simd::iota<V>(S(0)) < V(S(texels - i)) : V(0) == V(0);
    const V lane_weight = simd::select(in_range, V(scale), V(0));
    detail::texel_state<F, V, N> t;
    t.load(maps, i, px, py);
    V g_diffuse[3] = {V(0), V(0), V(0)}, g_specular[3] = {V(0), V(0), V(0)};
    std::array<V, N> g_dual;
    g_dual.fill(V(0));
    const V kd[3] = {t.diffuse[0] * V(inv_pi), t.diffuse[1] * V(inv_pi), t.diffuse[2] * V(inv_pi)};
    // The targets are one plane per image and channel, more streams than the hardware prefetchers
    // follow: each image's lines of the next block are asked for while this block shades it.
    const bool prefetch = i + prefetch_ahead < texels;
    for (std::size_t k = 0; k < configs.size(); ++k) {
      const bool read_mask = !targets.masks.empty() && !(all_ones && all_ones[k * group_count + std::size_t(g)]);
      if (prefetch) {
        for (int c = 0; c < 3; ++c) simd::prefetch(targets.images[k].plane(c) + i + prefetch_ahead);
        if (read_mask) simd::prefetch(targets.masks[k].plane(0) + i + prefetch_ahead);
      }
      const auto s = detail::shade<F, V, N>(t, configs[k], cull);
      const V geometry = s.geometry.value;
      // This image's weight per lane: m T / U_k, and 0 where its mask leaves the pixel out.
      V weight = targets.weights.empty() ? lane_weight : lane_weight * V(S(targets.weights[k]));
      // The lanes this image's loss uses: inside the maps and, with masks, not masked out.
      bool masked = partial;
      auto used = in_range;
      if (read_mask) {
        masked = true;
        const V m = simd::load<V>(targets.masks[k].plane(0) + i);
        used = used & (m != V(0));
        weight = simd::select(used, weight * m, V(0));
      }
      const bool floored = !targets.floors.empty() && targets.floors[k] > 0.0f;
      const V floor(S(floored ? targets.floors[k] : 0.0f));
      V w_spec(0), w_geom(0);  // sum_c dL/dR_c * specular_c / ... (see below)
      // The three channels' loss terms take one log: with R' = R + 0.01 and B' the target,
      //   sum_c |log R'_c - log B'_c| = log(prod_c max(R'_c, B'_c) / prod_c min(R'_c, B'_c)).
      // A masked lane's factors are 1 whatever its target (its terms add +0, and its weight 0
      // zeroes its gradient), so no value of a masked target can reach the results; so are the
      // lanes past the last texel, which read the planes' padding.
      V above_product(1), below_product(1);
      V rendered[3], target[3];
      for (int c = 0; c < 3; ++c) {
        const V intensity(configs[k].intensity[c]);
        const V spec = t.specular[c] * s.lobe;                 // a'_s exp(E)
        const V albedo_sum = kd[c] + spec;
        const V lit_intensity = geometry * intensity;
        V radiance = albedo_sum * lit_intensity;               // R_c
        V below_floor_weight = weight;                         // 0 where the render lies under the floor
        if (floored) {
          below_floor_weight = simd::select(radiance < floor, V(0), weight);
          radiance = simd::max(radiance, floor);
        }
        rendered[c] = radiance + V(loss_epsilon);
        target[c] = simd::load<V>(targets.images[k].plane(c) + i);
        V high = simd::max(rendered[c], target[c]), low = simd::min(rendered[c], target[c]);
        if (masked) {
          high = simd::select(used, high, V(1));
          low = simd::select(used, low, V(1));
        }
        above_product *= high;
        below_product *= low;
        // dL/dR_c = sign(R'_c - B'_c) / R'_c * weight, 0 below the floor (max(R, f) is flat there).
        const V dl = simd::select(rendered[c] >= target[c], below_floor_weight, -below_floor_weight) *
                     simd::reciprocal(rendered[c]);
        const V dl_gi = dl * lit_intensity;
        g_diffuse[c] += dl_gi;             // times 1/pi once the configurations are summed
        g_specular[c] += dl_gi * s.lobe;
        w_spec += dl_gi * spec;            // dR_c/dE = spec * G * I
        w_geom += dl * albedo_sum * intensity;  // dR_c/dG = (kd + spec) * I
      }
      // Both products lie in [1e-6, 1e30) unless a render is absurdly bright (R' / B' past 1e10):
      // then the three logs are taken one by one.
      if (simd::all(above_product < V(S(1e30)))) {
        loss_acc += simd::log_positive(above_product / below_product) * weight;
      } else {
        for (int c = 0; c < 3; ++c) {
          V term = simd::abs(simd::log_positive(rendered[c]) - simd::log_positive(target[c]));
          if (masked) term = simd::select(used, term, V(0));
          loss_acc += term * weight;
        }
      }
      if constexpr (N > 0) {
        if (!s.specular_culled)
          for (std::size_t p = 0; p < N; ++p) g_dual[p] = simd::fma(w_spec, s.lobe_gradient[p], g_dual[p]);
        if constexpr (F.normal_map)
          for (int p : {slots::nx_, slots::ny_}) g_dual[p] = simd::fma(w_geom, s.geometry.grad[p], g_dual[p]);
      }
    }
    if (gradient) {
      t.apply_lobe_factors(g_dual);
      for (int c = 0; c < 3; ++c) {
        simd::store<V>(gradient->plane(diffuse_r + c) + i, g_diffuse[c] * V(inv_pi));
        simd::store<V>(gradient->plane(specular_r + c) + i, g_specular[c]);
      }
      for (int pl : {lobe_x, lobe_y, fresnel_f0, normal_x, normal_y, rotation}) {
        bool active_plane = false;
        for (std::size_t p = 0; p < N; ++p) active_plane |= slots::plane[p] == pl;
        if (!active_plane) simd::store<V>(gradient->plane(pl) + i, V(0));
      }
      for (std::size_t p = 0; p < N; ++p) {
        // Clamped parameters (sx below min_lobe, ...) get the gradient of the clamped value, which
        // points back into the valid range; optimisers keep parameters inside by construction.
        simd::store<V>(gradient->plane(slots::plane[p]) + i, g_dual[p]);
      }
    }
    }  // blocks of the group
    const double l = double(simd::reduce_add(loss_acc));
    if (group_loss) group_loss[g] = l;
    loss += l;
  }
  }  // omp parallel
  return loss;
}

/// The image loss of `loss_and_gradient` over whole maps, without a gradient, for a feature set chosen at run
/// time: the kernel specialised for `features` (with_features), so a stage that disabled a feature is scored
/// the way it was fitted.
inline double image_loss(const material_maps& maps, const capture& cap, const loss_targets& targets,
                         const brdf_features& features, const render_options& options = {}) {
  return with_features(features,
                       [&]<brdf_features F>() { return loss_and_gradient<F>(maps, cap, targets, nullptr, {}, options); });
}

}  // namespace anisocap
