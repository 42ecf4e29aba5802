// How faithful each export is (README "Exports"): converts procedural materials of every kind to
// each target (export/conversion.hpp), evaluates the target's published model against the Ward +
// Schlick BRDF over a grid of light and view directions (export/fidelity.hpp), and prints the
// relative L1 error per target and kind. `--sweep` first sweeps the GGX alpha / Ward sigma ratio k
// per target and reports the minimiser (the defaults of exports::conversion_options).
//   export_fidelity [--size 64] [--per-kind 2] [--stride 4] [--sweep]
#include <CLI/CLI.hpp>

#include <cstdio>
#include <vector>

#include "anisocap/data/procedural.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/export/fidelity.hpp"

using namespace anisocap;

int main(int argc, char** argv) {
  CLI::App app{"error of each export's conversion, on procedural materials"};
  int size = 64, per_kind = 2, stride = 4;
  bool sweep = false;
  app.add_option("--size", size, "material size in texels")->capture_default_str();
  app.add_option("--per-kind", per_kind, "materials per kind")->capture_default_str();
  app.add_option("--stride", stride, "measure every n-th texel along x and y")->capture_default_str();
  app.add_flag("--sweep", sweep, "sweep the alpha/sigma ratio per GGX target first");
  CLI11_PARSE(app, argc, argv);

  std::vector<material_maps> materials;
  std::vector<int> kinds;
  for (int k = 0; k < material_kind_count; ++k)
    for (int i = 0; i < per_kind; ++i) {
      procedural_options po;
      po.kind = material_kind(k);
      materials.push_back(generate_material(1000 + 17 * k + i, size, size, po));
      canonicalise(materials.back());
      kinds.push_back(k);
    }
  exports::fidelity_options fo;
  fo.texel_stride = stride;
  auto measure_all = [&](const exports::fidelity_options& o, std::vector<exports::fidelity_result>* each) {
    std::array<double, exports::target_count> mean{};
    std::vector<exports::fidelity_result> results(materials.size());
#pragma omp parallel for schedule(dynamic)
    for (std::size_t m = 0; m < materials.size(); ++m) results[m] = exports::measure_fidelity(materials[m], o);
    for (const auto& r : results)
      for (int t = 0; t < exports::target_count; ++t) mean[t] += r.error[t] / double(results.size());
    if (each) *each = results;
    return mean;
  };
  if (sweep) {
    std::printf("| k (GGX alpha / Ward sigma) | gltf | blender | mtlx |\n|---|---|---|---|\n");
    double best[3] = {1e30, 1e30, 1e30}, best_k[3] = {1, 1, 1};
    for (double k = 0.6; k <= 1.61; k += 0.1) {
      exports::fidelity_options o = fo;
      o.conversion = {k, k, k};
      const auto mean = measure_all(o, nullptr);
      std::printf("| %.1f | %.3f | %.3f | %.3f |\n", k, mean[0], mean[1], mean[2]);
      for (int t = 0; t < 3; ++t)
        if (mean[t] < best[t]) best[t] = mean[t], best_k[t] = k;
      std::fflush(stdout);
    }
    std::printf("\nminimisers: gltf k = %.1f, blender k = %.1f, mtlx k = %.1f\n\n", best_k[0], best_k[1], best_k[2]);
  }
  std::vector<exports::fidelity_result> each;
  const auto mean = measure_all(fo, &each);
  std::printf("| material kind | gltf | blender | mtlx (Standard Surface) | mitsuba (ward) |\n|---|---|---|---|---|\n");
  for (int k = 0; k < material_kind_count; ++k) {
    std::array<double, exports::target_count> e{}, clamped{};
    for (std::size_t m = 0; m < materials.size(); ++m)
      if (kinds[m] == k)
        for (int t = 0; t < exports::target_count; ++t) e[t] += each[m].error[t] / per_kind, clamped[t] += each[m].clamped_fraction[t] / per_kind;
    std::printf("| %s |", material_kind_name(material_kind(k)));
    for (int t = 0; t < exports::target_count; ++t) std::printf(" %.1f %% (%.0f %%) |", 100 * e[t], 100 * clamped[t]);
    std::printf("\n");
  }
  std::printf("| **mean** |");
  for (int t = 0; t < exports::target_count; ++t) std::printf(" **%.1f %%** |", 100 * mean[t]);
  std::printf("\n\nrelative L1 error of the cosine-weighted BRDF over %zu x %zu light/view directions (zenith <= 75 deg);\n"
              "in parentheses: texels the target cannot express exactly (lobe wider than alpha = 1, aspect ratio over\n"
              "the target's limit; for mitsuba a rotated lobe or a shading normal)\n",
              exports::fidelity_directions(fo).size(), exports::fidelity_directions(fo).size());
  return 0;
}
