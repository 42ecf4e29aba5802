#pragma once
/// @file
/// The canonical form of the lobe parameters (docs/method.md section 1): the Ward lobe with
/// (sigma_x, sigma_y, alpha) is the same function as with (sigma_y, sigma_x, alpha + pi/2), and
/// alpha is pi-periodic, so every texel has one representative with sigma_x >= sigma_y and
/// alpha in [-pi/2, pi/2). Exports need it (the tangent then names the wide axis, as GGX-family
/// anisotropy parameters expect), and rotation maps in that form have no spurious pi/2 jumps.
#include <cmath>
#include <numbers>

#include "anisocap/brdf/material_maps.hpp"

namespace anisocap {

/// The canonical lobe of one texel.
struct canonical_lobe {
  float sx;     ///< the wider lobe width
  float sy;     ///< the narrower lobe width (sy <= sx)
  float alpha;  ///< rotation of the wide axis from the tangent, in [-pi/2, pi/2) (as floats)
};

/// Canonical form of (sx, sy, alpha): swaps the widths and adds pi/2 when sy > sx, then wraps alpha
/// into [-pi/2, pi/2). Renders identically (up to float rounding of cos and sin of alpha).
inline canonical_lobe make_canonical(float sx, float sy, float alpha) {
  constexpr double pi = std::numbers::pi;
  double a = alpha;
  if (sy > sx) {
    const float t = sx;
    sx = sy, sy = t;
    a += pi / 2;
  }
  a -= pi * std::floor((a + pi / 2) / pi);
  float af = float(a);
  // float(pi/2) lies above pi/2: a value that rounds onto it belongs at the lower end.
  constexpr float half_pi = float(pi / 2);
  if (af >= half_pi) af = float(a - pi);
  if (af < -half_pi) af = -half_pi;
  return {sx, sy, af};
}

/// Whether (sx, sy, alpha) is already in canonical form.
inline bool is_canonical(float sx, float sy, float alpha) {
  constexpr float half_pi = float(std::numbers::pi / 2);
  return sx >= sy && alpha >= -half_pi && alpha < half_pi;
}

/// Brings every texel of `maps` into canonical form (make_canonical); other planes are unchanged.
inline void canonicalise(material_maps& maps) {
  float* sx = maps.plane(lobe_x);
  float* sy = maps.plane(lobe_y);
  float* alpha = maps.plane(rotation);
  for (std::size_t i = 0; i < maps.texel_count(); ++i) {
    const canonical_lobe c = make_canonical(sx[i], sy[i], alpha[i]);
    sx[i] = c.sx, sy[i] = c.sy, alpha[i] = c.alpha;
  }
}

}  // namespace anisocap
