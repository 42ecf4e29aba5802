#pragma once
// `anisocap rectify photos.json -o DIR [--resolution N]`: perspective photographs of a flat sample
// to a texture-space capture that `anisocap capture DIR/capture.json` runs (calibration/rectify.hpp).
#include <CLI/CLI.hpp>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <memory>

#include "anisocap/calibration/markers.hpp"
#include "anisocap/calibration/rectify.hpp"

namespace anisocap::commands {

/// Registers `rectify`.
inline void add_rectify_command(CLI::App& app) {
  struct settings {
    std::filesystem::path photos, out = "anisocap-rectified";
    rectify_options options;
    marker_frame_options frame;
  };
  auto s = std::make_shared<settings>();
  auto* cmd = app.add_subcommand("rectify", "perspective photographs of a flat sample (photos.json) to a texture-space capture");
  cmd->add_option("photos", s->photos, "photos.json: sample size, camera, and per photo the file, corners and light")->required();
  cmd->add_option("-o,--out", s->out, "output folder: rectified_NN.exr, mask_NN.png (weights: 0 = ignore), capture.json")->capture_default_str();
  cmd->add_option("--resolution", s->options.resolution, "texels along the sample's longest side (0: what the photos support)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--saturation", s->options.saturation, "linear level at or above which a pixel counts as clipped (0: only the format's largest code)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--floor", s->options.floor,
                  "floor written into capture.json for every photo: the linear level (1 = an 8/16-bit photo's white) below which its "
                  "values are sensor noise, not measurements; the loss takes photograph and render as at least this (0: none)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--margin-px", s->options.resampling.margin_px, "photo pixels left out along each side of a texel's footprint (they also record its neighbours)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--footprint", s->options.resampling.statistic,
                  "how a texel's footprint becomes its value: auto (the median of its pixels where their mean is at most --dark-level, "
                  "unbiased by sensor noise clipped at black; the mean elsewhere), mean (area average) or median")
      ->transform(CLI::CheckedTransformer(std::map<std::string, footprint_statistic>{
          {"auto", footprint_statistic::automatic}, {"mean", footprint_statistic::mean}, {"median", footprint_statistic::median}}))
      ->default_str("auto");
  cmd->add_option("--dark-level", s->options.resampling.dark_level, "--footprint auto: the linear level (1 = the format's white) up to which the median is used")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--full-confidence-px", s->options.resampling.full_confidence_px,
                  "photo pixels across a texel that give it full weight in the loss; fewer weigh (d / this)^2 (0: every texel full weight)")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--tag-mm", s->frame.tag_mm, "the marker frame's tag size, as given to `markers` (photos without \"corners\")")->capture_default_str();
  cmd->add_option("--gap-mm", s->frame.gap_mm, "the marker frame's gap, as given to `markers`")->capture_default_str();
  cmd->callback([s] {
    try {
      rectify_options o = s->options;
      o.progress = [](std::size_t done, std::size_t total, const std::string& line) {
        std::fprintf(stderr, "rectify: %zu/%zu %s\n", done, total, line.c_str());
      };
      const photos_description d = read_photos_description(s->photos);
      // Photos without "corners": the corners from the printed marker frame's tags.
      const marker_frame frame = make_marker_frame(d.width_mm, d.height_mm, s->frame);
      const corner_finder markers = [&](const photo& picture, const photos_description&, const std::string& name) {
        return find_corners_from_markers(picture, frame, name);
      };
      const rectified_capture r = rectify(d, s->photos.parent_path(), o, markers);
      write_rectified_capture(r, s->out);
      for (std::size_t i = 0; i < r.photos.size(); ++i)
        if (r.photos[i].underresolved_fraction > 0.2)
          std::fprintf(stderr,
                       "rectify: note: %s does not resolve %.0f%% of the texels (under one photo pixel across): a closer or "
                       "higher-resolution photo, or a lower --resolution, gives sharper maps\n",
                       d.photos[i].file.c_str(), 100 * r.photos[i].underresolved_fraction);
      std::fprintf(stderr, "rectify: %zu images of %dx%d texels (%.3g mm per texel), masks and capture.json in %s\n"
                   "next: anisocap capture %s\n", r.photos.size(), r.width, r.height,
                   std::max(d.width_mm, d.height_mm) / std::max(r.width, r.height), s->out.c_str(), (s->out / "capture.json").c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "anisocap: error: %s\n", e.what());
      std::exit(1);
    }
  });
}

}  // namespace anisocap::commands
