#pragma once
// --tileable and --tile-overlap (export and capture), and the line and report entry that say what
// the tile changed (export/tileable.hpp).
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <string>

#include "anisocap/export/tileable.hpp"

namespace anisocap::commands {

/// Binds `--tileable` onto `on` and `--tile-overlap` onto `tile.overlap`; `what` ends the flag's help
/// ("export a seamless tile" / "also write a seamless tile to OUT/tileable/").
inline void add_tileable_options(CLI::App* c, bool& on, tileable_options& tile, const std::string& what) {
  c->add_flag("--tileable", on,
              what + ": the maps cross-faded over an overlap at each edge (export/tileable.hpp), smaller by the overlap along "
                     "each axis, every map alike (the rotation and the normal included)");
  c->add_option("--tile-overlap", tile.overlap, "with --tileable: the overlap, as a fraction of each side")->check(CLI::Range(0.01, 0.5));
}

/// Prints what the tile changed as one "tileable: ..." line.
inline void print_tileable_change(const tileable_change& c) {
  std::fprintf(stderr,
               "tileable: %dx%d maps made into a %dx%d tile; wrap-edge step / interior step %.2f -> %.2f (mean over the maps), "
               "largest mean shift %.3f standard deviations, variance ratios %.3f-%.3f\n",
               c.width_before, c.height_before, c.width_after, c.height_after, c.seam_before, c.seam_after, c.largest_mean_shift,
               c.variance_ratio_low, c.variance_ratio_high);
}

/// What the tile changed, for report.json.
inline nlohmann::json tileable_json(const tileable_change& c, double overlap) {
  return {{"overlap", overlap},
          {"width", c.width_after},
          {"height", c.height_after},
          {"seam_ratio_before", c.seam_before},
          {"seam_ratio_after", c.seam_after},
          {"largest_mean_shift", c.largest_mean_shift},
          {"variance_ratio", {c.variance_ratio_low, c.variance_ratio_high}}};
}

}  // namespace anisocap::commands
