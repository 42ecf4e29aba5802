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

/// Registers `photograph`.
inline void add_photograph_command(CLI::App& app) {
  struct settings {
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
  };
  auto s = std::make_shared<settings>();
  auto* cmd = app.add_subcommand("photograph", "synthetic perspective photographs (JPEG, PNG or EXR, and photos.json) of a material, with truth/ and the texture-space captures direct/ and direct-clipped/");
  cmd->add_option("-o,--out", s->out, "output folder: photos/, direct/, direct-clipped/, truth/")->capture_default_str();
  cmd->add_option("--maps", s->maps, "map set to photograph (default: a procedural material)");
  cmd->add_option("--size", s->size, "procedural material size in texels (square)")->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--seed", s->seed, "material, configuration and noise seed")->capture_default_str();
  cmd->add_option("--noise-seed", s->noise_seed, "another draw of the sensor noise for the same material and configurations (0: --seed's)")
      ->capture_default_str();
  cmd->add_option("--kind", s->kind, "procedural material kind (plain_weave, twill, satin, brushed_metal, ...)");
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
      photo_synthesis_options o = s->options;
      const std::uint64_t noise_seed = s->noise_seed != 0 ? hash64(s->seed ^ hash64(s->noise_seed)) : s->seed;
      o.seed = noise_seed;
      o.lookup = s->lookup == "nearest" ? texture_lookup::nearest : texture_lookup::bilinear;
      o.format = s->format == "png" ? photo_format::png : s->format == "exr" ? photo_format::linear_exr : photo_format::jpeg;
      material_maps truth;
      if (s->maps) {
        truth = read_maps(*s->maps);
      } else {
        procedural_options po;
        if (!s->kind.empty()) {
          po.kind = material_kind_from_name(s->kind);
          if (!po.kind) throw std::invalid_argument("unknown --kind '" + s->kind + "'");
        }
        truth = generate_material(s->seed, s->size, s->size, po);
      }
      capture configurations = s->set == "alpha" ? set_alpha(s->images, s->seed, truth.width(), truth.height())
                                                 : set_beta(s->images, s->seed, truth.width(), truth.height());
      std::fprintf(stderr, "photograph: %d photos of %dx%d px of a %dx%d-texel material (%s light)\n", s->images, o.width, o.height,
                   truth.width(), truth.height(), o.flash ? "flash" : "separate");
      if (s->plan) {
        // The plan's photographs after the set's; the set's keep their indices, so their noise too.
        o.flash_per_photo.assign(configurations.images.size(), o.flash ? 1 : 0);
        for (const plan_candidate& p : read_plan_photos(*s->plan)) {
          capture_image image = p.config;
          image.file = input_file_name(int(configurations.images.size()));
          configurations.images.push_back(image);
          o.flash_per_photo.push_back(p.flash ? 1 : 0);
          std::fprintf(stderr, "photograph: + the plan's %s photograph from [%.2f, %.2f, %.2f] sample lengths\n", p.flash ? "flash" : "lamp",
                       p.config.camera[0], p.config.camera[1], p.config.camera[2]);
        }
      }
      if (s->marker_frame) {
        // The sheet as printed at 4 dots per mm, lying flat around the sample.
        const double n = std::max(truth.width(), truth.height());
        const marker_frame frame = make_marker_frame(truth.width() / n * o.longest_mm, truth.height() / n * o.longest_mm, s->frame);
        auto sheet = std::make_shared<printed_surround>();
        sheet->albedo = draw_marker_frame(frame, 4.0);
        sheet->width_mm = sheet->albedo.width() / 4.0;
        sheet->height_mm = sheet->albedo.height() / 4.0;
        o.surround = sheet;
        if (fill->count() == 0) o.fill = 0.6;
      }
      synthetic_photographs photos = photograph_capture(truth, configurations, o);
      // The same configurations rendered in texture space, exposed as each photograph was and with
      // the same sensor noise, in the photographs' units (intensity times exposure, as photos.json
      // gives it): the capture a perfect rectification would give. (The image loss is not
      // invariant to one image's units alone, through its epsilon; studies/README.md.)
      std::vector<image> direct = render(truth, photos.texture_capture);
      capture direct_capture = photos.texture_capture;
      for (std::size_t i = 0; i < direct.size(); ++i) {
        const float e = float(photos.exposures[i]);
        for (int c = 0; c < 3; ++c)
          for (std::size_t k = 0; k < direct[i].pixel_count(); ++k) direct[i].plane(c)[k] *= e;
        add_sensor_noise(direct[i], o.noise, hash64(noise_seed ^ (0x646972656374ULL + i)));
        for (float& intensity : direct_capture.images[i].intensity) intensity *= e;
        // The floor rectify gives the photographs, so that both captures run the same loss.
        direct_capture.images[i].floor = s->floor;
      }
      write_maps(truth, s->out / "truth");
      write_synthetic_photographs(photos, s->out / "photos");
      if (s->marker_frame) {
        // As a user would: "corners" left out where the tags are found in the photograph, given
        // (here: exact) where they are not, e.g. in grazing views.
        const double n = std::max(truth.width(), truth.height());
        const marker_frame frame = make_marker_frame(truth.width() / n * o.longest_mm, truth.height() / n * o.longest_mm, s->frame);
        for (auto& entry : photos.description.photos) {
          try {
            find_corners_from_markers(read_photo(s->out / "photos" / entry.file), frame, entry.file);
            entry.corners.reset();
          } catch (const calibration_error&) {
            std::fprintf(stderr, "photograph: %s: too few of the frame's tags found, its corners stay in photos.json\n", entry.file.c_str());
          }
        }
        write_file_atomically(s->out / "photos" / "photos.json", photos_description_to_json(photos.description));
      }
      // The same texture-space capture clipped as the photographs are: values at or above white
      // (1 in the photographs' units) clip, and their texels are left out through a mask as
      // rectify leaves out clipped pixels: the capture a perfect rectification of these 8-bit
      // photographs would give, so that the rectification's own cost and the clipping's separate.
      capture clipped_capture = direct_capture;
      std::vector<image> clipped = direct, clipped_masks;
      for (std::size_t i = 0; i < clipped.size(); ++i) {
        image mask(clipped[i].width(), clipped[i].height(), 1);
        for (std::size_t k = 0; k < clipped[i].pixel_count(); ++k) {
          bool white = false;
          for (int c = 0; c < 3; ++c) {
            float& v = clipped[i].plane(c)[k];
            if (v >= 1.0f) white = true;
            v = std::min(v, 1.0f);
          }
          mask.plane(0)[k] = white ? 0.0f : 1.0f;
        }
        clipped_masks.push_back(std::move(mask));
        clipped_capture.images[i].mask = "mask_" + std::filesystem::path(clipped_capture.images[i].file).stem().string() + ".png";
      }
      std::filesystem::create_directories(s->out / "direct");
      std::filesystem::create_directories(s->out / "direct-clipped");
      file_transaction files;
      for (std::size_t i = 0; i < direct.size(); ++i) {
        write_exr(direct[i], s->out / "direct" / photos.texture_capture.images[i].file, files);
        write_exr(clipped[i], s->out / "direct-clipped" / clipped_capture.images[i].file, files);
        write_png(clipped_masks[i], s->out / "direct-clipped" / clipped_capture.images[i].mask, files, 0.0f, png_encoding::linear);
      }
      files.stage(s->out / "direct" / "capture.json", capture_to_json(direct_capture));
      files.stage(s->out / "direct-clipped" / "capture.json", capture_to_json(clipped_capture));
      files.commit();
      std::fprintf(stderr, "photograph: photos and photos.json in %s, texture-space capture in %s (clipped as the photos: %s), true maps in %s\n",
                   (s->out / "photos").c_str(), (s->out / "direct").c_str(), (s->out / "direct-clipped").c_str(), (s->out / "truth").c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "anisocap: error: %s\n", e.what());
      std::exit(1);
    }
  });
}

}  // namespace anisocap::commands
