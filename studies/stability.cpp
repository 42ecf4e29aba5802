// Numerical stability of the capture: the scenarios of
// tests/pipeline/stability_test.cpp at bench size, printed as Markdown tables (studies/README.md,
// "Numerical stability"). Every run is `capture_once` with the refine stage only (first guess from
// the photographs, then per-texel Adam, as `anisocap capture --stages refine`), exposure
// normalisation on unless a row says otherwise.
//
//   anisocap_study_stability [--size 256] [--images 12] [--steps 300] [--seed 7]
//
// Rows: the unscaled capture against the truth; the capture with intensities and photographs
// multiplied by a factor against the unscaled run (1 + 2^-23 shows how far one ulp of input moves
// the refine; 2^-13 must give identical maps); photographs clipped at 1 and at their 95th
// percentile against the truth; a capture whose cameras and lights are 75 to 88 degrees from the
// normal against the truth; and a photograph with one NaN pixel, which must be refused.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/random.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/configurations.hpp"
#include "../tests/support/stability_scenes.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

/// One refine-only pipeline run and its wall time.
struct run_result {
  capture_result pipeline;
  double seconds = 0;
};

run_result run_refine(const capture& cap, const std::vector<image>& photos, int steps, bool normalise = true) {
  capture_options o;
  o.stages = pipeline_stages{false, false, false, true};
  o.refine = refine_options{};  // from the first guess
  o.refine.steps = steps;
  o.kernel = kernel_options::parse("full");
  o.normalise_exposure = normalise;
  const auto t0 = std::chrono::steady_clock::now();
  run_result r{capture_once(cap, photos, o), 0};
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

/// Non-finite map values.
std::size_t non_finite(const material_maps& m) {
  std::size_t n = 0;
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < m.texel_count(); ++i) n += !std::isfinite(m.plane(k)[i]);
  return n;
}

/// Finite map values outside their parameter's range (docs/method.md section 1).
std::size_t out_of_range(const material_maps& m) {
  std::size_t bad = 0;
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0})
      bad += m.plane(k)[i] < 0.0f || m.plane(k)[i] > 1.0f;
    for (int k : {lobe_x, lobe_y}) bad += m.plane(k)[i] <= 0.0f || m.plane(k)[i] > 1.0f;
    const float nx = m.plane(normal_x)[i], ny = m.plane(normal_y)[i];
    bad += nx * nx + ny * ny >= 1.0f;
    bad += std::abs(m.plane(rotation)[i]) > std::numbers::pi_v<float> / 2 * (1 + 1e-6f);
  }
  return bad;
}


/// One table row: a run compared with a map set.
void print_row(const std::string& scenario, const std::string& against, const run_result& r, const material_maps& other) {
  const material_maps& m = r.pipeline.maps;
  const parameter_errors e = compare_maps(m, other);
  std::size_t bad_losses = 0;
  for (const auto& s : r.pipeline.stages) bad_losses += !std::isfinite(s.loss);
  std::printf("| %s | %s | %.2g | %.2g | %.2g | %.2g | %.2g | %.2g | %.1e / %.1e / %.1e | %zu | %zu | %.4f | %.1f |\n", scenario.c_str(),
              against.c_str(), max_difference(m, other, diffuse_r, diffuse_b), max_difference(m, other, specular_r, specular_b),
              max_difference(m, other, lobe_x, lobe_y), max_difference(m, other, fresnel_f0, fresnel_f0),
              max_difference(m, other, normal_x, normal_y), max_difference(m, other, rotation, rotation), e.diffuse, e.normal,
              e.lobes, non_finite(m) + bad_losses, out_of_range(m), r.pipeline.stages.back().loss, r.seconds);
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  int size = 256, images = 12, steps = 300;
  std::uint64_t seed = 7;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) { std::fprintf(stderr, "%s needs a value\n", a.c_str()); return 2; }
    const char* v = argv[++i];
    if (a == "--size") size = std::atoi(v);
    else if (a == "--images") images = std::atoi(v);
    else if (a == "--steps") steps = std::atoi(v);
    else if (a == "--seed") seed = std::strtoull(v, nullptr, 10);
    else { std::fprintf(stderr, "unknown option %s (--size, --images, --steps, --seed)\n", a.c_str()); return 2; }
  }
  if (size < 16 || images < 4 || steps < 1) { std::fprintf(stderr, "need --size >= 16, --images >= 4, --steps >= 1\n"); return 2; }

  const material_maps truth = generate_material(seed, size, size);
  const capture cap = set_alpha(images, seed, size, size);
  const std::vector<image> photos = render(truth, cap);
  std::printf("Procedural material %llu (%s), %d x %d, %d set-alpha images, refine only, %d steps, learning rate 0.03.\n\n",
              static_cast<unsigned long long>(seed), material_kind_name(draw_procedural_parameters(seed).kind), size, size, images,
              steps);
  std::printf("| scenario | against | a_d | a'_s | sigma | F0 | n_s | alpha | MSE a_d / n_s / sigma | NaN/Inf | out of range | final loss | s |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");

  const run_result reference = run_refine(cap, photos, steps);
  print_row("unscaled", "truth", reference, truth);
  struct factor_row { float factor; const char* name; bool normalise; };
  for (const factor_row& f : {factor_row{std::nextafter(1.0f, 2.0f), "x (1 + 2^-23), one ulp", true},
                              factor_row{0x1p-13f, "x 2^-13", true}, factor_row{1e-4f, "x 1e-4", true},
                              factor_row{1e4f, "x 1e4", true}, factor_row{1e-4f, "x 1e-4, not normalised", false},
                              factor_row{1e4f, "x 1e4, not normalised", false}}) {
    const auto [c, p] = scaled(cap, photos, f.factor);
    print_row(f.name, "unscaled run", run_refine(c, p, steps, f.normalise), reference.pipeline.maps);
  }
  for (const double q : {-1.0, 0.95}) {
    const float level = q < 0 ? 1.0f : quantile(photos, q);
    std::size_t at = 0, total = 0;
    const std::vector<image> p = clipped(photos, level);
    for (const image& im : p)
      for (int c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < im.pixel_count(); ++i, ++total) at += im.plane(c)[i] >= level;
    char name[96];
    std::snprintf(name, sizeof name, "clipped at %.3g (%s, %.1f%% of values)", level, q < 0 ? "1" : "95th percentile",
                  100.0 * double(at) / double(total));
    print_row(name, "truth", run_refine(cap, p, steps), truth);
  }
  {
    const capture grazing = grazing_capture(images, seed);
    print_row("cameras and lights 75-88 deg from the normal", "truth", run_refine(grazing, render(truth, grazing), steps), truth);
  }
  {
    std::vector<image> p = photos;
    p[images / 2].at(1, size / 3, size / 5) = std::numeric_limits<float>::quiet_NaN();
    std::string outcome = "no error (NaN maps would follow)";
    try {
      run_refine(cap, p, steps);
    } catch (const std::invalid_argument& e) {
      outcome = std::string("std::invalid_argument: ") + e.what();
    }
    std::printf("\nOne NaN pixel in image %d: %s\n", images / 2, outcome.c_str());
  }
  return 0;
}
