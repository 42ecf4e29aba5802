#pragma once
// `anisocap view MAPDIR -o material.html`: the interactive viewer page of a map set
// (export/viewer.hpp).
#include <CLI/CLI.hpp>

#include <cstdio>
#include <filesystem>
#include <memory>

#include "anisocap/data/map_io.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/export/viewer.hpp"

namespace anisocap::commands {

/// Registers `view`.
inline void add_view_command(CLI::App& app) {
  struct settings {
    std::filesystem::path maps, out = "material.html";
    viewer_options viewer;
  };
  auto s = std::make_shared<settings>();
  auto* cmd = app.add_subcommand("view", "write a self-contained HTML page (WebGL2) that renders a map set interactively");
  cmd->add_option("maps", s->maps, "map set folder")->required();
  cmd->add_option("-o,--out", s->out, "HTML file to write")->capture_default_str();
  cmd->add_option("--title", s->viewer.title, "page title (default: the map folder's name)");
  cmd->callback([s, cmd] {
    material_maps maps = read_maps(s->maps);
    canonicalise(maps);
    viewer_options options = s->viewer;
    if (cmd->count("--title") == 0) {
      std::filesystem::path folder = std::filesystem::absolute(s->maps).lexically_normal();
      if (!folder.has_filename()) folder = folder.parent_path();
      options.title = folder.filename().string();
    }
    write_viewer(maps, s->out, options);
    std::fprintf(stderr, "viewer for %s (%dx%d) written to %s\n", s->maps.c_str(), maps.width(), maps.height(), s->out.c_str());
  });
}

}  // namespace anisocap::commands
