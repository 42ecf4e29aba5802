// Whether the per-texel standard deviations (pipeline/uncertainty.hpp) are calibrated: over
// synthetic captures with sensor noise, the share of texels whose true value lies within 1 and 2
// standard deviations of the captured one, per parameter (68% and 95% for a calibrated Gaussian).
//
// For each family (one seeded procedural material each), each image count and each light (set
// alpha's separate lamp, or a phone's flash beside the lens), the default capture with the shipped
// networks runs on renders with shot and read noise; the coverage is counted over every texel
// (alpha only where the true lobe is anisotropic, |sx - sy| > 0.2 max(sx, sy), since alpha means
// nothing on an isotropic one). Prints a markdown table, and with --csv FILE the per-texel
// (|error| / sd) quantiles for a reliability plot.
//
//   anisocap_study_uncertainty_calibration [--size 96] [--images 8,12] [--shot 0.01] [--read 0.002]
//       [--families plain,twill,...] [--lights lamp,flash] [--models DIR]
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/sensor_noise.hpp"

using namespace anisocap;

namespace {

std::vector<std::string> split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) out.push_back(item);
  return out;
}

/// The difference of two rotations, wrapped to [-pi/2, pi/2) (alpha and alpha + pi are one lobe).
double rotation_difference(double a, double b) {
  double d = std::fmod(a - b + 0.5 * std::numbers::pi, std::numbers::pi);
  if (d < 0) d += std::numbers::pi;
  return d - 0.5 * std::numbers::pi;
}

}  // namespace

int main(int argc, char** argv) {
  int size = 96;
  std::string images = "8,12", families = "plain,basket,twill,herringbone,satin,velvet,brushed,spun", lights = "lamp,flash";
  std::string models = ANISOCAP_SWEEP_MODELS;
  sensor_noise noise{0.01, 0.002};
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i], v = argv[i + 1];
    if (a == "--size") size = std::atoi(v.c_str());
    else if (a == "--images") images = v;
    else if (a == "--families") families = v;
    else if (a == "--lights") lights = v;
    else if (a == "--models") models = v;
    else if (a == "--shot") noise.shot = std::atof(v.c_str());
    else if (a == "--read") noise.read = std::atof(v.c_str());
    else { std::fprintf(stderr, "uncertainty_calibration: unknown option %s\n", a.c_str()); return 2; }
  }
  if (argc % 2 == 0) { std::fprintf(stderr, "uncertainty_calibration: an option without its value\n"); return 2; }
  try {
    const networks nets = load_networks(models);
    std::array<double, parameter_count> within1{}, within2{}, counted{};
    int run = 0;
    for (const material_kind kind : material_kinds_from_names(families))
      for (const std::string& count_text : split(images))
        for (const std::string& light : split(lights)) {
          const int count = std::atoi(count_text.c_str());
          const std::uint64_t seed = 500 + std::uint64_t(run++);
          procedural_options po;
          po.kind = kind;
          material_maps truth = generate_material(seed, size, size, po);
          canonicalise(truth);
          capture cap = set_alpha(count, seed, size, size);
          if (light == "flash")
            for (capture_image& im : cap.images) {
              im.light = im.camera;
              im.light[0] += 0.05f;
            }
          else if (light != "lamp") throw std::invalid_argument("--lights takes lamp and flash");
          std::vector<image> photos = render(truth, cap);
          add_sensor_noise(photos, noise, seed);
          const capture_result r = capture_material(cap, photos, nets, capture_options{});
          const material_maps& sd = r.uncertainty->sd;
          std::array<double, parameter_count> in1{}, in2{}, n{};
          for (std::size_t i = 0; i < truth.texel_count(); ++i) {
            const float sx = truth.plane(lobe_x)[i], sy = truth.plane(lobe_y)[i];
            for (int k = 0; k < parameter_count; ++k) {
              if (k == rotation && !(std::abs(sx - sy) > 0.2f * std::max(sx, sy))) continue;
              const double error = k == rotation ? rotation_difference(r.maps.plane(k)[i], truth.plane(k)[i])
                                                 : double(r.maps.plane(k)[i]) - truth.plane(k)[i];
              const double s = sd.plane(k)[i];
              n[std::size_t(k)] += 1;
              in1[std::size_t(k)] += std::abs(error) <= s;
              in2[std::size_t(k)] += std::abs(error) <= 2 * s;
            }
          }
          std::printf("%-12s N=%-2d %-5s", material_kind_name(kind), count, light.c_str());
          for (int k = 0; k < parameter_count; ++k) {
            within1[std::size_t(k)] += in1[std::size_t(k)];
            within2[std::size_t(k)] += in2[std::size_t(k)];
            counted[std::size_t(k)] += n[std::size_t(k)];
            if (n[std::size_t(k)] > 0) std::printf(" %s %.0f/%.0f", parameter_name(k), 100 * in1[std::size_t(k)] / n[std::size_t(k)],
                                                   100 * in2[std::size_t(k)] / n[std::size_t(k)]);
          }
          std::printf("\n");
          std::fflush(stdout);
        }
    std::printf("\n| parameter | within 1 sd (68%%) | within 2 sd (95%%) |\n|---|---|---|\n");
    for (int k = 0; k < parameter_count; ++k)
      if (counted[std::size_t(k)] > 0)
        std::printf("| %s | %.0f%% | %.0f%% |\n", parameter_name(k), 100 * within1[std::size_t(k)] / counted[std::size_t(k)],
                    100 * within2[std::size_t(k)] / counted[std::size_t(k)]);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "uncertainty_calibration: %s\n", e.what());
    return 1;
  }
}
