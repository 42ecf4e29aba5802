#pragma once
/// @file
/// Per-texel conversion of the Ward + Schlick parameters (brdf/ward.hpp) to each export target's
/// parameters (export/target_models.hpp), in closed form:
///   - lobe widths: GGX a = k sigma along each axis (at normal incidence the two lobes have the same
///     peak 1 / (4 pi a_x a_y) for k = 1); k per target is the value that minimises the measured
///     error (export/fidelity.hpp, README "Exports"), then each target's (roughness, anisotropy)
///     parametrisation is inverted and clamped to its range;
///   - rotation: the canonical form (brdf/canonical_maps.hpp) puts the wide axis on the rotated
///     tangent, which is the axis every target stretches;
///   - specular colour and Fresnel: normal-incidence reflectance a'_s matched exactly, grazing
///     reflectance a'_s / F0 as far as the target's Fresnel allows;
///   - diffuse: a_d divided by the target's normal-incidence diffuse weight 1 - max_c F_c(0).
/// Expects canonical texels (sigma_x >= sigma_y); the result does not depend on it for Mitsuba.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "anisocap/brdf/ward.hpp"
#include "anisocap/export/target_models.hpp"

namespace anisocap::exports {

/// Whether the glTF export uses KHR_materials_anisotropy.
enum class gltf_anisotropy {
  automatic,  ///< whichever of the two the glTF model follows more closely on the maps (export/fidelity.hpp)
  on,         ///< always: anisotropic GGX, its direction in the mesh's tangent plane
  off,        ///< never: isotropic GGX about the normal-mapped normal
};

/// Ratios GGX alpha / Ward sigma per target (defaults: the measured minimisers, README "Exports"),
/// and the glTF export's use of KHR_materials_anisotropy.
struct conversion_options {
  double gltf_scale = 0.9;              ///< glTF KHR_materials_anisotropy
  double blender_scale = 0.9;           ///< Blender Principled BSDF
  double standard_surface_scale = 0.9;  ///< Standard Surface
  gltf_anisotropy gltf_anisotropy_use = gltf_anisotropy::automatic;  ///< see gltf_anisotropy
};

namespace detail {
inline double max3(const rgb& c) { return std::max({c[0], c[1], c[2]}); }
inline rgb diffuse_under(const ward_parameters<float>& p, double normal_fresnel_max) {
  rgb out;
  for (int c = 0; c < 3; ++c) out[c] = std::clamp(p.diffuse[c] / std::max(1 - normal_fresnel_max, 1e-3), 0.0, 1.0);
  return out;
}
inline double wrap_turns(double radians) {
  const double t = radians / (2 * std::numbers::pi);
  return t - std::floor(t);
}
}  // namespace detail

/// glTF: a_b = r^2, a_t = mix(r^2, 1, s^2) (KHR_materials_anisotropy), so r = sqrt(k sigma_y) and
/// s = sqrt((k sigma_x - a_b) / (1 - a_b)); without the extension (`anisotropic` false) one
/// alpha = r^2 = k sqrt(sigma_x sigma_y), the lobe of the same peak. F0 colour and weight w from
/// KHR_materials_specular: w f0_c = a'_s,c at normal incidence, w = a'_s / F0 (mean over channels)
/// at grazing, w <= 1.
inline gltf_texel to_gltf(const ward_parameters<float>& p, const conversion_options& o = {}, bool anisotropic = true) {
  gltf_texel g;
  g.anisotropic = anisotropic;
  if (anisotropic) {
    const double ab = std::clamp(o.gltf_scale * p.sy, 1e-4, 1.0), at = std::clamp(o.gltf_scale * p.sx, ab, 1.0);
    g.roughness = std::sqrt(ab);
    g.anisotropy_strength = ab < 1 ? std::sqrt((at - ab) / (1 - ab)) : 0.0;
  } else {
    g.roughness = std::sqrt(std::clamp(o.gltf_scale * std::sqrt(double(p.sx) * p.sy), 1e-4, 1.0));
  }
  g.anisotropy_angle = p.alpha;
  const rgb s{p.specular[0], p.specular[1], p.specular[2]};
  const double f0 = std::max(double(p.f0), 1e-4);
  g.specular = std::clamp((s[0] + s[1] + s[2]) / 3 / f0, detail::max3(s), 1.0);
  for (int c = 0; c < 3; ++c) g.specular_color[c] = g.specular > 0 ? std::min(s[c] / g.specular, 1.0) : 0.0;
  g.base_color = detail::diffuse_under(p, g.specular * detail::max3(g.specular_color));
  g.nx = p.nx, g.ny = p.ny;
  return g;
}

/// Blender: a_x = r^2 / aspect, a_y = r^2 aspect, aspect = sqrt(1 - 0.9 A), so r^2 = k sqrt(sx sy)
/// and A = (1 - sy/sx) / 0.9 (clamped to 1: aspect ratios above 10 cannot be expressed); the IOR
/// gives F0 and Specular Tint = a'_s / F0 (grazing stays white, where Ward's is a'_s / F0).
inline blender_texel to_blender(const ward_parameters<float>& p, const conversion_options& o = {}) {
  blender_texel b;
  const double sx = std::max<double>(p.sx, p.sy), sy = std::min<double>(p.sx, p.sy);
  b.roughness = std::sqrt(std::clamp(o.blender_scale * std::sqrt(sx * sy), 1e-4, 1.0));
  b.anisotropic = std::clamp((1 - sy / sx) / 0.9, 0.0, 1.0);
  b.anisotropic_rotation = detail::wrap_turns(p.alpha);
  const rgb s{p.specular[0], p.specular[1], p.specular[2]};
  const double f0 = std::clamp(std::max<double>(p.f0, detail::max3(s)), 1e-4, 0.999);
  b.ior = ior_of_f0(f0);
  for (int c = 0; c < 3; ++c) b.specular_tint[c] = s[c] / f0;
  b.base_color = detail::diffuse_under(p, detail::max3(s));
  b.nx = p.nx, b.ny = p.ny;
  return b;
}

/// Standard Surface: a_x = r^2 / aspect, a_y = r^2 aspect, aspect = sqrt(1 - A) with A <= 0.98
/// (aspect ratios up to 50); specular_color = a'_s / F0 and specular_IOR from F0, so the lobe's
/// Fresnel runs from a'_s to a'_s / F0 as Ward's does (dielectric Fresnel in place of Schlick).
inline standard_surface_texel to_standard_surface(const ward_parameters<float>& p, const conversion_options& o = {}) {
  standard_surface_texel t;
  const double sx = std::max<double>(p.sx, p.sy), sy = std::min<double>(p.sx, p.sy);
  t.specular_roughness = std::sqrt(std::clamp(o.standard_surface_scale * std::sqrt(sx * sy), 1e-4, 1.0));
  t.specular_anisotropy = std::clamp(1 - sy / sx, 0.0, 0.98);
  t.specular_rotation = detail::wrap_turns(p.alpha);
  const double f0 = std::clamp<double>(p.f0, 1e-4, 0.999);
  t.specular_ior = ior_of_f0(f0);
  const rgb s{p.specular[0], p.specular[1], p.specular[2]};
  t.specular = std::max(1.0, detail::max3(s) / f0);  // specular_color stays in [0, 1]
  for (int c = 0; c < 3; ++c) t.specular_color[c] = s[c] / f0 / t.specular;
  t.base_color = detail::diffuse_under(p, detail::max3(s));
  t.nx = p.nx, t.ny = p.ny;
  return t;
}

/// Mitsuba 0.6 ward (balanced): the same lobe, but axis-aligned and without Fresnel or shading
/// normal. A rotated lobe is replaced by the axis-aligned one with the same exponent along u and v:
/// 1/a_u^2 = cos^2/sx^2 + sin^2/sy^2, 1/a_v^2 = sin^2/sx^2 + cos^2/sy^2 (exact where alpha = 0);
/// specularReflectance = a'_s alpha_u alpha_v / (sx sy), which keeps the lobe's peak at normal
/// incidence (exact there; the Fresnel rise to a'_s / F0 at grazing angles is lost).
inline mitsuba_texel to_mitsuba(const ward_parameters<float>& p) {
  mitsuba_texel m;
  const double c = std::cos(p.alpha), s = std::sin(p.alpha);
  const double sx = std::max<double>(p.sx, ward_limits::min_lobe), sy = std::max<double>(p.sy, ward_limits::min_lobe);
  const double ix = 1.0 / (sx * sx), iy = 1.0 / (sy * sy);
  m.alpha_u = std::clamp(1 / std::sqrt(c * c * ix + s * s * iy), 1e-4, 1.0);
  m.alpha_v = std::clamp(1 / std::sqrt(s * s * ix + c * c * iy), 1e-4, 1.0);
  const double peak = m.alpha_u * m.alpha_v / (sx * sy);
  for (int k = 0; k < 3; ++k) m.diffuse_reflectance[k] = p.diffuse[k], m.specular_reflectance[k] = p.specular[k] * peak;
  return m;
}

}  // namespace anisocap::exports
