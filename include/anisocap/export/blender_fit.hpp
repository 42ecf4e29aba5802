#pragma once
/// @file
/// The inputs of Blender's Principled BSDF whose meaning changed in Blender 4.0, for Blender 3.x.
/// export/conversion.hpp (`to_blender`) writes the 4.x inputs: F0 through `IOR`, a colour
/// `Specular Tint` on F0, a base colour darkened under the specular layer. Cycles 3.x (the
/// "principled v1" closure of intern/cycles/kernel/svm/closure.h) reads them differently:
///   - `IOR` drives transmission only. The specular lobe's F0 is 0.08 `Specular` and its Fresnel
///     curve is that of the dielectric with the same F0, rising from F0 to white at grazing angles
///     (the curve `to_blender`'s IOR gives in 4.x): so `Specular` = F0 / 0.08.
///   - `Specular Tint` is a number t in [0, 1]: F0_c = 0.08 `Specular` ((1 - t) + t B_c / lum(B)),
///     B the base colour and lum its Rec. 709 luminance. A specular colour can only be grey plus a
///     multiple of the base colour's hue.
///   - `Metallic` m mixes in a lobe with F0 = B (same Fresnel curve) and weighs the diffuse by 1 - m.
///   - The diffuse is not darkened under the specular layer (and is Disney's diffuse, which equals
///     Lambert's at normal incidence), so the base colour is a_d itself.
/// Per texel we take the better of two fits, compared by their error at normal incidence in BRDF
/// units (the specular colour error times the lobe's peak, the diffuse error / pi):
///   dielectric: m = 0, B = a_d, (0.08 `Specular` (1 - t), 0.08 `Specular` t) the non-negative
///     least-squares fit of a'_s,c = a + b B_c / lum(B) (Cycles' Fresnel curve then rises from
///     F0 = a'_s to white at grazing angles, Ward's from a'_s to a'_s / F0: brighter where Ward's
///     F0 exceeds a'_s; a smaller `Specular` fitted to the curve cost more at normal incidence than
///     it gained at grazing angles in the Cycles renders, docs/results.md);
///   metal: m = 1, B = a'_s (exact specular colour), the diffuse a_d lost.
/// The lobe (Roughness, Anisotropic, Anisotropic Rotation, Tangent, Normal) is the same in 3.x and 4.x.
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "anisocap/brdf/ward.hpp"
#include "anisocap/export/target_models.hpp"

namespace anisocap::exports {

/// The Blender 3.x inputs that differ from blender_texel's 4.x ones.
struct blender3_texel {
  rgb base_color{};        ///< Base Color (linear), not darkened under the specular layer
  double specular = 0.5;   ///< Specular: F0 = 0.08 Specular (values above 1 allowed from a texture)
  double specular_tint = 0;///< Specular Tint in [0, 1]: F0 tinted towards the base colour's hue
  double metallic = 0;     ///< Metallic: 0 (dielectric fit) or 1 (metal fit)
};

/// Rec. 709 luminance, as Cycles' linear_rgb_to_gray in the default (linear Rec. 709) scene space.
inline double rec709_luminance(const rgb& c) { return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]; }

/// The Blender 3.x inputs of a texel (file comment). `f0` is the F0 the 4.x export sets through
/// the IOR (Fresnel curve shape), reused so that both versions share the curve.
inline blender3_texel to_blender3(const ward_parameters<float>& p, double f0) {
  const rgb s{p.specular[0], p.specular[1], p.specular[2]};
  rgb d;
  for (int c = 0; c < 3; ++c) d[c] = std::clamp<double>(p.diffuse[c], 0.0, 1.0);
  // Dielectric: s_c ~ a + b t_c, t_c = d_c / lum(d) (t = 1 where the base is black), a, b >= 0.
  const double lum = rec709_luminance(d);
  rgb t;
  for (int c = 0; c < 3; ++c) t[c] = lum > 0 ? d[c] / lum : 1.0;
  auto residual = [&](double a, double b) {
    double r = 0;
    for (int c = 0; c < 3; ++c) r += std::abs(a + b * t[c] - s[c]);
    return r;
  };
  double a = (s[0] + s[1] + s[2]) / 3, b = 0;  // grey only
  const double tm = (t[0] + t[1] + t[2]) / 3;
  double stt = 0, sts = 0;
  for (int c = 0; c < 3; ++c) stt += (t[c] - tm) * (t[c] - tm), sts += (t[c] - tm) * (s[c] - a);
  if (stt > 1e-12) {
    const double bb = std::max(0.0, sts / stt), aa = std::max(0.0, a - bb * tm);
    if (residual(aa, bb) < residual(a, b)) a = aa, b = bb;
  }
  if (residual(0, 0) <= residual(a, b)) a = 0, b = 0;
  const double peak = 1 / (4 * std::numbers::pi * std::max<double>(p.sx, 1e-3) * std::max<double>(p.sy, 1e-3));
  const double dielectric_error = residual(a, b) * peak;  // at normal incidence, in BRDF units
  blender3_texel out;
  out.base_color = d;
  out.specular = (a + b) / 0.08;
  out.specular_tint = a + b > 0 ? b / (a + b) : 0.0;
  // Metal: F0 = a'_s exactly, no diffuse. Errors at normal incidence in BRDF units.
  const double metal_error = (d[0] + d[1] + d[2]) / std::numbers::pi;
  if (metal_error < dielectric_error) {
    out.metallic = 1;
    for (int c = 0; c < 3; ++c) out.base_color[c] = std::clamp(s[c], 0.0, 1.0);
    out.specular_tint = 0;
  }
  // The metal's Fresnel curve still takes its shape from Specular: the one `f0` gives. The
  // dielectric's F0 and curve both come from Specular, so its curve is that of F0 = a + b.
  if (out.metallic > 0) out.specular = f0 / 0.08;
  return out;
}

}  // namespace anisocap::exports
