// Captures a material with anisocap as a library, as `anisocap capture` does, then writes its maps
// and a glTF.   usage: host_capture CAPTURE.json OUT
#include <anisocap/data/map_io.hpp>
#include <anisocap/export/gltf.hpp>
#include <anisocap/pipeline/capture_material.hpp>
#include <anisocap/pipeline/progress_line.hpp>

#include <cstdio>
#include <exception>
#include <filesystem>
#include <functional>

int main(int argc, char** argv) {
  if (argc != 3) return std::fprintf(stderr, "usage: %s capture.json OUT\n", argv[0]), 2;
  try {
    const auto input = anisocap::read_capture_photographs(argv[1]);  // description, photographs, masks
    const auto networks = anisocap::load_networks();                  // the installed weights
    anisocap::capture_options options;                                // the program's defaults
    anisocap::progress_line progress;
    options.progress = std::ref(progress);
    const anisocap::capture_result result = anisocap::capture_material(input, networks, options);
    const std::filesystem::path out = argv[2];
    anisocap::write_maps(result.maps, out);
    anisocap::exports::write_gltf(result.maps, out / "material.gltf");
    std::printf("%s: maps and material.gltf, image loss %.4f\n", argv[2], result.loss);
  } catch (const std::exception& e) {
    return std::fprintf(stderr, "host_capture: %s\n", e.what()), 1;
  }
}
