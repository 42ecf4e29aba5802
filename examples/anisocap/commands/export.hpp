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
#include "tileable.hpp"

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
  add_tileable_options(cmd, s->tileable, s->tile, "export a seamless tile");
  cmd->callback([s] {
    material_maps maps = read_maps(s->maps);
    if (s->tileable) {
      material_maps tile;
      try {
        tile = make_tileable(maps, s->tile);
      } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(s->maps.string() + ": --tileable: " + e.what());
      }
      print_tileable_change(compare_tile(maps, tile));
      maps = std::move(tile);
    }
    exports::export_material(maps, *exports::export_format_from_name(s->format), s->out, s->options);
    std::fprintf(stderr, "exported %s (%dx%d) as %s to %s\n", s->maps.c_str(), maps.width(), maps.height(), s->format.c_str(), s->out.c_str());
  });
}

}  // namespace anisocap::commands
