#pragma once
// `anisocap export MAPDIR --format F -o OUT`: a map set for another renderer (export/export.hpp).
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>

#include "anisocap/data/map_io.hpp"
#include "anisocap/export/export.hpp"
#include "anisocap/export/tileable.hpp"

namespace anisocap::commands {

/// Registers `export`.
inline void add_export_command(CLI::App& app) {
  struct settings {
    std::filesystem::path maps, out;
    std::string format;
    exports::export_options options;
    bool tileable = false;
    tileable_options tile;
  };
  auto s = std::make_shared<settings>();
  auto* cmd = app.add_subcommand("export", "convert a map set for another renderer: glTF, Mitsuba 0.6, Blender, MaterialX");
  cmd->add_option("maps", s->maps, "map set folder")->required();
  cmd->add_option("--format", s->format, "gltf (a .gltf file), mitsuba, blender or mtlx (a folder)")
      ->required()
      ->check(CLI::IsMember({"gltf", "mitsuba", "blender", "mtlx"}));
  cmd->add_option("-o,--out", s->out, "output: the .gltf file, or the folder for the other formats")->required();
  cmd->add_option("--width", s->options.width, "glTF: physical width of the sample in metres (default: longest side 1)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--gltf-anisotropy", s->options.conversion.gltf_anisotropy_use,
                  "glTF: KHR_materials_anisotropy where it fits the maps better than isotropic GGX (auto), always (on) or "
                  "never (off)")
      ->transform(CLI::CheckedTransformer(std::map<std::string, exports::gltf_anisotropy>{
                                              {"auto", exports::gltf_anisotropy::automatic},
                                              {"on", exports::gltf_anisotropy::on},
                                              {"off", exports::gltf_anisotropy::off}},
                                          CLI::ignore_case)
                     .description(""))
      ->type_name("auto|on|off")
      ->default_str("auto");
  cmd->add_flag("--tileable", s->tileable,
                "export a seamless tile: the maps cross-faded over an overlap at each edge (export/tileable.hpp), "
                "smaller by the overlap along each axis");
  cmd->add_option("--tile-overlap", s->tile.overlap, "with --tileable: the overlap, as a fraction of each side")
      ->check(CLI::Range(0.01, 0.5));
  cmd->callback([s] {
    material_maps maps = read_maps(s->maps);
    if (s->tileable) {
      const int w = maps.width(), h = maps.height();
      const seam_statistics before = measure_seam(maps);
      try {
        maps = make_tileable(maps, s->tile);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(s->maps.string() + ": --tileable: " + e.what());
      }
      const seam_statistics after = measure_seam(maps);
      double mean_shift = 0, variance_ratio_low = 1e300, variance_ratio_high = 0;
      for (int k = 0; k < parameter_count; ++k) {
        if (k == rotation || before.variance[k] < 1e-12) continue;  // the rotation's statistics are angles
        mean_shift = std::max(mean_shift, std::abs(after.mean[k] - before.mean[k]) / std::sqrt(before.variance[k]));
        variance_ratio_low = std::min(variance_ratio_low, after.variance[k] / before.variance[k]);
        variance_ratio_high = std::max(variance_ratio_high, after.variance[k] / before.variance[k]);
      }
      std::fprintf(stderr,
                   "tileable: %dx%d maps made into a %dx%d tile; wrap-edge step / interior step %.2f -> %.2f (mean over the maps), "
                   "largest mean shift %.3f standard deviations, variance ratios %.3f-%.3f\n",
                   w, h, maps.width(), maps.height(), before.mean_seam_ratio(), after.mean_seam_ratio(), mean_shift,
                   variance_ratio_low > variance_ratio_high ? 1.0 : variance_ratio_low, variance_ratio_high > 0 ? variance_ratio_high : 1.0);
    }
    exports::export_material(maps, *exports::export_format_from_name(s->format), s->out, s->options);
    std::fprintf(stderr, "exported %s (%dx%d) as %s to %s\n", s->maps.c_str(), maps.width(), maps.height(), s->format.c_str(), s->out.c_str());
  });
}

}  // namespace anisocap::commands
