// export/target_models.hpp and export/conversion.hpp: the target models' normalisation, the
// conversions' exact cases, and that the default alpha/sigma ratios minimise the measured error.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <vector>

#include "anisocap/data/procedural.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/export/conversion.hpp"
#include "anisocap/export/fidelity.hpp"

using namespace anisocap;
using namespace anisocap::exports;

namespace {

ward_parameters<float> texel(float sx, float sy, float f0, float alpha, float nx = 0, float ny = 0) {
  return {{0.3f, 0.2f, 0.1f}, {0.05f, 0.04f, 0.03f}, sx, sy, f0, nx, ny, alpha};
}

rgb ward(const ward_parameters<float>& p, const vec3& l, const vec3& v) {
  const ward_parameters<double> d{{p.diffuse[0], p.diffuse[1], p.diffuse[2]}, {p.specular[0], p.specular[1], p.specular[2]}, p.sx, p.sy, p.f0, p.nx, p.ny, p.alpha};
  const auto f = ward_evaluate(d, l, v);
  return {f[0], f[1], f[2]};
}

}  // namespace

TEST_CASE("GGX distribution is normalised: integral of D(h) h_z over the hemisphere is 1") {
  for (const auto& [ax, ay] : {std::pair{0.3, 0.3}, std::pair{0.5, 0.1}, std::pair{0.8, 0.4}}) {
    double sum = 0;
    const int nt = 800, np = 400;
    for (int i = 0; i < nt; ++i) {
      const double t = (i + 0.5) / nt * std::numbers::pi / 2;
      for (int j = 0; j < np; ++j) {
        const double p = (j + 0.5) / np * 2 * std::numbers::pi;
        const vec3 h{std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
        sum += ggx_distribution(h, ax, ay) * h[2] * std::sin(t) * (std::numbers::pi / 2 / nt) * (2 * std::numbers::pi / np);
      }
    }
    CHECK(sum == doctest::Approx(1.0).epsilon(2e-3));
  }
}

TEST_CASE("dielectric Fresnel: F0 of the IOR at normal incidence, 1 at grazing") {
  for (double f0 : {0.02, 0.04, 0.3}) {
    const double eta = ior_of_f0(f0);
    CHECK(f0_of_ior(eta) == doctest::Approx(f0));
    CHECK(fresnel_dielectric(1.0, eta) == doctest::Approx(f0));
    CHECK(fresnel_dielectric(1e-6, eta) == doctest::Approx(1.0).epsilon(1e-4));
  }
}

TEST_CASE("every GGX target matches Ward exactly at normal incidence when the ratio is 1") {
  const conversion_options unit{1.0, 1.0, 1.0};
  const vec3 n{0, 0, 1};
  for (const auto& p : {texel(0.3f, 0.1f, 0.06f, 0.4f), texel(0.2f, 0.2f, 0.5f, -1.2f), texel(0.15f, 0.05f, 0.1f, 1.0f)}) {
    const rgb w = ward(p, n, n);
    const rgb g = evaluate(to_gltf(p, unit), n, n), b = evaluate(to_blender(p, unit), n, n);
    const rgb s = evaluate(to_standard_surface(p, unit), n, n), m = evaluate(to_mitsuba(p), n, n);
    for (int c = 0; c < 3; ++c) {
      CHECK(g[c] == doctest::Approx(w[c]).epsilon(1e-6));
      CHECK(b[c] == doctest::Approx(w[c]).epsilon(1e-6));
      CHECK(s[c] == doctest::Approx(w[c]).epsilon(1e-6));
      CHECK(m[c] == doctest::Approx(w[c]).epsilon(1e-6));
    }
  }
}

TEST_CASE("Mitsuba's ward is exact for an axis-aligned lobe, flat normal and F0 = 1, at every direction") {
  const auto p = texel(0.25f, 0.08f, 1.0f, 0.0f);
  const mitsuba_texel m = to_mitsuba(p);
  CHECK(m.alpha_u == doctest::Approx(0.25));
  CHECK(m.alpha_v == doctest::Approx(0.08));
  const auto dirs = fidelity_directions({});
  for (const vec3& l : dirs)
    for (const vec3& v : dirs) {
      const rgb a = ward(p, l, v), b = evaluate(m, l, v);
      for (int c = 0; c < 3; ++c) REQUIRE(b[c] == doctest::Approx(a[c]).epsilon(1e-9));
    }
}

TEST_CASE("the conversions invert each target's roughness and anisotropy parametrisation") {
  const conversion_options o{0.9, 0.9, 0.9};
  const auto p = texel(0.4f, 0.08f, 0.05f, 1.1f);  // aspect 5: within every target's range
  const gltf_texel g = to_gltf(p, o);
  const double ab = g.roughness * g.roughness, at = ab + (1 - ab) * g.anisotropy_strength * g.anisotropy_strength;
  CHECK(ab == doctest::Approx(0.9 * 0.08));
  CHECK(at == doctest::Approx(0.9 * 0.4));
  CHECK(g.anisotropy_angle == doctest::Approx(1.1));
  const blender_texel b = to_blender(p, o);
  const double aspect_b = std::sqrt(1 - 0.9 * b.anisotropic), r2_b = b.roughness * b.roughness;
  CHECK(r2_b / aspect_b == doctest::Approx(0.9 * 0.4));
  CHECK(r2_b * aspect_b == doctest::Approx(0.9 * 0.08));
  CHECK(b.anisotropic_rotation == doctest::Approx(1.1 / (2 * std::numbers::pi)));
  const standard_surface_texel s = to_standard_surface(p, o);
  const double aspect_s = std::sqrt(1 - s.specular_anisotropy), r2_s = s.specular_roughness * s.specular_roughness;
  CHECK(r2_s / aspect_s == doctest::Approx(0.9 * 0.4));
  CHECK(r2_s * aspect_s == doctest::Approx(0.9 * 0.08));
  // A negative rotation wraps into [0, 1) turns.
  CHECK(to_standard_surface(texel(0.4f, 0.08f, 0.05f, -0.5f), o).specular_rotation == doctest::Approx(1 - 0.5 / (2 * std::numbers::pi)));
  // Standard Surface's specular_color * Fresnel runs from a'_s (normal) to a'_s / F0 (grazing).
  for (int c = 0; c < 3; ++c) CHECK(s.specular * s.specular_color[c] * f0_of_ior(s.specular_ior) == doctest::Approx(p.specular[c]));
}

TEST_CASE("the default alpha/sigma ratios minimise the measured error on procedural materials") {
  // One small material of every kind, seeds other than those of examples/export_fidelity.cpp.
  std::vector<material_maps> materials;
  for (int k = 0; k < material_kind_count; ++k) {
    procedural_options po;
    po.kind = material_kind(k);
    materials.push_back(generate_material(4242 + k, 16, 16, po));
    canonicalise(materials.back());
  }
  auto mean_error = [&](const conversion_options& c) {
    fidelity_options o;
    o.texel_stride = 4;
    o.conversion = c;
    std::array<double, target_count> mean{};
    for (const auto& m : materials) {
      const fidelity_result r = measure_fidelity(m, o);
      for (int t = 0; t < target_count; ++t) mean[t] += r.error[t] / double(materials.size());
    }
    return mean;
  };
  const auto at_default = mean_error({});
  for (double k : {0.7, 1.1}) {
    const auto other = mean_error({k, k, k});
    for (int t = 0; t < 3; ++t) CHECK(at_default[t] < other[t]);
  }
  for (int t = 0; t < target_count; ++t) {
    CHECK(std::isfinite(at_default[t]));
    CHECK(at_default[t] > 0);  // no target reproduces a normal-mapped, Fresnel material exactly
  }
}
