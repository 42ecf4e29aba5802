#pragma once
/// @file
/// Seeded procedural materials: woven fabrics (plain, basket, twill, herringbone, satin), crushed
/// velvet, linearly or circularly brushed metal, leather, coated (lacquered), printed surfaces and
/// metal foil on a fabric or print (docs/procedural.md). They stand in for the Bonn
/// SVBRDF dataset the paper trains and evaluates on (docs/method.md section 9), which is not available here:
/// each seed gives one material_maps (docs/method.md section 1) whose anisotropy follows its structure.
///
/// Conventions (docs/method.md section 2): the rotation alpha turns the lobe frame's x axis from +x (image
/// columns) towards +y (up in the scene, towards row 0). For a thread, x runs along its fibres and
/// **decision** sigma_x (along the fibres) < sigma_y (across): a cylinder's normals spread across
/// its axis, so its highlight is wide across the thread, as in Ward's brushed metal (grooves along
/// x, slopes spread in y). The normal's (x, y) are in the scene frame (t_g = +x, b_g = +y).
///
/// Pattern scales are in texels (thread pitch 5 to 20 by default), so a larger image shows more
/// threads, as a larger photograph of the same cloth would. The generator is a pure function of
/// (seed, size, options), any size, OpenMP over rows: the drawn choices (kind, pattern, colours,
/// per-thread hashes) are identical on every machine (core/random.hpp); values that pass through
/// libm (cos, pow, exp) may differ in the last bit of a float between standard libraries.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/srgb.hpp"

namespace anisocap {

/// The families of procedural material. New kinds are added at the end, so a kind's number (and
/// the materials of the original mix) never change.
enum class material_kind : int {
  plain_weave,     ///< over one, under one: warp and weft alternate at every crossing
  basket_weave,    ///< plain weave of doubled threads (2 x 2 blocks)
  twill,           ///< floats over 2-3 threads shifted by one per row: diagonal ribs (denim, gabardine)
  herringbone,     ///< twill whose diagonal reverses in bands: zig-zag
  satin,           ///< long floats of one family (4 or 7 threads), sparse tie points: glossy, one direction
  crushed_velvet,  ///< pile whose direction wanders smoothly: rotation and shade vary in patches
  brushed_metal,   ///< metal brushed along one direction: fine parallel scratches, high F0
  spun_metal,      ///< metal turned on a lathe: circular brushing around a centre
  leather,         ///< grained hide: cells and creases tilt the normals, low F0, broad nearly isotropic lobe
  coated,          ///< lacquered surface: narrow isotropic clear-coat lobe over a plain or printed colour
  printed,         ///< sharp-edged ink pattern (stripes, dots, checks, glyph blocks, blots) on glossy paper or film
  foil,            ///< metal foil shapes on a weave or a print: metal and dielectric side by side
};

/// Number of material_kind values.
inline constexpr int material_kind_count = 12;

/// Number of kinds in the original mix (kind_for_seed): the first eight.
inline constexpr int original_kind_count = 8;

/// Short lower-case name of a kind, for logs and command lines.
inline const char* material_kind_name(material_kind kind) {
  static constexpr const char* names[material_kind_count] = {"plain",   "basket", "twill",  "herringbone",
                                                             "satin",   "velvet", "brushed", "spun",
                                                             "leather", "coated", "printed", "foil"};
  const int k = static_cast<int>(kind);
  return k >= 0 && k < material_kind_count ? names[k] : "unknown";
}

/// The kind with the given short name (material_kind_name), or nothing.
inline std::optional<material_kind> material_kind_from_name(std::string_view name) {
  for (int k = 0; k < material_kind_count; ++k)
    if (name == material_kind_name(static_cast<material_kind>(k))) return static_cast<material_kind>(k);
  return std::nullopt;
}

/// The kinds of a comma-separated list of names ("leather,printed"). Throws
/// std::invalid_argument naming an unknown name and listing the known ones.
inline std::vector<material_kind> material_kinds_from_names(std::string_view list) {
  std::vector<material_kind> kinds;
  while (!list.empty()) {
    const auto comma = list.find(',');
    const std::string_view name = list.substr(0, comma);
    if (!name.empty()) {
      const auto kind = material_kind_from_name(name);
      if (!kind) {
        std::string known;
        for (int k = 0; k < material_kind_count; ++k)
          known += std::string(k ? ", " : "") + material_kind_name(static_cast<material_kind>(k));
        throw std::invalid_argument("unknown material family '" + std::string(name) + "' (known: " + known + ")");
      }
      kinds.push_back(*kind);
    }
    list = comma == std::string_view::npos ? std::string_view{} : list.substr(comma + 1);
  }
  return kinds;
}

/// True for the woven kinds (threads along two directions).
inline constexpr bool is_weave(material_kind kind) { return static_cast<int>(kind) <= static_cast<int>(material_kind::satin); }

/// True for the all-metal kinds (foil is metal in places only).
inline constexpr bool is_metal(material_kind kind) {
  return kind == material_kind::brushed_metal || kind == material_kind::spun_metal;
}

/// The families that training never draws (material_mix::training), kept apart as a check of how
/// the networks generalise to surfaces they have not seen: leather (grain normals, low F0) and
/// printed (sharp-edged diffuse patterns).
inline constexpr std::array<material_kind, 2> held_out_kinds = {material_kind::leather, material_kind::printed};

/// True when `kind` is one of held_out_kinds.
inline constexpr bool is_held_out(material_kind kind) {
  for (material_kind k : held_out_kinds)
    if (k == kind) return true;
  return false;
}

/// Which families a seed's kind is drawn from when no kind is forced.
enum class material_mix : int {
  original,  ///< kind_for_seed: the eight original kinds (every result before the extended mix used it)
  extended,  ///< kind_for_seed_v2: all twelve kinds, metals more often, spun centres nearer the middle
  training,  ///< kind_for_seed_v2 without held_out_kinds: what the networks train on
};

/// Short name of a mix ("original", "extended", "training"), for command lines.
inline const char* material_mix_name(material_mix mix) {
  switch (mix) {
    case material_mix::original: return "original";
    case material_mix::extended: return "extended";
    case material_mix::training: return "training";
  }
  return "unknown";
}

/// The mix with the given short name (material_mix_name), or nothing.
inline std::optional<material_mix> material_mix_from_name(std::string_view name) {
  for (material_mix m : {material_mix::original, material_mix::extended, material_mix::training})
    if (name == material_mix_name(m)) return m;
  return std::nullopt;
}

/// The kind a seed gives in the original mix: weaves about 2/3 of the time (the Bonn dataset is
/// mostly fabric), velvet and the two metals the rest. Uses its own hash of the seed, so forcing a
/// kind leaves the other drawn properties of that seed unchanged.
inline material_kind kind_for_seed(std::uint64_t seed) {
  // Cumulative weights in percent: plain 15, basket 8, twill 17, herringbone 10, satin 14,
  // velvet 10, brushed 15, spun 11.
  static constexpr int cumulative[original_kind_count] = {15, 23, 40, 50, 64, 74, 89, 100};
  const auto draw = static_cast<int>(hash64(seed ^ 0x6b696e64ULL) % 100);
  int k = 0;
  while (draw >= cumulative[k]) ++k;
  return static_cast<material_kind>(k);
}

/// Weight in percent of each kind in the extended mix (kind_for_seed_v2), in material_kind order:
/// fabrics 41 (plain 9, basket 4, twill 9, herringbone 5, satin 8, velvet 6), metals 28
/// (brushed 15, spun 13: the weak case gets more samples), leather 8, coated 8, printed 7, foil 8.
inline constexpr std::array<int, material_kind_count> extended_mix_weights = {9, 4, 9, 5, 8, 6, 15, 13, 8, 8, 7, 8};

/// The kind a seed gives in the extended mix: draw = hash(seed) mod W over the summed weights W of
/// extended_mix_weights, counting only the kinds that are not held out when `without_held_out`
/// (material_mix::training; the remaining kinds keep their relative weights). Like kind_for_seed,
/// it uses its own hash of the seed.
inline material_kind kind_for_seed_v2(std::uint64_t seed, bool without_held_out = false) {
  int total = 0;
  for (int k = 0; k < material_kind_count; ++k)
    if (!without_held_out || !is_held_out(static_cast<material_kind>(k))) total += extended_mix_weights[std::size_t(k)];
  int draw = static_cast<int>(hash64(seed ^ 0x6b696e6432ULL) % std::uint64_t(total));
  for (int k = 0; k < material_kind_count; ++k) {
    const auto kind = static_cast<material_kind>(k);
    if (without_held_out && is_held_out(kind)) continue;
    draw -= extended_mix_weights[std::size_t(k)];
    if (draw < 0) return kind;
  }
  return material_kind::plain_weave;  // not reached: the weights sum to total
}

/// The kind a seed gives in `mix`.
inline material_kind kind_for_seed(std::uint64_t seed, material_mix mix) {
  switch (mix) {
    case material_mix::extended: return kind_for_seed_v2(seed, false);
    case material_mix::training: return kind_for_seed_v2(seed, true);
    default: return kind_for_seed(seed);
  }
}

/// What a caller may fix instead of drawing it from the seed.
struct procedural_options {
  std::optional<material_kind> kind;  ///< force a kind (default: kind_for_seed(seed, mix))
  material_mix mix = material_mix::original;  ///< the families drawn when no kind is forced
  double min_thread_pitch = 5.0;      ///< smallest distance between thread centres, texels (>= 2)
  double max_thread_pitch = 20.0;     ///< largest distance between thread centres, texels
  bool random_rotation = true;        ///< false: warp along +x, weft along +y, brushing along +x
};

/// Every property of one procedural material, drawn from its seed (draw_procedural_parameters)
/// and then turned into maps texel by texel (generate_material). Public so that tests and tools
/// can see what the maps should show.
struct procedural_parameters {
  using rgb = std::array<double, 3>;  ///< linear RGB

  material_kind kind = material_kind::plain_weave;  ///< the family
  std::uint64_t seed = 0;                           ///< base of the per-thread and noise hashes
  double rotation = 0;  ///< warp (or brushing) direction, radians from +x towards +y

  // Weaves: the warp runs along `rotation`, the weft at rotation + pi/2.
  double warp_pitch = 8, weft_pitch = 8;  ///< distance between warp (weft) thread centres, texels
  int pattern_period = 2;                 ///< twill / satin repeat in threads
  int pattern_over = 1;                   ///< twill: threads the warp floats over per repeat
  int pattern_step = 1;                   ///< twill direction (+-1) / satin move number
  int herringbone_band = 4;               ///< threads per herringbone band
  bool weft_faced = false;                ///< satin / twill: the weft shows the long floats instead
  double coverage = 0.9;                  ///< fraction of the pitch a thread's width fills
  double bump = 0.4;                      ///< normal tilt (sine) at a thread's edge: the cylinder profile
  double dip = 0.3;                       ///< normal tilt where a float dives under a crossing thread
  double twist = 0;                       ///< fibre angle relative to the thread axis (yarn twist), radians
  double waviness = 0.2;                  ///< thread displacement by low-frequency noise, in pitches
  std::array<rgb, 2> warp_colours{}, weft_colours{};  ///< yarn colours (two for stripes and checks)
  std::array<std::uint8_t, 16> warp_sequence{}, weft_sequence{};  ///< colour index per thread in the repeat
  int warp_sequence_length = 1, weft_sequence_length = 1;          ///< repeat of the colour sequences
  double colour_jitter = 0.1;  ///< relative brightness variation between threads
  double slub = 0.1;           ///< relative brightness variation along a thread
  std::array<double, 2> f0{0.05, 0.05};            ///< Fresnel F0 of warp, weft (or the metal / pile)
  std::array<double, 2> specular_fraction{1, 1};   ///< a_s = a'_s / F0 of warp, weft
  std::array<rgb, 2> specular_tint{rgb{1, 1, 1}, rgb{1, 1, 1}};  ///< colour of a'_s (white unless metallic)
  std::array<double, 2> sigma_along{0.1, 0.1};     ///< lobe width along the fibres (sigma_x)
  std::array<double, 2> sigma_across{0.3, 0.3};    ///< lobe width across the fibres (sigma_y)
  double property_jitter = 0.15;  ///< relative variation of F0, a_s and lobes between threads

  // Velvet and metals.
  rgb base_colour{0.5, 0.5, 0.5};  ///< velvet pile / metal diffuse colour
  double feature_scale = 64;       ///< velvet patch size / scratch segment length, texels
  double turns = 1;                ///< velvet: how far the pile direction wanders, in half turns
  double scratch_strength = 0.05;  ///< metals: normal tilt of the fine scratches
  double scratch_density = 0.1;    ///< metals: fraction of scratch lanes holding a deep scratch
  std::array<double, 2> centre{0, 0};  ///< spun metal: centre of the circles, texels from the image centre

  /// A sharp-edged layout of the plane: where ink (printed, coated) or foil lies.
  struct pattern_layout {
    int shape = 0;           ///< 0 stripes, 1 dots, 2 check, 3 blocks (glyph-like rectangles), 4 blots (thresholded noise)
    double period = 32;      ///< repeat of the pattern (blots: feature size), texels
    double duty = 0.5;       ///< inked fraction: of a period (stripes, check), of a cell (dot diameter), of the area (blots)
    double rotation = 0;     ///< direction of the pattern's u axis, radians from +x towards +y
    std::uint64_t seed = 0;  ///< hash of the per-cell choices (blocks, ink of each feature) and of the blots
  };

  // Printed and coated surfaces (also the printed base of foil): inks over a base colour.
  pattern_layout print;           ///< where the inks lie
  std::array<rgb, 3> ink_colours{};  ///< ink colours (linear RGB)
  int ink_count = 1;              ///< inks in use (1-3)
  double ink_gloss = 1;           ///< printed: lobe width of inked texels relative to the base's (matte > 1)
  double orange_peel = 0;         ///< coated: normal tilt of the coat's gentle waviness
  bool plain_base = false;        ///< coated: a plain colour under the coat instead of a print

  // Foil: metal shapes over a woven or printed base (base_kind's parameters above).
  material_kind base_kind = material_kind::plain_weave;  ///< what lies around the foil
  pattern_layout foil_layout;     ///< where the foil lies
  rgb foil_tint{1, 1, 1};         ///< a'_s of the foil (a metal palette colour)
  double foil_f0 = 0.8;           ///< F0 of the foil
  std::array<double, 2> foil_lobes{0.04, 0.08};  ///< sigma_x, sigma_y of the foil (x along foil_layout.rotation)

  /// Names of the colours drawn, for describe().
  std::array<std::uint8_t, 3> colour_names{};
};

namespace procedural_detail {

using rgb = procedural_parameters::rgb;

/// A named colour, sRGB 0-255 (as one would pick it), converted to linear RGB when drawn.
struct named_colour {
  const char* name;
  int r, g, b;
};

/// Fabric yarn colours: a palette of common dyes and naturals.
inline constexpr named_colour fabric_palette[] = {
    {"navy", 31, 42, 68},          {"indigo", 42, 57, 98},     {"denim", 60, 90, 140},    {"royal", 40, 70, 170},
    {"sky", 120, 170, 210},        {"teal", 30, 110, 110},     {"emerald", 20, 120, 80},  {"forest", 35, 80, 50},
    {"olive", 100, 100, 50},       {"mustard", 200, 160, 50},  {"gold", 200, 160, 60},    {"orange", 220, 110, 40},
    {"rust", 160, 70, 40},         {"crimson", 170, 30, 40},   {"burgundy", 110, 25, 40}, {"plum", 90, 40, 80},
    {"lavender", 150, 130, 190},   {"pink", 210, 150, 150},    {"cream", 235, 225, 200},  {"beige", 200, 180, 150},
    {"camel", 180, 140, 90},       {"chocolate", 80, 50, 35},  {"charcoal", 55, 55, 60},  {"grey", 130, 130, 130},
    {"black", 20, 20, 22},         {"white", 240, 240, 238},
};
inline constexpr int fabric_palette_size = int(sizeof(fabric_palette) / sizeof(fabric_palette[0]));

/// Metal reflectances (linear RGB, close to measured F0 of the metals).
inline constexpr struct {
  const char* name;
  double r, g, b;
} metal_palette[] = {
    {"aluminium", 0.91, 0.92, 0.92}, {"silver", 0.95, 0.93, 0.88}, {"steel", 0.56, 0.57, 0.58},
    {"gold", 1.00, 0.71, 0.29},      {"copper", 0.95, 0.64, 0.54}, {"brass", 0.91, 0.78, 0.42},
    {"titanium", 0.54, 0.50, 0.45},  {"chrome", 0.55, 0.56, 0.55},
};
inline constexpr int metal_palette_size = int(sizeof(metal_palette) / sizeof(metal_palette[0]));

inline rgb palette_colour(int index) {
  const auto& c = fabric_palette[index];
  return {srgb_to_linear(c.r / 255.0), srgb_to_linear(c.g / 255.0), srgb_to_linear(c.b / 255.0)};
}

/// A palette colour with its brightness and saturation nudged, so two materials sharing a palette
/// entry still differ.
inline rgb varied_colour(random_generator& rng, int index) {
  const rgb c = palette_colour(index);
  const double brightness = rng.uniform(0.8, 1.2), saturation = rng.uniform(0.8, 1.15);
  const double grey = (c[0] + c[1] + c[2]) / 3.0;
  rgb out;
  for (int k = 0; k < 3; ++k) out[k] = std::clamp(brightness * (grey + saturation * (c[k] - grey)), 0.003, 0.95);
  return out;
}

inline double log_uniform(random_generator& rng, double a, double b) { return a * std::exp(std::log(b / a) * rng.uniform()); }

inline std::int64_t floor_to_int(double x) { return static_cast<std::int64_t>(std::floor(x)); }

inline std::int64_t floor_mod(std::int64_t a, std::int64_t m) { return ((a % m) + m) % m; }

inline std::int64_t floor_div(std::int64_t a, std::int64_t m) { return (a - floor_mod(a, m)) / m; }

/// Wraps an angle into [-pi/2, pi/2] (alpha is pi-periodic, docs/method.md section 1).
inline double wrap_half_turn(double angle) {
  double a = angle - std::numbers::pi * std::round(angle / std::numbers::pi);
  return std::clamp(a, -std::numbers::pi / 2, std::numbers::pi / 2);
}

inline double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3 - 2 * t);
}

/// Salts that give each use of the seed its own hash stream.
enum salt : std::uint64_t {
  salt_warp = 0x77617270, salt_weft = 0x77656674, salt_slub = 0x736c7562, salt_fibre = 0x66696272,
  salt_wave_u = 0x77617675, salt_wave_v = 0x77617676, salt_shade = 0x73686164, salt_angle = 0x616e676c,
  salt_scratch = 0x73637261, salt_lane = 0x6c616e65, salt_texel = 0x74657863, salt_stain = 0x7374616e,
  salt_print = 0x7072696e, salt_foil = 0x666f696c, salt_grain = 0x67726169, salt_peel = 0x7065656c,
};

inline std::uint64_t salted(std::uint64_t seed, salt s) { return hash64(seed ^ (std::uint64_t(s) * 0x9e3779b97f4a7c15ULL)); }

/// A colour sequence over `length` threads: solid (all 0), or bands of colour 1 in colour 0.
inline int draw_sequence(random_generator& rng, std::array<std::uint8_t, 16>& sequence, bool striped) {
  sequence.fill(0);
  if (!striped) return 1;
  const int length = 4 + int(rng.uniform_int(13));  // 4..16 threads per repeat
  const int band = 1 + int(rng.uniform_int(std::uint64_t(length / 2)));
  for (int k = 0; k < band; ++k) sequence[std::size_t(k)] = 1;
  return length;
}

/// Draws a weave's pattern, threads, colours and reflectance into `p` (p.kind a weave).
inline void draw_weave(random_generator& rng, procedural_parameters& p, const procedural_options& options) {
  p.warp_pitch = log_uniform(rng, options.min_thread_pitch, options.max_thread_pitch);
  p.weft_pitch = std::max(2.0, p.warp_pitch * rng.uniform(0.8, 1.25));
  switch (p.kind) {
    case material_kind::twill:
    case material_kind::herringbone: {
      static constexpr int over[] = {2, 2, 3, 1}, period[] = {3, 4, 4, 3};  // 2/1, 2/2, 3/1, 1/2
      const int k = int(rng.uniform_int(4));
      p.pattern_over = over[k];
      p.pattern_period = period[k];
      p.pattern_step = rng.bernoulli(0.5) ? 1 : -1;
      p.herringbone_band = 3 + int(rng.uniform_int(6));
      break;
    }
    case material_kind::satin: {
      const bool eight = rng.bernoulli(0.4);  // 5-end satin (move 2) or 8-end satin (move 3)
      p.pattern_period = eight ? 8 : 5;
      p.pattern_step = eight ? 3 : 2;
      p.weft_faced = rng.bernoulli(0.3);  // sateen
      break;
    }
    default:
      p.pattern_period = 2;
      break;
  }
  p.coverage = rng.uniform(0.78, 0.97);
  p.bump = rng.uniform(0.25, 0.6);
  p.dip = rng.uniform(0.15, 0.45);
  p.twist = rng.uniform(-0.35, 0.35);
  p.waviness = rng.uniform(0.05, 0.3);

  // Colours: solid, striped warp, or a check (both striped); weft same hue, a shade, or a contrast.
  const int style = int(rng.uniform_int(10));  // 0-5 solid, 6-7 stripes, 8-9 check
  const int c0 = int(rng.uniform_int(fabric_palette_size));
  int c1 = c0, c2 = int(rng.uniform_int(fabric_palette_size));
  const int weft_choice = int(rng.uniform_int(3));  // same, shade of it, contrast (denim, chambray)
  if (weft_choice == 2) c1 = int(rng.uniform_int(fabric_palette_size));
  p.warp_colours = {varied_colour(rng, c0), varied_colour(rng, c2)};
  p.weft_colours = {varied_colour(rng, c1), p.warp_colours[1]};
  if (weft_choice == 1)
    for (double& v : p.weft_colours[0]) v = std::clamp(v * rng.uniform(0.6, 1.5), 0.003, 0.95);
  p.colour_names = {std::uint8_t(c0), std::uint8_t(c1), std::uint8_t(c2)};
  p.warp_sequence_length = draw_sequence(rng, p.warp_sequence, style >= 6);
  p.weft_sequence_length = style >= 8 ? p.warp_sequence_length : 1;
  if (style >= 8) p.weft_sequence = p.warp_sequence;  // a check: same sett both ways
  p.colour_jitter = rng.uniform(0.03, 0.2);
  p.slub = rng.uniform(0.02, 0.2);

  // Reflectance: dielectric yarns (F0 ~ 0.02-0.25, white specular, a'_s <= F0), satins glossier;
  // one material in ten has a metallic weft (lame).
  const bool glossy = p.kind == material_kind::satin;
  for (int f = 0; f < 2; ++f) {
    p.f0[f] = log_uniform(rng, 0.02, glossy ? 0.35 : 0.25);
    p.specular_fraction[f] = rng.uniform(glossy ? 0.6 : 0.3, 1.0);
    p.sigma_along[f] = log_uniform(rng, glossy ? 0.03 : 0.05, glossy ? 0.12 : 0.25);
    p.sigma_across[f] = std::min(1.0, p.sigma_along[f] * rng.uniform(1.8, 5.0));
  }
  if (rng.bernoulli(0.5)) {  // same yarn both ways
    p.f0[1] = p.f0[0];
    p.specular_fraction[1] = p.specular_fraction[0];
    p.sigma_along[1] = p.sigma_along[0];
    p.sigma_across[1] = p.sigma_across[0];
  }
  if (rng.bernoulli(0.1)) {
    const auto& m = metal_palette[rng.uniform_int(metal_palette_size)];
    p.specular_tint[1] = {m.r, m.g, m.b};
    p.f0[1] = rng.uniform(0.5, 0.9);
    p.specular_fraction[1] = rng.uniform(0.7, 1.0);
    for (double& v : p.weft_colours[0]) v *= 0.2;
  }
  p.property_jitter = rng.uniform(0.05, 0.25);
}

/// Name of a pattern_layout shape.
inline const char* pattern_name(int shape) {
  static constexpr const char* names[] = {"stripes", "dots", "check", "blocks", "blots"};
  return shape >= 0 && shape < 5 ? names[shape] : "pattern";
}

/// Draws a sharp-edged pattern layout: shape, period in [min_period, max_period] texels, duty, and
/// a direction (along the image axes 60 % of the time, as prints and stamps usually are).
inline procedural_parameters::pattern_layout draw_layout(random_generator& rng, std::uint64_t seed, double min_period,
                                                        double max_period) {
  procedural_parameters::pattern_layout l;
  l.shape = int(rng.uniform_int(5));
  l.period = log_uniform(rng, min_period, max_period);
  l.duty = rng.uniform(0.2, 0.6);
  l.rotation = rng.bernoulli(0.6) ? 0.0 : rng.uniform(-std::numbers::pi / 2, std::numbers::pi / 2);
  l.seed = seed;
  return l;
}

/// Draws a print: its layout, 1-3 inks from the fabric palette and the paper (white, cream or
/// beige 60 % of the time, else a palette colour), with a glossy nearly isotropic base lobe
/// (F0 0.03-0.1, sigma 0.06-0.2) and matte or glossy inks.
inline void draw_print(random_generator& rng, procedural_parameters& p) {
  p.print = draw_layout(rng, salted(p.seed, salt_print), 8.0, 96.0);
  static constexpr int papers[] = {25, 18, 19};  // white, cream, beige
  const int paper = rng.bernoulli(0.6) ? papers[rng.uniform_int(3)] : int(rng.uniform_int(fabric_palette_size));
  p.base_colour = varied_colour(rng, paper);
  p.ink_count = 1 + int(rng.uniform_int(3));
  int inks[3];
  for (int k = 0; k < 3; ++k) {
    inks[k] = int(rng.uniform_int(fabric_palette_size));
    p.ink_colours[std::size_t(k)] = varied_colour(rng, inks[k]);
  }
  p.colour_names = {std::uint8_t(paper), std::uint8_t(inks[0]), std::uint8_t(inks[1])};
  p.f0[0] = p.f0[1] = log_uniform(rng, 0.03, 0.1);
  p.specular_fraction[0] = p.specular_fraction[1] = rng.uniform(0.5, 1.0);
  p.sigma_along[0] = p.sigma_along[1] = rng.uniform(0.06, 0.2);
  p.sigma_across[0] = p.sigma_across[1] = p.sigma_along[0] * rng.uniform(1.0, 1.3);
  p.ink_gloss = rng.uniform(0.7, 2.0);
  p.bump = rng.uniform(0.0, 0.03);  // paper fibres
}

/// Draws leather: a brown, black or dyed hide, grain cells of 3-14 texels whose creases tilt the
/// normal by up to ~0.5, a low F0 (0.02-0.06) and a broad, nearly isotropic lobe.
inline void draw_leather(random_generator& rng, procedural_parameters& p) {
  static constexpr int hides[] = {21, 20, 24, 14, 12, 19, 22, 0, 8, 18};  // chocolate, camel, black, burgundy, ...
  const int c = hides[rng.uniform_int(sizeof hides / sizeof hides[0])];
  p.base_colour = varied_colour(rng, c);
  p.colour_names = {std::uint8_t(c), std::uint8_t(c), std::uint8_t(c)};
  p.feature_scale = log_uniform(rng, 3.0, 14.0);
  p.bump = rng.uniform(0.15, 0.5);
  p.colour_jitter = rng.uniform(0.2, 0.5);  // how much darker the creases are
  p.f0[0] = p.f0[1] = log_uniform(rng, 0.02, 0.06);
  p.specular_fraction[0] = p.specular_fraction[1] = rng.uniform(0.2, 0.8);
  p.sigma_along[0] = p.sigma_along[1] = rng.uniform(0.12, 0.4);
  p.sigma_across[0] = p.sigma_across[1] = std::min(1.0, p.sigma_along[0] * rng.uniform(1.0, 1.35));
  p.property_jitter = rng.uniform(0.05, 0.2);
}

/// Draws a lacquered surface: a print (or, 40 % of the time, a plain colour) under a clear coat
/// with a narrow isotropic lobe (sigma 0.02-0.06), a high F0 for a dielectric (0.04-0.3) with
/// a'_s close to it, and a gentle orange-peel waviness.
inline void draw_coated(random_generator& rng, procedural_parameters& p) {
  draw_print(rng, p);
  p.plain_base = rng.bernoulli(0.4);
  p.f0[0] = p.f0[1] = log_uniform(rng, 0.04, 0.3);
  p.specular_fraction[0] = p.specular_fraction[1] = rng.uniform(0.7, 1.0);
  p.sigma_along[0] = p.sigma_along[1] = log_uniform(rng, 0.02, 0.06);
  p.sigma_across[0] = p.sigma_across[1] = p.sigma_along[0] * rng.uniform(1.0, 1.15);
  p.orange_peel = rng.uniform(0.003, 0.03);
}

/// Draws foil: a weave (plain, basket, twill or satin; 60 %) or a print around metal shapes of
/// 16-128 texels covering 20-60 % of a period, with a metal palette tint, a'_s 0.7-1 of it, F0
/// near the tint's luminance, lobes 0.03-0.1 along the stamping direction and up to 3x across.
inline void draw_foil(random_generator& rng, procedural_parameters& p, const procedural_options& options) {
  static constexpr material_kind weaves[] = {material_kind::plain_weave, material_kind::basket_weave,
                                             material_kind::twill, material_kind::satin};
  const bool woven = rng.bernoulli(0.6);
  p.base_kind = woven ? weaves[rng.uniform_int(4)] : material_kind::printed;
  p.kind = p.base_kind;  // the base is drawn as that kind would be
  if (woven)
    draw_weave(rng, p, options);
  else
    draw_print(rng, p);
  p.kind = material_kind::foil;
  const int m = int(rng.uniform_int(metal_palette_size));
  const auto& metal = metal_palette[m];
  const double fraction = rng.uniform(0.7, 1.0);
  p.foil_tint = {fraction * metal.r, fraction * metal.g, fraction * metal.b};
  p.foil_f0 = std::clamp(0.2126 * metal.r + 0.7152 * metal.g + 0.0722 * metal.b, 0.0, 1.0) * rng.uniform(0.85, 1.0);
  p.foil_lobes[0] = rng.uniform(0.03, 0.1);
  p.foil_lobes[1] = std::min(1.0, p.foil_lobes[0] * rng.uniform(1.0, 3.0));
  p.foil_layout = draw_layout(rng, salted(p.seed, salt_foil), 16.0, 128.0);
  p.scratch_strength = rng.uniform(0.01, 0.05);  // crinkles of the foil
  p.colour_names[2] = std::uint8_t(m);
}

}  // namespace procedural_detail

/// Draws every property of material `seed` (see procedural_parameters); generate_material turns
/// them into maps. Throws std::invalid_argument for a bad pitch range.
inline procedural_parameters draw_procedural_parameters(std::uint64_t seed, const procedural_options& options = {}) {
  using namespace procedural_detail;
  if (!(options.min_thread_pitch >= 2.0) || !(options.max_thread_pitch >= options.min_thread_pitch))
    throw std::invalid_argument("generate_material: thread pitch range must satisfy 2 <= min <= max");
  random_generator rng(hash64(seed ^ 0x6d6174657269616cULL));  // salted: unrelated to a capture of the same seed
  procedural_parameters p;
  p.kind = options.kind ? *options.kind : kind_for_seed(seed, options.mix);
  p.seed = hash64(seed);
  // A quarter of the materials lie along the image axes, as photographed cloth often does.
  p.rotation = options.random_rotation && rng.bernoulli(0.75) ? rng.uniform(-std::numbers::pi / 2, std::numbers::pi / 2) : 0.0;

  if (is_weave(p.kind)) {
    draw_weave(rng, p, options);
  } else if (p.kind == material_kind::crushed_velvet) {
    static constexpr int velvet_colours[] = {3, 6, 7, 10, 13, 14, 15, 16, 21, 24, 1, 5};  // deep dyes
    const int c = velvet_colours[rng.uniform_int(sizeof velvet_colours / sizeof velvet_colours[0])];
    p.base_colour = varied_colour(rng, c);
    p.colour_names = {std::uint8_t(c), std::uint8_t(c), std::uint8_t(c)};
    p.feature_scale = log_uniform(rng, 24.0, 160.0);
    p.turns = rng.uniform(0.3, 1.0);
    p.f0[0] = p.f0[1] = log_uniform(rng, 0.02, 0.08);
    p.specular_fraction[0] = p.specular_fraction[1] = rng.uniform(0.2, 0.6);
    // A soft sheen rather than a sharp highlight: broad lobes, still twice as wide across the pile.
    p.sigma_along[0] = p.sigma_along[1] = rng.uniform(0.15, 0.35);
    p.sigma_across[0] = p.sigma_across[1] = std::min(1.0, p.sigma_along[0] * rng.uniform(2.0, 3.0));
    p.bump = rng.uniform(0.05, 0.25);
    p.property_jitter = rng.uniform(0.05, 0.15);
  } else if (is_metal(p.kind)) {
    const int m = int(rng.uniform_int(metal_palette_size));
    const auto& metal = metal_palette[m];
    p.colour_names = {std::uint8_t(m), std::uint8_t(m), std::uint8_t(m)};
    p.specular_tint[0] = p.specular_tint[1] = {metal.r, metal.g, metal.b};
    const double diffuse = rng.uniform(0.0, 0.06);
    p.base_colour = {diffuse * metal.r, diffuse * metal.g, diffuse * metal.b};
    p.f0[0] = p.f0[1] = std::clamp(0.2126 * metal.r + 0.7152 * metal.g + 0.0722 * metal.b, 0.0, 1.0) * rng.uniform(0.85, 1.0);
    p.specular_fraction[0] = p.specular_fraction[1] = rng.uniform(0.7, 1.0);
    p.sigma_along[0] = p.sigma_along[1] = rng.uniform(0.02, 0.07);
    p.sigma_across[0] = p.sigma_across[1] = std::min(1.0, rng.uniform(0.12, 0.4));
    p.scratch_strength = rng.uniform(0.03, 0.12);
    p.scratch_density = rng.uniform(0.03, 0.2);
    p.feature_scale = log_uniform(rng, 20.0, 200.0);
    p.property_jitter = rng.uniform(0.03, 0.1);
    // The extended mix brings spun centres 2.9x nearer the middle, so that circles are seen curving
    // on a 256-texel capture (within +-400 texels they mostly look straight).
    const double shrink = options.mix == material_mix::original ? 1.0 : 0.35;
    const double cx = rng.uniform(-400.0, 400.0), cy = rng.uniform(-400.0, 400.0);
    p.centre = {cx * shrink, cy * shrink};
  } else if (p.kind == material_kind::leather) {
    draw_leather(rng, p);
  } else if (p.kind == material_kind::coated) {
    draw_coated(rng, p);
  } else if (p.kind == material_kind::printed) {
    draw_print(rng, p);
  } else {
    draw_foil(rng, p, options);
  }
  return p;
}

/// One line describing a drawn material, for logs: kind, pattern, scale, colours, rotation.
inline std::string describe(const procedural_parameters& p) {
  using namespace procedural_detail;
  char buffer[256];
  const double degrees = p.rotation * 180.0 / std::numbers::pi;
  if (is_weave(p.kind)) {
    char pattern[48];
    if (p.kind == material_kind::twill || p.kind == material_kind::herringbone)
      std::snprintf(pattern, sizeof pattern, "%s %d/%d", material_kind_name(p.kind), p.pattern_over,
                    p.pattern_period - p.pattern_over);
    else if (p.kind == material_kind::satin)
      std::snprintf(pattern, sizeof pattern, "%d-end %s", p.pattern_period, p.weft_faced ? "sateen" : "satin");
    else
      std::snprintf(pattern, sizeof pattern, "%s weave", material_kind_name(p.kind));
    std::snprintf(buffer, sizeof buffer, "%s, pitch %.1fx%.1f px, warp %s, weft %s, rotation %.0f deg", pattern,
                  p.warp_pitch, p.weft_pitch, fabric_palette[p.colour_names[0]].name,
                  fabric_palette[p.colour_names[1]].name, degrees);
  } else if (p.kind == material_kind::crushed_velvet) {
    std::snprintf(buffer, sizeof buffer, "velvet, %s, patches %.0f px", fabric_palette[p.colour_names[0]].name,
                  p.feature_scale);
  } else if (p.kind == material_kind::spun_metal) {
    std::snprintf(buffer, sizeof buffer, "spun %s, lobes %.3f x %.3f, centre (%.0f, %.0f) px",
                  metal_palette[p.colour_names[0]].name, p.sigma_along[0], p.sigma_across[0], p.centre[0], p.centre[1]);
  } else if (p.kind == material_kind::brushed_metal) {
    std::snprintf(buffer, sizeof buffer, "brushed %s, lobes %.3f x %.3f, rotation %.0f deg",
                  metal_palette[p.colour_names[0]].name, p.sigma_along[0], p.sigma_across[0], degrees);
  } else if (p.kind == material_kind::leather) {
    std::snprintf(buffer, sizeof buffer, "leather, %s, grain %.1f px, bump %.2f, F0 %.3f, lobes %.3f x %.3f",
                  fabric_palette[p.colour_names[0]].name, p.feature_scale, p.bump, p.f0[0], p.sigma_along[0],
                  p.sigma_across[0]);
  } else if (p.kind == material_kind::coated || p.kind == material_kind::printed) {
    char base[96];
    if (p.kind == material_kind::coated && p.plain_base)
      std::snprintf(base, sizeof base, "plain %s", fabric_palette[p.colour_names[0]].name);
    else
      std::snprintf(base, sizeof base, "%s %.0f px, %d ink%s (%s, ...) on %s", pattern_name(p.print.shape), p.print.period,
                    p.ink_count, p.ink_count > 1 ? "s" : "", fabric_palette[p.colour_names[1]].name,
                    fabric_palette[p.colour_names[0]].name);
    std::snprintf(buffer, sizeof buffer, "%s, %s, F0 %.3f, lobes %.3f x %.3f", material_kind_name(p.kind), base, p.f0[0],
                  p.sigma_along[0], p.sigma_across[0]);
  } else {
    std::snprintf(buffer, sizeof buffer, "foil, %s %s %.0f px on %s, F0 %.2f, lobes %.3f x %.3f",
                  metal_palette[p.colour_names[2]].name, pattern_name(p.foil_layout.shape), p.foil_layout.period,
                  material_kind_name(p.base_kind), p.foil_f0, p.foil_lobes[0], p.foil_lobes[1]);
  }
  return buffer;
}

namespace procedural_detail {

/// The 12 parameters of one texel before they are checked into their ranges.
struct texel_values {
  rgb diffuse{}, specular{};
  double sigma_x = 0.1, sigma_y = 0.1, f0 = 0.04, normal_x = 0, normal_y = 0, alpha = 0;
};

/// True where the warp crosses over the weft at crossing (i, j): i counts weft threads (along the
/// warp direction), j warp threads.
inline bool warp_on_top(const procedural_parameters& p, std::int64_t i, std::int64_t j) {
  bool warp = true;
  switch (p.kind == material_kind::foil ? p.base_kind : p.kind) {
    case material_kind::plain_weave: warp = floor_mod(i + j, 2) == 0; break;
    case material_kind::basket_weave: warp = floor_mod(floor_div(i, 2) + floor_div(j, 2), 2) == 0; break;
    case material_kind::twill: warp = floor_mod(i + p.pattern_step * j, p.pattern_period) < p.pattern_over; break;
    case material_kind::herringbone: {
      const std::int64_t direction = floor_mod(floor_div(j, p.herringbone_band), 2) == 0 ? 1 : -1;
      warp = floor_mod(i + direction * p.pattern_step * j, p.pattern_period) < p.pattern_over;
      break;
    }
    case material_kind::satin:  // one tie point per thread and repeat, moved by the move number
      warp = floor_mod(i - p.pattern_step * j, p.pattern_period) != 0;
      if (p.weft_faced) warp = !warp;
      break;
    default: break;
  }
  return warp;
}

/// Per-thread factor in [1 - amount, 1 + amount] from a hash.
inline double jitter(std::uint64_t seed, std::int64_t thread, std::int64_t which, double amount) {
  return 1.0 + amount * (2.0 * hash_uniform(seed, thread, which) - 1.0);
}

/// What every texel of one material shares, computed once per map rather than per texel.
struct texel_context {
  double c, s;              ///< cos and sin of the rotation
  double print_c, print_s;  ///< cos and sin of the print's direction
  double foil_c, foil_s;    ///< cos and sin of the foil's direction
  explicit texel_context(const procedural_parameters& p)
      : c(std::cos(p.rotation)), s(std::sin(p.rotation)), print_c(std::cos(p.print.rotation)),
        print_s(std::sin(p.print.rotation)), foil_c(std::cos(p.foil_layout.rotation)), foil_s(std::sin(p.foil_layout.rotation)) {}
};

/// A woven texel at (X, Y) texels from the image centre, Y up.
inline texel_values weave_texel(const procedural_parameters& p, const texel_context& context, double X, double Y) {
  const double c = context.c, s = context.s;
  // Threads are not perfectly straight: displace the lattice by smooth noise of ~12 pitches.
  const double pitch = 0.5 * (p.warp_pitch + p.weft_pitch);
  const double f = 1.0 / (12.0 * pitch);
  const double u = c * X + s * Y + p.waviness * p.weft_pitch * 2.0 * (value_noise(salted(p.seed, salt_wave_u), X * f, Y * f) - 0.5);
  const double v = -s * X + c * Y + p.waviness * p.warp_pitch * 2.0 * (value_noise(salted(p.seed, salt_wave_v), X * f, Y * f) - 0.5);
  const double a = u / p.weft_pitch, b = v / p.warp_pitch;
  const std::int64_t i = floor_to_int(a), j = floor_to_int(b);
  const double fa = a - double(i), fb = b - double(j);
  const bool warp_top = warp_on_top(p, i, j);

  // Which thread is seen: the top one, or the one under it in the gap beside the top one.
  const double across_top = 2.0 * (warp_top ? fb : fa) - 1.0;
  const bool gap = std::abs(across_top) > p.coverage;
  const bool warp_seen = warp_top != gap;
  const int family = warp_seen ? 0 : 1;
  const std::int64_t thread = warp_seen ? j : i;
  const std::uint64_t family_seed = salted(p.seed, warp_seen ? salt_warp : salt_weft);

  // Profile across the seen thread (-1..1) and the float ends along it.
  const double across = gap ? 2.0 * (warp_seen ? fb : fa) - 1.0 : across_top / p.coverage;
  const double along = warp_seen ? fa : fb;
  double tilt_along = 0.0, shade = 1.0;
  if (!gap) {
    const bool next_same = warp_seen ? warp_on_top(p, i + 1, j) : !warp_on_top(p, i, j + 1);
    const bool previous_same = warp_seen ? warp_on_top(p, i - 1, j) : !warp_on_top(p, i, j - 1);
    const double end = 0.35;
    const double rise = previous_same ? 0.0 : smoothstep(end, 0.0, along);
    const double fall = next_same ? 0.0 : smoothstep(1.0 - end, 1.0, along);
    tilt_along = p.dip * (fall - rise);  // a diving end slopes down: the normal leans outwards
    shade *= 1.0 - 0.35 * std::max(rise, fall);
  } else {
    shade *= 0.55;  // the thread below lies in shadow between its neighbours
  }
  const double tilt_across = (gap ? 0.5 : 1.0) * p.bump * std::clamp(across, -1.0, 1.0);
  const double across2 = across * across;
  shade *= 1.0 - 0.3 * across2 * across2;  // cylinder edges turn away

  // Per-thread and along-thread variation.
  const double along_texels = warp_seen ? u : v, across_texels = warp_seen ? v : u;
  const double slub = 1.0 + p.slub * 2.0 * (value_noise(salted(p.seed, salt_slub), along_texels / (4.0 * pitch), double(thread) * 7.31 + family * 101.0) - 0.5);
  const double fibre = 1.0 + 0.12 * (value_noise(salted(p.seed, salt_fibre), along_texels * 0.12, across_texels * 1.3) - 0.5);
  const double brightness = jitter(family_seed, thread, 0, p.colour_jitter) * slub * fibre * shade;

  texel_values t;
  const auto& sequence = warp_seen ? p.warp_sequence : p.weft_sequence;
  const int length = warp_seen ? p.warp_sequence_length : p.weft_sequence_length;
  const int colour = sequence[std::size_t(floor_mod(thread, length))];
  const rgb& yarn = warp_seen ? p.warp_colours[std::size_t(colour)] : p.weft_colours[std::size_t(colour)];
  for (int k = 0; k < 3; ++k) t.diffuse[k] = yarn[k] * brightness;

  const double f0 = p.f0[family] * jitter(family_seed, thread, 1, p.property_jitter);
  const double fraction = p.specular_fraction[family] * jitter(family_seed, thread, 2, p.property_jitter) * (gap ? 0.5 : 1.0) * fibre;
  t.f0 = f0;
  for (int k = 0; k < 3; ++k) t.specular[k] = std::min(1.0, fraction) * f0 * p.specular_tint[family][k];
  const double lobe = jitter(family_seed, thread, 3, p.property_jitter) * (gap ? 1.5 : 1.0);
  t.sigma_x = p.sigma_along[family] * lobe;
  t.sigma_y = p.sigma_across[family] * lobe;

  // Normal in (u, v), then in the scene frame; alpha along the fibres of the seen thread.
  const double n_u = warp_seen ? tilt_along : tilt_across;
  const double n_v = warp_seen ? tilt_across : tilt_along;
  t.normal_x = c * n_u - s * n_v;
  t.normal_y = s * n_u + c * n_v;
  t.alpha = wrap_half_turn(p.rotation + (warp_seen ? 0.0 : std::numbers::pi / 2) + p.twist);
  return t;
}

/// A crushed-velvet texel: the pile direction turns with smooth noise, and its shade follows it.
inline texel_values velvet_texel(const procedural_parameters& p, double X, double Y) {
  const double f = 1.0 / p.feature_scale;
  const double wander = fractal_noise(salted(p.seed, salt_angle), X * f, Y * f, 2);
  const double direction = p.rotation + std::numbers::pi * p.turns * 2.0 * (wander - 0.5);
  const double patch = fractal_noise(salted(p.seed, salt_shade), X * f * 1.7, Y * f * 1.7, 2);
  const double speck = hash_uniform(salted(p.seed, salt_texel), floor_to_int(X), floor_to_int(Y));
  // Pile bent towards the viewer's side looks lighter: shade by direction and by patch.
  const double shade = (0.55 + 0.45 * std::cos(2.0 * (direction - p.rotation))) * (0.7 + 0.6 * patch) * (0.92 + 0.16 * speck);
  texel_values t;
  for (int k = 0; k < 3; ++k) t.diffuse[k] = p.base_colour[k] * (0.5 + 0.6 * shade);
  const double j = 1.0 + p.property_jitter * (2.0 * patch - 1.0);
  t.f0 = p.f0[0] * j;
  for (int k = 0; k < 3; ++k) t.specular[k] = std::min(1.0, p.specular_fraction[0] * j) * t.f0;
  t.sigma_x = p.sigma_along[0] / j;
  t.sigma_y = p.sigma_across[0] / j;
  const double lean = p.bump * (0.4 + 0.6 * patch);
  t.normal_x = lean * std::cos(direction);
  t.normal_y = lean * std::sin(direction);
  t.alpha = wrap_half_turn(direction);
  return t;
}

/// Scratch profile across a brushing lane: fine scratches everywhere (noise stretched along the
/// brushing direction) plus sparse deep scratches of random length.
inline double scratch_tilt(const procedural_parameters& p, double along, double across) {
  double tilt = p.scratch_strength * 2.0 * (value_noise(salted(p.seed, salt_scratch), across * 0.8, along * 0.004) - 0.5);
  const double lane_width = 3.0;
  const std::int64_t lane = floor_to_int(across / lane_width);
  const std::uint64_t lane_seed = salted(p.seed, salt_lane);
  if (hash_uniform(lane_seed, lane, 0) < p.scratch_density) {
    const double length = p.feature_scale * (0.5 + 1.5 * hash_uniform(lane_seed, lane, 1));
    const double offset = length * hash_uniform(lane_seed, lane, 2);
    const std::int64_t segment = floor_to_int((along + offset) / length);
    if (hash_uniform(hash64(lane_seed + 1), lane, segment) < 0.6) {
      const double centre = (double(lane) + 0.3 + 0.4 * hash_uniform(hash64(lane_seed + 2), lane, segment)) * lane_width;
      const double d = (across - centre) / 0.8;  // a groove about two texels wide
      tilt += 4.0 * p.scratch_strength * d * std::exp(-d * d);
    }
  }
  return tilt;
}

/// A brushed or spun metal texel.
inline texel_values metal_texel(const procedural_parameters& p, const texel_context& context, double X, double Y) {
  double direction, along, across;
  if (p.kind == material_kind::spun_metal) {
    const double dx = X - p.centre[0], dy = Y - p.centre[1];
    const double radius = std::sqrt(dx * dx + dy * dy), azimuth = std::atan2(dy, dx);
    direction = azimuth + std::numbers::pi / 2;  // tangent to the circles
    across = radius;
    along = radius * (azimuth + std::numbers::pi);  // arc length (seam at the -x ray)
  } else {
    const double c = context.c, s = context.s;
    // The brushing direction wanders by a degree or two over the plate.
    direction = p.rotation + 0.03 * (value_noise(salted(p.seed, salt_angle), X / 300.0, Y / 300.0) - 0.5);
    along = c * X + s * Y;
    across = -s * X + c * Y;
  }
  const double tilt = scratch_tilt(p, along, across);
  const double stain = value_noise(salted(p.seed, salt_stain), X / 150.0, Y / 150.0);
  texel_values t;
  for (int k = 0; k < 3; ++k) t.diffuse[k] = p.base_colour[k] * (0.7 + 0.6 * stain);
  const double j = 1.0 + p.property_jitter * (2.0 * stain - 1.0);
  t.f0 = p.f0[0] * j;
  for (int k = 0; k < 3; ++k) t.specular[k] = p.specular_fraction[0] * p.specular_tint[0][k] * (1.0 - 0.5 * std::abs(tilt));
  t.sigma_x = p.sigma_along[0] * j;
  t.sigma_y = p.sigma_across[0] * j;
  // The scratches tilt the normal across the brushing direction.
  t.normal_x = -std::sin(direction) * tilt;
  t.normal_y = std::cos(direction) * tilt;
  t.alpha = wrap_half_turn(direction);
  return t;
}

/// Which ink (1-3) a pattern puts at (X, Y), or 0 for none; (c, s) is the layout's direction.
/// Edges are sharp: a texel is inked or not, as a print or a stamped foil is.
inline int pattern_slot(const procedural_parameters::pattern_layout& l, double c, double s, double X, double Y) {
  const double u = (c * X + s * Y) / l.period, v = (-s * X + c * Y) / l.period;
  switch (l.shape) {
    case 0: {  // stripes along v, one ink per stripe in turn
      const std::int64_t k = floor_to_int(u);
      return u - double(k) < l.duty ? 1 + int(floor_mod(k, 3)) : 0;
    }
    case 1: {  // dots on staggered rows, diameter (0.3 + duty) of a cell, an ink per dot
      const std::int64_t j = floor_to_int(v);
      const double shifted = u + 0.5 * double(floor_mod(j, 2));
      const std::int64_t i = floor_to_int(shifted);
      const double du = shifted - double(i) - 0.5, dv = v - double(j) - 0.5;
      const double radius = 0.5 * std::min(0.95, 0.3 + l.duty);
      return du * du + dv * dv < radius * radius ? 1 + int(3.0 * hash_uniform(l.seed, i, j)) : 0;
    }
    case 2: {  // check: bands both ways, the crossings in a third ink
      const bool a = u - std::floor(u) < l.duty, b = v - std::floor(v) < l.duty;
      return a && b ? 3 : a ? 1 : b ? 2 : 0;
    }
    case 3: {  // blocks: one glyph per cell (a stem and a bar at drawn places), lines of one ink, word gaps
      const std::int64_t i = floor_to_int(u), j = floor_to_int(v);
      if (hash_uniform(l.seed, i, j) < 0.15) return 0;
      const double fu = u - double(i), fv = v - double(j);
      const int ink = 1 + int(3.0 * hash_uniform(hash64(l.seed + 1), j, 0));
      for (std::uint64_t r = 0; r < 2; ++r) {
        const std::uint64_t h = hash64(l.seed + 2 + r);
        const double x0 = 0.1 + 0.5 * hash_uniform(h, i, j), y0 = 0.1 + 0.5 * hash_uniform(h + 1, i, j);
        const double w = r == 0 ? 0.12 + 0.2 * l.duty : 0.3 + 0.5 * l.duty, t = r == 0 ? 0.5 + 0.3 * l.duty : 0.12 + 0.2 * l.duty;
        if (fu >= x0 && fu < std::min(0.9, x0 + w) && fv >= y0 && fv < std::min(0.9, y0 + t)) return ink;
      }
      return 0;
    }
    default: {  // blots: thresholded fractal noise, the ink chosen by a slower noise
      const double n = fractal_noise(l.seed, u, v, 3);
      if (n < 0.3 + 0.4 * (1.0 - l.duty)) return 0;
      return 1 + std::min(2, int(3.0 * value_noise(hash64(l.seed + 1), u / 3.0, v / 3.0)));
    }
  }
}

/// A printed texel (also a coated one and the printed base of foil): paper or ink colour with
/// paper fibres; the printed kind's inks change the lobe width (ink_gloss), a coat covers all.
inline texel_values print_texel(const procedural_parameters& p, const texel_context& context, double X, double Y) {
  const bool coat = p.kind == material_kind::coated;
  const int slot = coat && p.plain_base ? 0 : pattern_slot(p.print, context.print_c, context.print_s, X, Y);
  const double fibre = value_noise(salted(p.seed, salt_fibre), X * 0.5, Y * 0.5);
  const rgb& colour = slot ? p.ink_colours[std::size_t((slot - 1) % p.ink_count)] : p.base_colour;
  const double shade = coat && p.plain_base ? 0.9 + 0.2 * fractal_noise(salted(p.seed, salt_shade), X / 60.0, Y / 60.0, 2)
                                            : 0.96 + 0.08 * fibre;
  texel_values t;
  for (int k = 0; k < 3; ++k) t.diffuse[k] = colour[k] * shade;
  const double gloss = slot && !coat ? p.ink_gloss : 1.0;
  t.f0 = p.f0[0];
  for (int k = 0; k < 3; ++k) t.specular[k] = std::min(1.0, p.specular_fraction[0] / gloss) * t.f0;
  t.sigma_x = p.sigma_along[0] * gloss;
  t.sigma_y = p.sigma_across[0] * gloss;
  if (coat) {  // orange peel: a slow waviness of the coat
    const double f = 1.0 / 24.0;
    t.normal_x = p.orange_peel * 2.0 * (value_noise(salted(p.seed, salt_peel), X * f, Y * f) - 0.5);
    t.normal_y = p.orange_peel * 2.0 * (value_noise(hash64(salted(p.seed, salt_peel)), X * f, Y * f) - 0.5);
  } else {
    t.normal_x = p.bump * 2.0 * (fibre - 0.5);
    t.normal_y = p.bump * 2.0 * (value_noise(hash64(salted(p.seed, salt_fibre)), X * 0.5, Y * 0.5) - 0.5);
  }
  t.alpha = wrap_half_turn(p.rotation);
  return t;
}

/// Distances from (x, y) to the nearest and the second-nearest point of a jittered grid with one
/// point per unit cell (cellular noise): their difference is 0 on the borders between cells.
inline std::array<double, 2> cellular(std::uint64_t seed, double x, double y) {
  const std::int64_t ix = floor_to_int(x), iy = floor_to_int(y);
  double first = 9.0, second = 9.0;
  for (std::int64_t j = iy - 1; j <= iy + 1; ++j) {
    for (std::int64_t i = ix - 1; i <= ix + 1; ++i) {
      const double dx = double(i) + hash_uniform(seed, i, j) - x, dy = double(j) + hash_uniform(hash64(seed), i, j) - y;
      const double d = std::sqrt(dx * dx + dy * dy);
      if (d < first) {
        second = first;
        first = d;
      } else if (d < second) {
        second = d;
      }
    }
  }
  return {first, second};
}

/// Height of leather's grain at (X, Y), texels: 1 on the cell tops, 0 in the creases between
/// cells, plus a slow unevenness of the hide.
inline double leather_height(const procedural_parameters& p, double X, double Y) {
  const double f = 1.0 / p.feature_scale;
  const auto [first, second] = cellular(salted(p.seed, salt_grain), X * f, Y * f);
  return smoothstep(0.0, 0.3, second - first) + 0.3 * fractal_noise(salted(p.seed, salt_shade), X * f * 0.3, Y * f * 0.3, 2);
}

/// A leather texel: the normal follows the grain's slope (central differences of leather_height),
/// creases are darker, duller and rougher.
inline texel_values leather_texel(const procedural_parameters& p, double X, double Y) {
  const double h = 0.5;
  const double top = leather_height(p, X, Y);
  const double slope_x = (leather_height(p, X + h, Y) - leather_height(p, X - h, Y)) / (2 * h);
  const double slope_y = (leather_height(p, X, Y + h) - leather_height(p, X, Y - h)) / (2 * h);
  const double crease = std::clamp(top, 0.0, 1.0);  // 0 in a crease
  const double mottle = fractal_noise(salted(p.seed, salt_stain), X / 40.0, Y / 40.0, 2);
  texel_values t;
  for (int k = 0; k < 3; ++k) t.diffuse[k] = p.base_colour[k] * (1.0 - p.colour_jitter * (1.0 - crease)) * (0.85 + 0.3 * mottle);
  const double j = 1.0 + p.property_jitter * (2.0 * mottle - 1.0);
  t.f0 = p.f0[0] * j;
  for (int k = 0; k < 3; ++k) t.specular[k] = std::min(1.0, p.specular_fraction[0] * j * (0.6 + 0.4 * crease)) * t.f0;
  t.sigma_x = p.sigma_along[0] * (1.3 - 0.3 * crease);
  t.sigma_y = p.sigma_across[0] * (1.3 - 0.3 * crease);
  // A crease about a fifth of a cell wide falls by ~1: scale the slope so its tilt is ~bump.
  const double scale = p.bump * p.feature_scale * 0.15;
  t.normal_x = -scale * slope_x;
  t.normal_y = -scale * slope_y;
  t.alpha = wrap_half_turn(p.rotation);
  return t;
}

/// A foil texel: metal inside the foil layout's shapes (dark diffuse, a'_s the tint, high F0,
/// lobes along the stamping direction, fine crinkles), the woven or printed base elsewhere.
inline texel_values foil_texel(const procedural_parameters& p, const texel_context& context, double X, double Y) {
  if (!pattern_slot(p.foil_layout, context.foil_c, context.foil_s, X, Y))
    return is_weave(p.base_kind) ? weave_texel(p, context, X, Y) : print_texel(p, context, X, Y);
  texel_values t;
  for (int k = 0; k < 3; ++k) t.diffuse[k] = 0.02 * p.foil_tint[k];
  const double crinkle_x = value_noise(salted(p.seed, salt_scratch), X / 6.0, Y / 6.0) - 0.5;
  const double crinkle_y = value_noise(hash64(salted(p.seed, salt_scratch)), X / 6.0, Y / 6.0) - 0.5;
  t.specular = p.foil_tint;
  t.f0 = p.foil_f0;
  t.sigma_x = p.foil_lobes[0];
  t.sigma_y = p.foil_lobes[1];
  t.normal_x = 2.0 * p.scratch_strength * crinkle_x;
  t.normal_y = 2.0 * p.scratch_strength * crinkle_y;
  t.alpha = wrap_half_turn(p.foil_layout.rotation);
  return t;
}

/// A texel's 12 parameters (parameter_index order) with every value forced into its valid range
/// (docs/method.md section 1), so no map the generator writes can be rejected by a renderer or an optimiser.
inline std::array<float, parameter_count> finish(const texel_values& t) {
  std::array<float, parameter_count> out{};
  for (int k = 0; k < 3; ++k) {
    out[std::size_t(diffuse_r + k)] = float(std::clamp(t.diffuse[k], 0.0, 1.0));
    out[std::size_t(specular_r + k)] = float(std::clamp(t.specular[k], 0.0, 1.0));
  }
  out[lobe_x] = float(std::clamp(t.sigma_x, 0.02, 1.0));
  out[lobe_y] = float(std::clamp(t.sigma_y, 0.02, 1.0));
  out[fresnel_f0] = float(std::clamp(t.f0, 0.01, 1.0));
  double nx = t.normal_x, ny = t.normal_y;
  const double length = std::sqrt(nx * nx + ny * ny), limit = 0.9;  // at most ~64 degrees of tilt
  if (length > limit) {
    nx *= limit / length;
    ny *= limit / length;
  }
  out[normal_x] = float(nx);
  out[normal_y] = float(ny);
  out[rotation] = float(std::clamp(t.alpha, -std::numbers::pi / 2, std::numbers::pi / 2));
  return out;
}

/// One texel of any kind, checked into range.
inline std::array<float, parameter_count> sample(const procedural_parameters& p, const texel_context& context, double X,
                                                 double Y) {
  if (is_weave(p.kind)) return finish(weave_texel(p, context, X, Y));
  switch (p.kind) {
    case material_kind::crushed_velvet: return finish(velvet_texel(p, X, Y));
    case material_kind::leather: return finish(leather_texel(p, X, Y));
    case material_kind::coated:
    case material_kind::printed: return finish(print_texel(p, context, X, Y));
    case material_kind::foil: return finish(foil_texel(p, context, X, Y));
    default: return finish(metal_texel(p, context, X, Y));
  }
}

}  // namespace procedural_detail

/// The material described by `p` at point (X, Y), in texels from the centre of the image, Y up
/// (texel (x, y) of a W x H map has its centre at X = x + 0.5 - W/2, Y = H/2 - y - 0.5): the 12
/// parameters in parameter_index order. For tests and tools that probe single points.
inline std::array<float, parameter_count> procedural_sample(const procedural_parameters& p, double X, double Y) {
  return procedural_detail::sample(p, procedural_detail::texel_context(p), X, Y);
}

/// The maps of the material described by `p`, width x height texels (any positive size).
/// Texel (x, y) is sampled at its centre, (x + 0.5 - W/2, H/2 - y - 0.5) texels from the middle
/// of the image, y up (row 0 at the top, docs/method.md section 4). Rows are independent: OpenMP over rows.
inline material_maps generate_material(const procedural_parameters& p, int width, int height) {
  using namespace procedural_detail;
  if (width <= 0 || height <= 0)
    throw std::invalid_argument("generate_material: size must be positive, got " + std::to_string(width) + " x " +
                                std::to_string(height));
  material_maps maps(width, height);
  const texel_context context(p);
#pragma omp parallel for schedule(static) if (std::size_t(width) * std::size_t(height) >= 16384)
  for (int y = 0; y < height; ++y) {
    const double Y = 0.5 * height - (double(y) + 0.5);
    for (int x = 0; x < width; ++x) {
      const auto values = sample(p, context, double(x) + 0.5 - 0.5 * width, Y);
      for (int k = 0; k < parameter_count; ++k) maps.at(k, x, y) = values[std::size_t(k)];
    }
  }
  return maps;
}

/// The maps of procedural material `seed`, width x height texels: draw_procedural_parameters then
/// generate_material. The same seed, size and options give the same maps on every machine.
inline material_maps generate_material(std::uint64_t seed, int width, int height, const procedural_options& options = {}) {
  return generate_material(draw_procedural_parameters(seed, options), width, height);
}

}  // namespace anisocap
