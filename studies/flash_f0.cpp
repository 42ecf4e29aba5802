// What a flash capture writes for F0, and what that costs a renderer's grazing view.
//
// A phone's flash sits beside the lens: every photograph sees the half vector along the view
// direction, where the Fresnel factor F / F0 is 1, so the photographs do not determine F0 and the
// automatic kernel leaves Fresnel out. For one procedural material of each original family this
// synthesises a flash capture (the light 8% of the sample's size beside the camera), runs the default
// capture with the shipped networks, and measures the image error (docs/method.md section 5) of
// three grazing views (camera and lamp 17 degrees above the plane on opposite sides, where a fabric
// shows its sheen) for the written maps and for the same maps with F0 replaced: by the truth, by
// the written map's median, by 0.04 (a dielectric) and by 1 (the reduced kernel's placeholder).
//
//   anisocap_study_flash_f0 [--size 128] [--images 10] [--models DIR] [--families satin,velvet]
// (the material of the i-th family listed has seed 100 + i: the default order gives docs/results.md's table)
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>

#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"

using namespace anisocap;

int main(int argc, char** argv) {
  int size = 128, images = 10;
  std::string models = ANISOCAP_SWEEP_MODELS, families = "satin,twill,velvet,brushed,plain,herringbone,spun,basket";
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string a = argv[i];
    if (a == "--size") size = std::atoi(argv[i + 1]);
    else if (a == "--images") images = std::atoi(argv[i + 1]);
    else if (a == "--models") models = argv[i + 1];
    else if (a == "--families") families = argv[i + 1];
    else { std::fprintf(stderr, "flash_f0: unknown option %s\n", argv[i]); return 2; }
  }
  if (argc % 2 == 0) { std::fprintf(stderr, "flash_f0: an option without its value\n"); return 2; }
  try {
    const networks nets = load_networks(models);
    capture grazing;
    const double elevation = 17 * std::numbers::pi / 180;
    for (double azimuth : {0.0, 0.25 * std::numbers::pi, 0.5 * std::numbers::pi})
      grazing.images.push_back(mirror_configuration_at(
          {0, 0, 0}, {std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth), std::sin(elevation)}, 2.0, 2.0));
    std::printf("| family | kernel | F0 written (mean) | F0 true (mean) | grazing error: written | true F0 | ratio | median F0 | F0 = 0.04 | F0 = 1 |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
    int index = 0;
    for (const material_kind kind : material_kinds_from_names(families)) {
      procedural_options po;
      po.kind = kind;
      const material_maps truth = generate_material(100 + index, size, size, po);
      random_generator rng(7 + index);
      ++index;
      const capture cap = flash_set(images, rng, size, size, {0.08f, 0.03f, 0.0f});
      const capture_result r = capture_material(cap, render(truth, cap), nets, capture_options{});
      const std::size_t n = truth.texel_count();
      auto with_f0 = [&](auto value) {
        material_maps m = r.maps;
        for (std::size_t i = 0; i < n; ++i) m.plane(fresnel_f0)[i] = value(i);
        return novel_view_error(m, truth, grazing);
      };
      std::vector<float> sorted(r.maps.plane(fresnel_f0), r.maps.plane(fresnel_f0) + n);
      std::nth_element(sorted.begin(), sorted.begin() + std::ptrdiff_t(n / 2), sorted.end());
      const float median = sorted[n / 2];
      double mean = 0, mean_true = 0;
      for (std::size_t i = 0; i < n; ++i) { mean += r.maps.plane(fresnel_f0)[i]; mean_true += truth.plane(fresnel_f0)[i]; }
      const double written = novel_view_error(r.maps, truth, grazing);
      const double ideal = with_f0([&](std::size_t i) { return truth.plane(fresnel_f0)[i]; });
      std::printf("| %s | %s | %.3f | %.3f | %.3f | %.3f | %.2f | %.3f | %.3f | %.3f |\n", material_kind_name(kind),
                  r.features.fresnel ? "Fresnel" : "no Fresnel", mean / double(n), mean_true / double(n), written, ideal,
                  written / ideal, with_f0([&](std::size_t) { return median; }), with_f0([](std::size_t) { return 0.04f; }),
                  with_f0([](std::size_t) { return 1.0f; }));
      std::fflush(stdout);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flash_f0: %s\n", e.what());
    return 1;
  }
}
