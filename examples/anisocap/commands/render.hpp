#pragma once
// `anisocap render`: a map set rendered under a capture's configurations.
#include <memory>

#include "common.hpp"

namespace anisocap::commands {

/// Registers `anisocap render`.
inline void add_render_command(CLI::App& app) {
  struct settings {
    fs::path maps, capture_file, out;
  };
  auto s = std::make_shared<settings>();
  auto* c = app.add_subcommand("render", "render a map set under a capture's configurations");
  c->add_option("--maps", s->maps, "map set folder")->required();
  c->add_option("--capture", s->capture_file, "capture.json")->required();
  c->add_option("-o,--out", s->out, "output folder")->required();
  c->callback([s] {
    const material_maps maps = read_maps(s->maps);
    const capture cap = read_capture(s->capture_file);
    std::vector<fs::path> inputs = capture_inputs(cap, s->capture_file), maps_in = map_files(s->maps);
    inputs.insert(inputs.end(), maps_in.begin(), maps_in.end());
    refuse_overwriting_inputs(image_outputs(cap, s->out), inputs);  // before the render's work
    output_lock lock(s->out);
    // The cheapest kernel that renders these maps exactly (within 1e-4 relative): skips anisotropy,
    // Fresnel or the normal frame when the maps and configurations do not need them.
    const kernel_analysis kernel = analyse_kernel(maps, cap, 1e-4);
    write_renders(maps, cap, s->out, kernel.features, inputs);
    std::fprintf(stderr, "rendered %zu images of %dx%d into %s (kernel: %s)\n", cap.images.size(), maps.width(), maps.height(),
                 s->out.c_str(), kernel.describe().c_str());
  });
}

}  // namespace anisocap::commands
