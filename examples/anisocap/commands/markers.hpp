#pragma once
// `anisocap markers`: a printable AprilTag frame for a sample of a given size
// (calibration/markers.hpp); `rectify` finds a photo's corners from it when "corners" are absent.
#include <CLI/CLI.hpp>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <memory>

#include "anisocap/calibration/markers.hpp"
#include "anisocap/data/image_io.hpp"

namespace anisocap::commands {

/// Registers `markers`.
inline void add_markers_command(CLI::App& app) {
  struct settings {
    double width_mm = 0, height_mm = 0, dpi = 300;
    marker_frame_options frame;
    std::filesystem::path out = "marker-frame.png";
  };
  auto s = std::make_shared<settings>();
  auto* cmd = app.add_subcommand("markers", "a printable AprilTag frame (PNG) around a sample; rectify finds the corners from it");
  cmd->add_option("--width-mm", s->width_mm, "the sample's width in mm (along its top edge)")->required()->check(CLI::PositiveNumber);
  cmd->add_option("--height-mm", s->height_mm, "the sample's height in mm")->required()->check(CLI::PositiveNumber);
  cmd->add_option("--dpi", s->dpi, "print resolution in dots per inch")->capture_default_str()->check(CLI::Range(50.0, 2400.0));
  cmd->add_option("--tag-mm", s->frame.tag_mm, "side of a tag's black square in mm (0: a fifth of the shorter side, 8-30 mm)")->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--gap-mm", s->frame.gap_mm, "gap between the sample's window and the tags in mm")->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("-o,--out", s->out, "output PNG")->capture_default_str();
  cmd->callback([s] {
    try {
      const marker_frame f = make_marker_frame(s->width_mm, s->height_mm, s->frame);
      const image sheet = draw_marker_frame(f, s->dpi / 25.4);
      write_png(sheet, s->out, 0.0f, png_encoding::linear);
      std::fprintf(stderr, "markers: %zu tags of %.1f mm around a %.1f x %.1f mm window, sheet %.1f x %.1f mm: print %s at %g dpi, 100%% scale\n",
                   f.markers.size(), f.tag_mm, s->width_mm, s->height_mm, sheet.width() * 25.4 / s->dpi, sheet.height() * 25.4 / s->dpi,
                   s->out.c_str(), s->dpi);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "anisocap: error: %s\n", e.what());
      std::exit(1);
    }
  });
}

}  // namespace anisocap::commands
