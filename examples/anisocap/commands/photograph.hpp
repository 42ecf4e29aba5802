#pragma once
// `anisocap photograph`: synthetic perspective photographs (JPEG, PNG or EXR + photos.json) of a procedural
// material or a map set, with the same configurations rendered directly in texture space beside
// them, to test `rectify` + `capture` without a camera (calibration/photo_synthesis.hpp).
#include <CLI/CLI.hpp>

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "anisocap/calibration/markers.hpp"
#include "anisocap/calibration/photo_synthesis.hpp"
#include "anisocap/calibration/rectify.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/plan_io.hpp"
#include "anisocap/render/configurations.hpp"

namespace anisocap::commands {

/// The options of `photograph`.
struct photograph_settings {
  std::filesystem::path out = "anisocap-photographs";
  std::optional<std::filesystem::path> maps;
  std::optional<std::filesystem::path> plan;
  int size = 128, images = 12;
  std::uint64_t seed = 1;
  std::uint64_t noise_seed = 0;
  std::string kind, set = "alpha", lookup = "bilinear", format = "jpeg";
  photo_synthesis_options options;
  bool marker_frame = false;
  marker_frame_options frame;
  float floor = rectify_options{}.floor;
  bool fill_given = false;  ///< --fill was given (else --marker-frame sets 0.6)
};

/// The material `photograph` photographs: --maps, or the procedural material of --seed and --kind.
inline material_maps photograph_material(const photograph_settings& s) {
  if (s.maps) return read_maps(*s.maps);
  procedural_options po;
  if (!s.kind.empty()) {
    po.kind = material_kind_from_name(s.kind);
    if (!po.kind) throw std::invalid_argument("unknown --kind '" + s.kind + "'");
  }
  return generate_material(s.seed, s.size, s.size, po);
}

/// The configurations `photograph` takes: the set's, then --plan's, each of those with its own
/// flash or lamp (o.flash_per_photo). The set's keep their indices, so their noise too.
inline capture photograph_configurations(const photograph_settings& s, const material_maps& truth, photo_synthesis_options& o) {
  capture configurations = s.set == "alpha" ? set_alpha(s.images, s.seed, truth.width(), truth.height())
                                             : set_beta(s.images, s.seed, truth.width(), truth.height());
  std::fprintf(stderr, "photograph: %d photos of %dx%d px of a %dx%d-texel material (%s light)\n", s.images, o.width, o.height,
               truth.width(), truth.height(), o.flash ? "flash" : "separate");
  if (!s.plan) return configurations;
  o.flash_per_photo.assign(configurations.images.size(), o.flash ? 1 : 0);
  for (const plan_candidate& p : read_plan_photos(*s.plan)) {
    capture_image image = p.config;
    image.file = input_file_name(int(configurations.images.size()));
    configurations.images.push_back(image);
    o.flash_per_photo.push_back(p.flash ? 1 : 0);
    std::fprintf(stderr, "photograph: + the plan's %s photograph from [%.2f, %.2f, %.2f] sample lengths\n", p.flash ? "flash" : "lamp",
                 p.config.camera[0], p.config.camera[1], p.config.camera[2]);
  }
  return configurations;
}

/// The marker frame of `anisocap markers` (s.frame) around a sample of truth's shape.
inline marker_frame photograph_frame(const photograph_settings& s, const material_maps& truth, double longest_mm) {
  const double n = std::max(truth.width(), truth.height());
  return make_marker_frame(truth.width() / n * longest_mm, truth.height() / n * longest_mm, s.frame);
}

/// The photographs' configurations rendered in texture space: direct/ and direct-clipped/.
struct texture_space_captures {
  capture direct_capture, clipped_capture;   ///< their capture.json
  std::vector<image> direct, clipped, masks;  ///< their images, and direct-clipped/'s masks
};

/// Renders `photos`' configurations in texture space, exposed as each photograph was and with the
/// same sensor noise, in the photographs' units (intensity times exposure, as photos.json gives
/// it): the capture a perfect rectification would give. (The image loss is not invariant to one
/// image's units alone, through its epsilon; studies/README.md.) Then the same clipped as the
/// photographs are: values at or above white (1 in the photographs' units) clip, and their texels
/// are left out through a mask as rectify leaves out clipped pixels: the capture a perfect
/// rectification of 8-bit photographs would give, so that the rectification's own cost and the
/// clipping's separate. Every image gets `floor`, the floor rectify gives the photographs, so that
/// both captures run the same loss.
inline texture_space_captures render_texture_space(const material_maps& truth, const synthetic_photographs& photos,
                                                   const sensor_noise& noise, std::uint64_t noise_seed, float floor) {
  texture_space_captures t;
  t.direct = render(truth, photos.texture_capture);
  t.direct_capture = photos.texture_capture;
  for (std::size_t i = 0; i < t.direct.size(); ++i) {
    const float e = float(photos.exposures[i]);
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < t.direct[i].pixel_count(); ++k) t.direct[i].plane(c)[k] *= e;
    add_sensor_noise(t.direct[i], noise, hash64(noise_seed ^ (0x646972656374ULL + i)));
    for (float& intensity : t.direct_capture.images[i].intensity) intensity *= e;
    t.direct_capture.images[i].floor = floor;
  }
  t.clipped_capture = t.direct_capture;
  t.clipped = t.direct;
  for (std::size_t i = 0; i < t.clipped.size(); ++i) {
    image mask(t.clipped[i].width(), t.clipped[i].height(), 1);
    for (std::size_t k = 0; k < t.clipped[i].pixel_count(); ++k) {
      bool white = false;
      for (int c = 0; c < 3; ++c) {
        float& v = t.clipped[i].plane(c)[k];
        if (v >= 1.0f) white = true;
        v = std::min(v, 1.0f);
      }
      mask.plane(0)[k] = white ? 0.0f : 1.0f;
    }
    t.masks.push_back(std::move(mask));
    t.clipped_capture.images[i].mask = "mask_" + std::filesystem::path(t.clipped_capture.images[i].file).stem().string() + ".png";
  }
  return t;
}

/// Writes direct/ and direct-clipped/ into `out`, all or nothing.
inline void write_texture_space(const texture_space_captures& t, const std::filesystem::path& out) {
  std::filesystem::create_directories(out / "direct");
  std::filesystem::create_directories(out / "direct-clipped");
  file_transaction files;
  for (std::size_t i = 0; i < t.direct.size(); ++i) {
    write_exr(t.direct[i], out / "direct" / t.direct_capture.images[i].file, files);
    write_exr(t.clipped[i], out / "direct-clipped" / t.clipped_capture.images[i].file, files);
    write_png(t.masks[i], out / "direct-clipped" / t.clipped_capture.images[i].mask, files, 0.0f, png_encoding::linear);
  }
  files.stage(out / "direct" / "capture.json", capture_to_json(t.direct_capture));
  files.stage(out / "direct-clipped" / "capture.json", capture_to_json(t.clipped_capture));
  files.commit();
}

/// Runs `photograph`: photographs the material, renders the texture-space captures beside them and
/// writes photos/, truth/, direct/ and direct-clipped/ (see the file comment).
inline void run_photograph_command(const photograph_settings& s) {
  photo_synthesis_options o = s.options;
  const std::uint64_t noise_seed = s.noise_seed != 0 ? hash64(s.seed ^ hash64(s.noise_seed)) : s.seed;
  o.seed = noise_seed;
  o.lookup = s.lookup == "nearest" ? texture_lookup::nearest : texture_lookup::bilinear;
  o.format = s.format == "png" ? photo_format::png : s.format == "exr" ? photo_format::linear_exr : photo_format::jpeg;
  const material_maps truth = photograph_material(s);
  const capture configurations = photograph_configurations(s, truth, o);
  std::optional<marker_frame> frame;
  if (s.marker_frame) {
    frame = photograph_frame(s, truth, o.longest_mm);
    // The sheet as printed at 4 dots per mm, lying flat around the sample.
    auto sheet = std::make_shared<printed_surround>();
    sheet->albedo = draw_marker_frame(*frame, 4.0);
    sheet->width_mm = sheet->albedo.width() / 4.0;
    sheet->height_mm = sheet->albedo.height() / 4.0;
    o.surround = sheet;
    if (!s.fill_given) o.fill = 0.6;
  }
  synthetic_photographs photos = photograph_capture(truth, configurations, o);
  const texture_space_captures texture_space = render_texture_space(truth, photos, o.noise, noise_seed, s.floor);
  write_maps(truth, s.out / "truth");
  write_synthetic_photographs(photos, s.out / "photos");
  if (frame) {
    // As a user would: "corners" left out where the tags are found in the photograph, given
    // (here: exact) where they are not, e.g. in grazing views.
    for (auto& entry : photos.description.photos) {
      try {
        find_corners_from_markers(read_photo(s.out / "photos" / entry.file), *frame, entry.file);
        entry.corners.reset();
      } catch (const calibration_error&) {
        std::fprintf(stderr, "photograph: %s: too few of the frame's tags found, its corners stay in photos.json\n", entry.file.c_str());
      }
    }
    write_file_atomically(s.out / "photos" / "photos.json", photos_description_to_json(photos.description));
  }
  write_texture_space(texture_space, s.out);
  std::fprintf(stderr, "photograph: photos and photos.json in %s, texture-space capture in %s (clipped as the photos: %s), true maps in %s\n",
               (s.out / "photos").c_str(), (s.out / "direct").c_str(), (s.out / "direct-clipped").c_str(), (s.out / "truth").c_str());
}

/// Registers `photograph`.
inline void add_photograph_command(CLI::App& app) {
  auto s = std::make_shared<photograph_settings>();
  auto* cmd = app.add_subcommand("photograph", "synthetic perspective photographs (JPEG, PNG or EXR, and photos.json) of a material, with truth/ and the texture-space captures direct/ and direct-clipped/");
  cmd->add_option("-o,--out", s->out, "output folder: photos/, direct/, direct-clipped/, truth/")->capture_default_str();
  cmd->add_option("--maps", s->maps, "map set to photograph (default: a procedural material)");
  cmd->add_option("--size", s->size, "procedural material size in texels (square)")->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--seed", s->seed, "material, configuration and noise seed")->capture_default_str();
  cmd->add_option("--noise-seed", s->noise_seed, "another draw of the sensor noise for the same material and configurations (0: --seed's)")
      ->capture_default_str();
  cmd->add_option("--kind", s->kind, "procedural material kind: plain, basket, twill, herringbone, satin, velvet, brushed, spun, leather, coated, printed or foil (default: any)");
  cmd->add_option("--images", s->images, "number of photographs of the set (--plan's come on top)")->capture_default_str()->check(CLI::Range(4, 1000));
  cmd->add_option("--set", s->set, "configuration set: alpha or beta")->capture_default_str()->check(CLI::IsMember({"alpha", "beta"}));
  cmd->add_option("--plan", s->plan,
                  "also take the photographs of a plan.json of `anisocap plan` (numbered after the set's, each with its own flash or "
                  "lamp; the set's photographs are the same as without it)");
  cmd->add_flag("--flash", s->options.flash, "light fixed to the camera (a phone's flash) instead of the configuration's light");
  cmd->add_option("--flash-offset", s->options.flash_offset_mm, "flash offset from the lens in mm, camera coordinates x right, y down, z forward")
      ->delimiter(',')->capture_default_str();
  cmd->add_option("--photo-width", s->options.width, "photo width in pixels")->capture_default_str();
  cmd->add_option("--photo-height", s->options.height, "photo height in pixels")->capture_default_str();
  cmd->add_option("--sample-mm", s->options.longest_mm, "the sample's longest side in mm")->capture_default_str();
  cmd->add_option("--white-fraction", s->options.white_fraction, "exposure: this fraction of the sample's pixels stays below white")->capture_default_str();
  cmd->add_option("--lookup", s->lookup, "texture lookup between texel centres: bilinear, or nearest (each texel a patch of constant material)")
      ->capture_default_str()->check(CLI::IsMember({"bilinear", "nearest"}));
  cmd->add_option("--format", s->format,
                  "photo format: jpeg (8-bit sRGB, as a phone writes), png (8-bit sRGB, lossless), exr (linear float clipped to [0, 1], a RAW "
                  "developed linearly; rectify it with --saturation 1)")
      ->capture_default_str()->check(CLI::IsMember({"jpeg", "png", "exr"}));
  cmd->add_option("--quality", s->options.jpeg_quality, "JPEG quality")->capture_default_str()->check(CLI::Range(1, 100));
  auto* fill = cmd->add_option("--fill", s->options.fill, "the sample's image spans at most this share of the frame (sets each photo's focal length)")
                   ->capture_default_str()->check(CLI::Range(0.05, 1.0));
  cmd->add_flag("--marker-frame", s->marker_frame,
                "the sample lies in the printed frame of `anisocap markers` (same --tag-mm, --gap-mm), --fill 0.6 unless given; photos.json "
                "leaves out the corners of photos whose tags are found: rectify finds them from the tags");
  cmd->add_option("--tag-mm", s->frame.tag_mm, "with --marker-frame: the frame's tag size, as given to `markers`")->capture_default_str();
  cmd->add_option("--gap-mm", s->frame.gap_mm, "with --marker-frame: the frame's gap, as given to `markers`")->capture_default_str();
  cmd->add_option("--floor", s->floor,
                  "floor of the texture-space captures direct/ and direct-clipped/ (capture.json), as rectify's --floor gives the "
                  "photographs")
      ->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--shot-noise", s->options.noise.shot, "sensor shot noise at white (relative standard deviation)")->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->add_option("--read-noise", s->options.noise.read, "sensor read noise (standard deviation)")->capture_default_str()->check(CLI::NonNegativeNumber);
  cmd->callback([s, fill] {
    try {
      s->fill_given = fill->count() > 0;
      run_photograph_command(*s);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "anisocap: error: %s\n", e.what());
      std::exit(1);
    }
  });
}

}  // namespace anisocap::commands
