#pragma once
// `anisocap synthesize`: a procedural material, its map set, rendered inputs and capture.json.
#include <memory>

#include "anisocap/brdf/canonical_maps.hpp"
#include "common.hpp"

namespace anisocap::commands {

/// What synthesize makes.
struct synthesize_settings {
  fs::path out = "anisocap-synthetic";
  int width = 256, height = 256, images = 12;
  std::string set = "alpha";  ///< configuration set (docs/method.md section 6)
  std::uint64_t seed = 1;
  std::string kind;           ///< material kind (empty: drawn from the seed and `mix`)
  material_mix mix = material_mix::original;  ///< families the kind is drawn from without --kind
  fresnel_options fresnel;    ///< set alpha's grazing configurations (default: the paper's 2)
  sensor_noise noise;         ///< simulated sensor noise on the rendered inputs
};

/// A procedural material, its map set (truth/), N rendered inputs and capture.json.
inline void synthesize(const synthesize_settings& a) {
  if (a.width < 1 || a.height < 1) throw std::invalid_argument("--width and --height must be positive");
  if (a.images < 4) throw std::invalid_argument("--images must be at least 4 (set alpha needs 2 Fresnel and 2 independent)");
  // The maps and the rendered inputs, each about twice (working copies, the files' buffers).
  const double needed = double(a.width) * a.height * sizeof(float) * 2.0 * (parameter_count + 3.0 * a.images);
  const double available = double(sysconf(_SC_PHYS_PAGES)) * double(sysconf(_SC_PAGESIZE));
  if (needed > available)
    throw std::invalid_argument("a " + std::to_string(a.width) + " x " + std::to_string(a.height) + " material with " +
                                std::to_string(a.images) + " inputs needs about " + std::to_string(int(std::ceil(needed / (1 << 30)))) +
                                " GiB of memory; this machine has " + std::to_string(int(available / (1 << 30))) + " GiB");
  procedural_options options;
  options.mix = a.mix;
  if (!a.kind.empty()) {
    options.kind = material_kind_from_name(a.kind);
    if (!options.kind) throw std::invalid_argument("unknown --kind '" + a.kind + "'");
  }
  material_maps truth = generate_material(a.seed, a.width, a.height, options);
  canonicalise(truth);  // the written truth/ is canonical (brdf/canonical_maps.hpp); renders are unchanged
  capture cap;
  if (a.set == "alpha") cap = set_alpha(a.images, a.seed, a.width, a.height, a.fresnel);
  else if (a.set == "beta") cap = set_beta(a.images, a.seed, a.width, a.height);
  else throw std::invalid_argument("--set must be alpha or beta, got '" + a.set + "'");
  a.noise.validate();
  output_lock lock(a.out);  // one run per output folder
  write_maps(truth, a.out / "truth");
  std::vector<image> photos = render(truth, cap);
  add_sensor_noise(photos, a.noise, a.seed);
  write_images(photos, cap, a.out);
  write_capture(cap, a.out / "capture.json");
  std::fprintf(stderr, "synthesized %s (%s, seed %llu, %dx%d) with %d inputs (set %s) in %s\n",
               material_kind_name(draw_procedural_parameters(a.seed, options).kind), a.kind.empty() ? "kind from seed" : "forced",
               static_cast<unsigned long long>(a.seed), a.width, a.height, a.images, a.set.c_str(), a.out.c_str());
}

/// Registers `anisocap synthesize`.
inline void add_synthesize_command(CLI::App& app) {
  auto s = std::make_shared<synthesize_settings>();
  auto* c = app.add_subcommand("synthesize", "make a procedural material, its map set (truth/), rendered inputs and capture.json");
  c->add_option("-o,--out", s->out, "output folder");
  c->add_option("--width", s->width, "material width in texels");
  c->add_option("--height", s->height, "material height in texels");
  c->add_option("--images", s->images, "number of input images");
  c->add_option("--set", s->set, "configuration set: alpha (Fresnel + anisotropic pairs + independent) or beta (independent + mirror)");
  c->add_option("--seed", s->seed, "material and configuration seed");
  c->add_option("--kind", s->kind,
                "force a material kind: plain, basket, twill, herringbone, satin, velvet, brushed, spun, leather, coated, printed, foil");
  c->add_option("--fresnel", s->fresnel.count,
                "grazing (Fresnel) configurations in set alpha; 4 with N = 12 separates a'_s from F0 better on metals (studies/README.md)")
      ->check(CLI::NonNegativeNumber);
  add_mix_option(c, s->mix, {material_mix::original, material_mix::extended, material_mix::training},
                 "families the kind is drawn from without --kind: original, extended or training");
  add_noise_options(c, s->noise);
  c->callback([s] { synthesize(*s); });
}

}  // namespace anisocap::commands
