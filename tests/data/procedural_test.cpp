// Tests for data/procedural.hpp: determinism, valid ranges, the weave structure (which thread is
// on top, rotation along the thread, normals across it), metals, and variety over seeds.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <set>
#include <stdexcept>
#include <string>

#include "anisocap/data/procedural.hpp"

using namespace anisocap;

namespace {

bool identical(const material_maps& a, const material_maps& b) {
  return a.width() == b.width() && a.height() == b.height() &&
         std::memcmp(a.data(), b.data(), a.plane_stride() * parameter_count * sizeof(float)) == 0;
}

/// Distance between two rotations modulo pi (alpha is pi-periodic), in [0, pi/2].
double angle_distance(double a, double b) {
  double d = std::fmod(std::abs(a - b), std::numbers::pi);
  return std::min(d, std::numbers::pi - d);
}

double mean_plane(const material_maps& m, int k) {
  double sum = 0;
  for (int y = 0; y < m.height(); ++y)
    for (int x = 0; x < m.width(); ++x) sum += m.at(k, x, y);
  return sum / double(m.texel_count());
}

long long floor_mod(long long a, long long m) { return ((a % m) + m) % m; }

/// The weaves restated from their textile definitions (independently of the generator's code):
/// true where the warp is on top at crossing (i = weft index along the warp, j = warp index).
bool expected_warp_on_top(const procedural_parameters& p, long long i, long long j) {
  switch (p.kind) {
    case material_kind::plain_weave: return (i + j) % 2 == 0;  // checkerboard
    case material_kind::basket_weave: return (floor_mod(i, 4) < 2) == (floor_mod(j, 4) < 2);  // 2x2 blocks
    case material_kind::twill:  // warp floats over `over` of `period`, shifted by one per warp thread
      return floor_mod(i + p.pattern_step * j, p.pattern_period) < p.pattern_over;
    case material_kind::satin: {  // exactly one tie point per warp thread and repeat
      const bool tie = floor_mod(i - p.pattern_step * j, p.pattern_period) == 0;
      return p.weft_faced ? tie : !tie;
    }
    default: return true;
  }
}

}  // namespace

TEST_CASE("the same seed gives the same maps; different seeds differ") {
  for (std::uint64_t seed : {0ULL, 1ULL, 12345ULL}) {
    const material_maps a = generate_material(seed, 67, 45), b = generate_material(seed, 67, 45);
    CHECK(identical(a, b));
    CHECK_FALSE(identical(a, generate_material(seed + 1, 67, 45)));
  }
  // Forcing the kind keeps the kind forced, for every seed.
  for (int k = 0; k < material_kind_count; ++k) {
    procedural_options options;
    options.kind = static_cast<material_kind>(k);
    CHECK(draw_procedural_parameters(99, options).kind == *options.kind);
  }
}

TEST_CASE("every plane stays in its valid range, for hundreds of seeds and odd sizes") {
  const int sizes[][2] = {{37, 53}, {1, 1}, {64, 5}};
  for (auto [w, h] : sizes) {
    for (std::uint64_t seed = 0; seed < 300; ++seed) {
      const material_maps m = generate_material(seed * 7919 + 3, w, h);
      REQUIRE(m.width() == w);
      REQUIRE(m.height() == h);
      int bad = 0;  // counted, not asserted per value: millions of assertions would dominate the run time
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          for (int k = 0; k < parameter_count; ++k) bad += !std::isfinite(m.at(k, x, y));
          for (int k = diffuse_r; k <= specular_b; ++k) bad += !(m.at(k, x, y) >= 0.0f && m.at(k, x, y) <= 1.0f);
          bad += !(m.at(lobe_x, x, y) >= 0.02f && m.at(lobe_x, x, y) <= 1.0f);
          bad += !(m.at(lobe_y, x, y) >= 0.02f && m.at(lobe_y, x, y) <= 1.0f);
          bad += !(m.at(fresnel_f0, x, y) > 0.0f && m.at(fresnel_f0, x, y) <= 1.0f);
          const float nx = m.at(normal_x, x, y), ny = m.at(normal_y, x, y);
          bad += !(nx * nx + ny * ny < 1.0f);
          bad += !(std::abs(m.at(rotation, x, y)) <= float(std::numbers::pi / 2));
        }
      }
      INFO("seed ", seed * 7919 + 3, ", size ", w, " x ", h);
      CHECK(bad == 0);
    }
  }
  CHECK_THROWS_AS(generate_material(1, 0, 5), std::invalid_argument);
  procedural_options bad;
  bad.min_thread_pitch = 10;
  bad.max_thread_pitch = 5;
  CHECK_THROWS_AS(generate_material(1, 8, 8, bad), std::invalid_argument);
}

TEST_CASE("weaves: the top thread follows the weave, the rotation follows the top thread") {
  const material_kind kinds[] = {material_kind::plain_weave, material_kind::basket_weave, material_kind::twill,
                                 material_kind::satin};
  for (material_kind kind : kinds) {
    for (std::uint64_t seed = 0; seed < 20; ++seed) {
      procedural_options options;
      options.kind = kind;
      procedural_parameters p = draw_procedural_parameters(seed, options);
      p.waviness = 0;  // straight threads: crossing (i, j) is centred at ((i + 1/2) pw, (j + 1/2) pv)
      const double c = std::cos(p.rotation), s = std::sin(p.rotation);
      const double warp_alpha = p.rotation + p.twist, weft_alpha = p.rotation + std::numbers::pi / 2 + p.twist;
      int agree = 0, total = 0;
      for (long long i = -6; i < 6; ++i) {
        for (long long j = -6; j < 6; ++j) {
          const double u = (double(i) + 0.5) * p.weft_pitch, v = (double(j) + 0.5) * p.warp_pitch;
          const auto texel = procedural_sample(p, c * u - s * v, s * u + c * v);
          const bool warp = expected_warp_on_top(p, i, j);
          agree += angle_distance(texel[rotation], warp ? warp_alpha : weft_alpha) < 1e-4;
          ++total;
          // Fibres run along the thread: the lobe is narrow along it (sigma_x) and wide across.
          CHECK(texel[lobe_y] > 1.3f * texel[lobe_x]);
        }
      }
      INFO(material_kind_name(kind), " seed ", seed);
      CHECK(agree == total);
    }
  }
}

TEST_CASE("plain weave: neighbouring crossings alternate the rotation by pi/2, even with wavy threads") {
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    procedural_options options;
    options.kind = material_kind::plain_weave;
    const procedural_parameters p = draw_procedural_parameters(seed, options);
    const double c = std::cos(p.rotation), s = std::sin(p.rotation);
    random_generator rng(seed);
    int alternate = 0, repeat = 0;
    const int samples = 400;
    for (int k = 0; k < samples; ++k) {
      const double X = rng.uniform(-200, 200), Y = rng.uniform(-200, 200);
      const double a0 = procedural_sample(p, X, Y)[rotation];
      const double a1 = procedural_sample(p, X + c * p.weft_pitch, Y + s * p.weft_pitch)[rotation];
      const double a2 = procedural_sample(p, X + 2 * c * p.weft_pitch, Y + 2 * s * p.weft_pitch)[rotation];
      alternate += std::abs(angle_distance(a0, a1) - std::numbers::pi / 2) < 0.01;
      repeat += angle_distance(a0, a2) < 0.01;
    }
    INFO("seed ", seed);
    // Not every pair: a point may sit in the gap between threads, or the waviness may shift a cell.
    CHECK(alternate > samples * 6 / 10);
    CHECK(repeat > samples * 6 / 10);
  }
}

TEST_CASE("weaves: the normal tilts across the thread like a cylinder") {
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    procedural_options options;
    options.kind = material_kind::plain_weave;
    procedural_parameters p = draw_procedural_parameters(seed, options);
    p.waviness = 0;
    const double c = std::cos(p.rotation), s = std::sin(p.rotation);
    // Crossing (0, 0) has the warp on top: it runs along u, so its normal leans towards +-v.
    const double u = 0.5 * p.weft_pitch;
    for (double side : {-1.0, 1.0}) {
      const double v = (0.5 + side * 0.3) * p.warp_pitch;
      const auto texel = procedural_sample(p, c * u - s * v, s * u + c * v);
      const double towards_v = -s * texel[normal_x] + c * texel[normal_y];
      const double towards_u = c * texel[normal_x] + s * texel[normal_y];
      CHECK(towards_v * side > 0.1);
      CHECK(std::abs(towards_u) < 0.05);
    }
  }
}

TEST_CASE("weaves are anisotropic on most texels; satin shows mostly one family") {
  for (std::uint64_t seed = 0; seed < 40; ++seed) {
    const procedural_parameters p = draw_procedural_parameters(seed);
    if (!is_weave(p.kind)) continue;
    const material_maps m = generate_material(p, 96, 80);
    int anisotropic = 0;
    for (int y = 0; y < m.height(); ++y)
      for (int x = 0; x < m.width(); ++x) anisotropic += m.at(lobe_y, x, y) > 1.3f * m.at(lobe_x, x, y);
    CHECK(anisotropic > int(m.texel_count()) * 9 / 10);
  }
  procedural_options options;
  options.kind = material_kind::satin;
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    const procedural_parameters p = draw_procedural_parameters(seed, options);
    const material_maps m = generate_material(p, 128, 128);
    const double face = p.rotation + p.twist + (p.weft_faced ? std::numbers::pi / 2 : 0.0);
    int on_face = 0;
    for (int y = 0; y < m.height(); ++y)
      for (int x = 0; x < m.width(); ++x) on_face += angle_distance(m.at(rotation, x, y), face) < 1e-3;
    CHECK(on_face > int(m.texel_count()) * 6 / 10);
  }
}

TEST_CASE("metals: dark diffuse, high F0, narrow lobe along the brushing direction") {
  for (material_kind kind : {material_kind::brushed_metal, material_kind::spun_metal}) {
    for (std::uint64_t seed = 0; seed < 8; ++seed) {
      procedural_options options;
      options.kind = kind;
      const procedural_parameters p = draw_procedural_parameters(seed, options);
      const material_maps m = generate_material(p, 64, 48);
      CHECK(mean_plane(m, diffuse_g) < 0.08);
      CHECK(mean_plane(m, fresnel_f0) > 0.4);
      CHECK(mean_plane(m, specular_g) > 0.3);
      CHECK(mean_plane(m, lobe_y) > 2.0 * mean_plane(m, lobe_x));
      if (kind == material_kind::brushed_metal) {
        double worst = 0;
        for (int y = 0; y < m.height(); ++y)
          for (int x = 0; x < m.width(); ++x) worst = std::max(worst, angle_distance(m.at(rotation, x, y), p.rotation));
        CHECK(worst < 0.05);  // follows the brushing direction within a few degrees
      } else {
        // Tangent to circles around the centre: perpendicular to the radius at the corners.
        const double X = 0.5 - 32, Y = 24 - 0.5;
        const double radial = std::atan2(Y - p.centre[1], X - p.centre[0]);
        CHECK(std::abs(angle_distance(m.at(rotation, 0, 0), radial) - std::numbers::pi / 2) < 1e-3);
      }
      // Scratches: the normal varies across the brushing direction.
      double spread = 0;
      for (int y = 0; y < m.height(); ++y)
        for (int x = 0; x < m.width(); ++x) spread += std::abs(m.at(normal_x, x, y)) + std::abs(m.at(normal_y, x, y));
      CHECK(spread / double(m.texel_count()) > 0.005);
    }
  }
}

TEST_CASE("variety: 40 seeds give many kinds, colours and looks") {
  std::set<int> kinds;
  std::set<std::string> descriptions;
  double min_luminance = 1, max_luminance = 0, min_chroma = 1, max_chroma = 0;
  std::set<int> dominant;
  for (std::uint64_t seed = 0; seed < 40; ++seed) {
    const procedural_parameters p = draw_procedural_parameters(seed);
    kinds.insert(int(p.kind));
    descriptions.insert(describe(p));
    const material_maps m = generate_material(p, 48, 48);
    const double r = mean_plane(m, diffuse_r), g = mean_plane(m, diffuse_g), b = mean_plane(m, diffuse_b);
    const double luminance = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    min_luminance = std::min(min_luminance, luminance);
    max_luminance = std::max(max_luminance, luminance);
    const double chroma = (std::max({r, g, b}) - std::min({r, g, b})) / std::max(1e-6, std::max({r, g, b}));
    min_chroma = std::min(min_chroma, chroma);
    max_chroma = std::max(max_chroma, chroma);
    if (chroma > 0.25) dominant.insert(r >= g && r >= b ? 0 : g >= b ? 1 : 2);
  }
  CHECK(kinds.size() >= 6);
  CHECK(descriptions.size() == 40);
  CHECK(max_luminance - min_luminance > 0.3);
  CHECK(max_chroma - min_chroma > 0.5);
  CHECK(dominant.size() == 3);  // reddish, greenish and bluish materials all occur

  // Over many seeds every kind occurs, none dominates.
  int counts[original_kind_count] = {};
  for (std::uint64_t seed = 0; seed < 2000; ++seed) ++counts[int(kind_for_seed(seed))];
  for (int c : counts) {
    CHECK(c > 2000 / 25);
    CHECK(c < 2000 / 4);
  }
  for (int k = 0; k < material_kind_count; ++k) {
    const auto kind = static_cast<material_kind>(k);
    CHECK(material_kind_from_name(material_kind_name(kind)) == kind);
  }
  CHECK_FALSE(material_kind_from_name("linen").has_value());
}

TEST_CASE("pinned texel: the same seed gives the same material on every build") {
  // Produced by this implementation and found bit-identical with GCC 12 at -O0 and -O3 for
  // -march=x86-64, x86-64-v3 and native (AVX-512) and with clang 14 (see the capture test too).
  CHECK(describe(draw_procedural_parameters(7)) ==
        "basket weave, pitch 10.7x9.3 px, warp royal, weft burgundy, rotation 0 deg");
  const material_maps m = generate_material(7, 97, 61);
  const float expected[parameter_count] = {0.0860540271f, 0.00771824503f, 0.0138786845f, 0.0111491531f,
                                           0.0111491531f, 0.0111491531f,  0.0666392371f, 0.2347399f,
                                           0.0217960551f, -0.313623339f,  0.188766435f,  1.24407589f};
  for (int k = 0; k < parameter_count; ++k) CHECK(m.at(k, 13, 29) == expected[k]);
}

TEST_CASE("the original mix is unchanged: kind_for_seed(seed, original) is kind_for_seed(seed), eight kinds only") {
  for (std::uint64_t seed = 0; seed < 3000; ++seed) {
    const material_kind kind = kind_for_seed(seed, material_mix::original);
    CHECK(kind == kind_for_seed(seed));
    CHECK(int(kind) < original_kind_count);
  }
  // Old seeds keep their materials: the default options draw from the original mix.
  CHECK(draw_procedural_parameters(7).kind == kind_for_seed(7));
  CHECK(describe(draw_procedural_parameters(399 * 7919 + 11)) == "spun steel, lobes 0.045 x 0.243, centre (268, 1) px");
}

TEST_CASE("extended mix: every kind occurs with about its documented weight; the training mix never draws a held-out kind") {
  const int draws = 20000;
  int extended[material_kind_count] = {}, training[material_kind_count] = {};
  for (std::uint64_t seed = 0; seed < std::uint64_t(draws); ++seed) {
    ++extended[int(kind_for_seed(seed, material_mix::extended))];
    ++training[int(kind_for_seed(seed, material_mix::training))];
  }
  int held_out_weight = 0;
  for (material_kind k : held_out_kinds) held_out_weight += extended_mix_weights[std::size_t(k)];
  for (int k = 0; k < material_kind_count; ++k) {
    const auto kind = static_cast<material_kind>(k);
    const double expected = draws * extended_mix_weights[std::size_t(k)] / 100.0;
    INFO(material_kind_name(kind));
    CHECK(std::abs(extended[k] - expected) < 5 * std::sqrt(expected));  // 5 standard deviations of a binomial count
    if (is_held_out(kind)) {
      CHECK(training[k] == 0);
    } else {
      const double expected_training = draws * extended_mix_weights[std::size_t(k)] / double(100 - held_out_weight);
      CHECK(std::abs(training[k] - expected_training) < 5 * std::sqrt(expected_training));
    }
  }
  CHECK(held_out_kinds.size() == 2);
  CHECK(is_held_out(material_kind::leather));
  CHECK(is_held_out(material_kind::printed));
  CHECK(material_mix_from_name("training") == material_mix::training);
  CHECK_FALSE(material_mix_from_name("all").has_value());
  CHECK(material_kinds_from_names("leather,printed") == std::vector<material_kind>{material_kind::leather, material_kind::printed});
  CHECK(material_kinds_from_names("").empty());
  CHECK_THROWS_WITH_AS(material_kinds_from_names("leather,linen"), doctest::Contains("linen"), std::invalid_argument);
}

namespace {

/// Per-material statistics of a kind over a few seeds (extended mix).
struct kind_statistics {
  double f0 = 0, specular = 0, diffuse = 0, tilt = 0, anisotropy = 0;
  int bad = 0;  ///< values outside docs/method.md section 1's ranges
};

kind_statistics statistics(material_kind kind, int seeds, int size) {
  kind_statistics s;
  for (int seed = 0; seed < seeds; ++seed) {
    procedural_options options;
    options.kind = kind;
    options.mix = material_mix::extended;
    const material_maps m = generate_material(std::uint64_t(seed) * 104729 + 5, size, size, options);
    for (int y = 0; y < size; ++y) {
      for (int x = 0; x < size; ++x) {
        for (int k = 0; k < parameter_count; ++k) s.bad += !std::isfinite(m.at(k, x, y));
        for (int k = diffuse_r; k <= specular_b; ++k) s.bad += !(m.at(k, x, y) >= 0.0f && m.at(k, x, y) <= 1.0f);
        const float sx = m.at(lobe_x, x, y), sy = m.at(lobe_y, x, y), f0 = m.at(fresnel_f0, x, y);
        s.bad += !(sx >= 0.02f && sx <= 1.0f) + !(sy >= 0.02f && sy <= 1.0f) + !(f0 > 0.0f && f0 <= 1.0f);
        const float nx = m.at(normal_x, x, y), ny = m.at(normal_y, x, y);
        s.bad += !(nx * nx + ny * ny < 1.0f);
        s.bad += !(std::abs(m.at(rotation, x, y)) <= float(std::numbers::pi / 2));
        s.f0 += f0;
        s.specular += m.at(specular_g, x, y);
        s.diffuse += m.at(diffuse_g, x, y);
        s.tilt += std::sqrt(nx * nx + ny * ny);
        s.anisotropy += std::max(sx, sy) / std::min(sx, sy);
      }
    }
  }
  const double n = double(seeds) * size * size;
  s.f0 /= n;
  s.specular /= n;
  s.diffuse /= n;
  s.tilt /= n;
  s.anisotropy /= n;
  return s;
}

}  // namespace

TEST_CASE("new kinds: valid ranges and the statistics that set them apart") {
  const kind_statistics leather = statistics(material_kind::leather, 6, 48);
  const kind_statistics coated = statistics(material_kind::coated, 6, 48);
  const kind_statistics printed = statistics(material_kind::printed, 6, 48);
  const kind_statistics foil = statistics(material_kind::foil, 12, 64);
  const kind_statistics brushed = statistics(material_kind::brushed_metal, 6, 48);
  for (const kind_statistics* s : {&leather, &coated, &printed, &foil, &brushed}) CHECK(s->bad == 0);
  // Leather: low F0, bumpy grain normals, a nearly isotropic lobe.
  CHECK(leather.f0 < 0.07);
  CHECK(leather.tilt > 0.06);
  CHECK(leather.tilt > 4 * printed.tilt);
  CHECK(leather.anisotropy < 1.5);
  // Coated: a narrow isotropic clear-coat lobe, flat, F0 above leather's and the print's.
  CHECK(coated.anisotropy < 1.2);
  CHECK(coated.tilt < 0.03);
  CHECK(coated.f0 > leather.f0);
  // Printed: flat, nearly isotropic, dielectric.
  CHECK(printed.tilt < 0.03);
  CHECK(printed.f0 < 0.12);
  // Metals keep a high F0 and a'_s; foil lies between metal and dielectric.
  CHECK(brushed.f0 > 0.4);
  CHECK(brushed.specular > 0.3);
  CHECK(foil.f0 > printed.f0);
  CHECK(foil.f0 < brushed.f0);
}

TEST_CASE("printed and foil: sharp-edged layouts, metal inside the foil and dielectric outside") {
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    procedural_options options;
    options.kind = material_kind::printed;
    const procedural_parameters p = draw_procedural_parameters(seed, options);
    const material_maps m = generate_material(p, 96, 96);
    // Sharp edges: the diffuse colour takes few distinct values (paper and inks, times the fibre
    // shade of at most +-4 %), and both paper and ink occur.
    int ink = 0;
    for (int y = 0; y < 96; ++y)
      for (int x = 0; x < 96; ++x) {
        const double r = m.at(diffuse_r, x, y) / std::max(1e-6, p.base_colour[0]);
        ink += std::abs(r - 1.0) > 0.05 || std::abs(m.at(diffuse_g, x, y) / std::max(1e-6, p.base_colour[1]) - 1.0) > 0.05;
      }
    INFO(describe(p));
    CHECK(ink > 0);
    CHECK(ink < 96 * 96);
  }
  int metal_texels = 0, dielectric_texels = 0;
  for (std::uint64_t seed = 0; seed < 10; ++seed) {
    procedural_options options;
    options.kind = material_kind::foil;
    const procedural_parameters p = draw_procedural_parameters(seed, options);
    CHECK((is_weave(p.base_kind) || p.base_kind == material_kind::printed));
    const material_maps m = generate_material(p, 128, 128);
    int wrong = 0;  // counted, not asserted per texel
    for (int y = 0; y < 128; ++y)
      for (int x = 0; x < 128; ++x) {
        // Foil texels carry the foil's F0 exactly (no jitter inside a foil shape); there a'_s is the
        // tint and the diffuse is dark. The base (dielectric yarns, ink, paper; a lame weft jitters) never does.
        if (m.at(fresnel_f0, x, y) == float(p.foil_f0)) {
          ++metal_texels;
          wrong += std::abs(m.at(specular_g, x, y) - float(p.foil_tint[1])) > 1e-6f || !(m.at(diffuse_g, x, y) < 0.03f);
        } else {
          ++dielectric_texels;
        }
      }
    INFO(describe(p));
    CHECK(wrong == 0);
  }
  CHECK(metal_texels > 10 * 128 * 128 / 20);  // foil covers a real share
  CHECK(dielectric_texels > 10 * 128 * 128 / 5);
}

TEST_CASE("spun metal in the extended mix: the centre lies nearer the middle, the original mix keeps its centres") {
  int inside_extended = 0, inside_original = 0;
  for (std::uint64_t seed = 0; seed < 200; ++seed) {
    procedural_options options;
    options.kind = material_kind::spun_metal;
    const procedural_parameters original = draw_procedural_parameters(seed, options);
    options.mix = material_mix::extended;
    const procedural_parameters extended = draw_procedural_parameters(seed, options);
    CHECK(extended.centre[0] == doctest::Approx(0.35 * original.centre[0]));
    inside_extended += std::abs(extended.centre[0]) < 128 && std::abs(extended.centre[1]) < 128;
    inside_original += std::abs(original.centre[0]) < 128 && std::abs(original.centre[1]) < 128;
  }
  CHECK(inside_extended > 2 * inside_original);  // inside a 256-texel capture: ~65 % against ~10 %
}
