// Whether `anisocap plan`'s photographs help more than others: from a flash-only start (a phone's
// photographs, the light beside the lens), for one procedural material of each family, add K
// photographs chosen by
//   - plan: plan_photographs on the first capture's maps (pipeline/plan.hpp);
//   - rule: the paper's Fresnel configurations (set alpha's grazing pair, camera low, light mirrored);
//   - random: independent configurations (camera and light each anywhere above the sample);
// capture again from all the photographs (the default capture with the shipped networks), and
// measure the maps against the truth (compare_maps, the mean of the five map errors) and the image
// error of three grazing views (camera and lamp 17 degrees above the plane, opposite: where F0
// shows). Prints one line per material and a markdown table of the means.
//
// With --seeds N, N materials per family (seeds 900 + family index + 100 s). The table ends with
// how often each strategy's error was the lowest of the three additions.
//
//   anisocap_study_plan_comparison [--size 96] [--start 6] [--add 2] [--seeds 1] [--families ...] [--models DIR]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/pipeline/plan.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/sensor_noise.hpp"

using namespace anisocap;

int main(int argc, char** argv) {
  int size = 96, start = 6, add = 2, seeds = 1;
  std::string families = "plain,basket,twill,herringbone,satin,velvet,brushed,spun", models = ANISOCAP_SWEEP_MODELS;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i], v = argv[i + 1];
    if (a == "--size") size = std::atoi(v.c_str());
    else if (a == "--start") start = std::atoi(v.c_str());
    else if (a == "--add") add = std::atoi(v.c_str());
    else if (a == "--seeds") seeds = std::atoi(v.c_str());
    else if (a == "--families") families = v;
    else if (a == "--models") models = v;
    else { std::fprintf(stderr, "plan_comparison: unknown option %s\n", a.c_str()); return 2; }
  }
  if (argc % 2 == 0) { std::fprintf(stderr, "plan_comparison: an option without its value\n"); return 2; }
  try {
    const networks nets = load_networks(models);
    const sensor_noise noise{0.01, 0.002};
    capture grazing;
    const double elevation = 17 * std::numbers::pi / 180;
    for (double azimuth : {0.0, 0.25 * std::numbers::pi, 0.5 * std::numbers::pi})
      grazing.images.push_back(mirror_configuration_at(
          {0, 0, 0}, {std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth), std::sin(elevation)}, 2.0, 2.0));
    const char* strategies[] = {"start", "plan", "rule", "random"};
    if (seeds < 1) throw std::invalid_argument("--seeds must be at least 1");
    double map_sum[4] = {}, grazing_sum[4] = {}, f0_sum[4] = {};
    int map_wins[4] = {}, grazing_wins[4] = {}, f0_wins[4] = {};
    int materials = 0;
    const std::vector<material_kind> kinds = material_kinds_from_names(families);
    for (std::size_t material = 0; material < kinds.size() * std::size_t(seeds); ++material) {
      const std::size_t family = material / std::size_t(seeds), s_index = material % std::size_t(seeds);
      const material_kind kind = kinds[family];
      const std::uint64_t seed = 900 + std::uint64_t(family) + 100 * std::uint64_t(s_index);
      procedural_options po;
      po.kind = kind;
      material_maps truth = generate_material(seed, size, size, po);
      canonicalise(truth);
      random_generator rng(seed);
      const capture flash = flash_set(start, rng, size, size, {0.05f, 0.0f, 0.0f});
      auto run = [&](const capture& cap) {
        std::vector<image> photos = render(truth, cap);
        add_sensor_noise(photos, noise, seed + cap.images.size());
        return capture_material(cap, photos, nets, capture_options{});
      };
      const capture_result first = run(flash);
      // The plan, on the first capture's maps and its exposure-normalised photographs.
      capture seen = flash;
      std::vector<image> photos = render(truth, flash);
      add_sensor_noise(photos, noise, seed + flash.images.size());
      apply_exposure(seen, photos, first.exposure_scale);
      plan_options o;
      o.photos = add;
      const plan_result plan = plan_photographs(first.maps, seen, make_loss_targets(photos), first.uncertainty->noise, o);
      capture planned = flash, rule = flash, random = flash;
      for (const planned_photo& p : plan.photos) {
        capture_image im = p.candidate.config;
        for (float& i : im.intensity) i = float(i / first.exposure_scale);  // back into the capture's own units
        planned.images.push_back(im);
      }
      random_generator extra(seed ^ 0x5eedULL);
      for (int i = 0; i < add; ++i) {
        rule.images.push_back(fresnel_configuration(extra, size, size));
        random.images.push_back(independent_configuration(extra, size, size));
      }
      const capture_result results[4] = {first, run(planned), run(rule), run(random)};
      std::printf("%-12s %4llu", material_kind_name(kind), static_cast<unsigned long long>(seed));
      double maps_errors[4], grazing_errors[4], f0_errors[4];
      for (int s = 0; s < 4; ++s) {
        const parameter_errors e = compare_maps(results[s].maps, truth);
        const double maps_error = (e.diffuse + e.specular + e.normal + e.lobes + e.fresnel) / 5;
        const double g = novel_view_error(results[s].maps, truth, grazing);
        map_sum[s] += maps_error;
        grazing_sum[s] += g;
        f0_sum[s] += e.fresnel;
        maps_errors[s] = maps_error, grazing_errors[s] = g, f0_errors[s] = e.fresnel;
        std::printf("  %s: maps %.4f F0 %.4f grazing %.3f", strategies[s], maps_error, e.fresnel, g);
      }
      auto best_addition = [](const double* e) { return 1 + int(std::min_element(e + 1, e + 4) - (e + 1)); };
      ++map_wins[best_addition(maps_errors)], ++grazing_wins[best_addition(grazing_errors)], ++f0_wins[best_addition(f0_errors)];
      std::printf("\n");
      std::fflush(stdout);
      ++materials;
    }
    std::printf("\n| photographs | mean map error | F0 error | grazing-view error |\n|---|---|---|---|\n");
    for (int s = 0; s < 4; ++s)
      std::printf("| %s%s | %.4f | %.4f | %.3f |\n", s == 0 ? "flash start" : strategies[s], s == 0 ? "" : " (+K)", map_sum[s] / materials,
                  f0_sum[s] / materials, grazing_sum[s] / materials);
    std::printf("| lowest of the three additions (of %d) | %d / %d / %d | %d / %d / %d | %d / %d / %d |\n", materials, map_wins[1], map_wins[2],
                map_wins[3], f0_wins[1], f0_wins[2], f0_wins[3], grazing_wins[1], grazing_wins[2], grazing_wins[3]);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "plan_comparison: %s\n", e.what());
    return 1;
  }
}
