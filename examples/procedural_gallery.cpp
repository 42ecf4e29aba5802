// procedural_gallery: a contact sheet of procedural materials (data/procedural.hpp), one row per
// seed, columns diffuse, specular, lobes (R = sx, G = sy), F0, normal (xy mapped to RG) and
// rotation (hue of 2 alpha), as an sRGB PNG, to judge by eye that the maps look like cloth and metal.
//
//   procedural_gallery [--first SEED] [--count N] [--size PX] [-o gallery.png]
#include <CLI/CLI.hpp>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>
#include <vector>

#include "anisocap/data/procedural.hpp"

namespace {

unsigned char to_byte(double linear) {
  const double c = std::clamp(linear, 0.0, 1.0);
  const double s = c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
  return static_cast<unsigned char>(std::lround(s * 255.0));
}

unsigned char raw_byte(double v) { return static_cast<unsigned char>(std::lround(std::clamp(v, 0.0, 1.0) * 255.0)); }

/// A hue wheel colour for an angle in [0, 2 pi).
void hue(double angle, double rgb[3]) {
  for (int k = 0; k < 3; ++k) rgb[k] = 0.5 + 0.5 * std::cos(angle - 2.0 * std::numbers::pi * k / 3.0);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Contact sheet of procedural materials"};
  std::uint64_t first = 0;
  int count = 12, size = 160;
  std::string output = "gallery.png";
  app.add_option("--first", first, "first seed");
  app.add_option("--count", count, "number of seeds")->check(CLI::Range(1, 200));
  app.add_option("--size", size, "tile size in pixels")->check(CLI::Range(8, 2048));
  app.add_option("-o,--output", output, "PNG file to write");
  std::string kinds, mix = "original";
  app.add_option("--kind", kinds, "force these kinds, comma-separated, one per row in turn (e.g. leather,foil)");
  app.add_option("--mix", mix, "families drawn when no kind is forced: original, extended or training")
      ->check(CLI::IsMember({"original", "extended", "training"}));
  CLI11_PARSE(app, argc, argv);
  anisocap::procedural_options options;
  options.mix = *anisocap::material_mix_from_name(mix);
  std::vector<anisocap::material_kind> forced;
  try {
    forced = anisocap::material_kinds_from_names(kinds);
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "procedural_gallery: --kind: %s\n", e.what());
    return 1;
  }

  const int columns = 6, gap = 4;
  const int sheet_width = columns * (size + gap), sheet_height = count * (size + gap);
  std::vector<unsigned char> sheet(std::size_t(sheet_width) * sheet_height * 3, 255);
  for (int row = 0; row < count; ++row) {
    const std::uint64_t seed = first + std::uint64_t(row);
    if (!forced.empty()) options.kind = forced[std::size_t(row) % forced.size()];
    const auto parameters = anisocap::draw_procedural_parameters(seed, options);
    std::printf("seed %llu: %s\n", static_cast<unsigned long long>(seed), anisocap::describe(parameters).c_str());
    const anisocap::material_maps maps = anisocap::generate_material(parameters, size, size);
    for (int column = 0; column < columns; ++column) {
      for (int y = 0; y < size; ++y) {
        for (int x = 0; x < size; ++x) {
          unsigned char pixel[3];
          using namespace anisocap;
          switch (column) {
            case 0: for (int k = 0; k < 3; ++k) pixel[k] = to_byte(maps.at(diffuse_r + k, x, y)); break;
            case 1: for (int k = 0; k < 3; ++k) pixel[k] = to_byte(maps.at(specular_r + k, x, y)); break;
            case 2:
              pixel[0] = raw_byte(maps.at(lobe_x, x, y));
              pixel[1] = raw_byte(maps.at(lobe_y, x, y));
              pixel[2] = 0;
              break;
            case 3: pixel[0] = pixel[1] = pixel[2] = raw_byte(maps.at(fresnel_f0, x, y)); break;
            case 4:
              pixel[0] = raw_byte(0.5 + 0.5 * maps.at(normal_x, x, y));
              pixel[1] = raw_byte(0.5 + 0.5 * maps.at(normal_y, x, y));
              pixel[2] = raw_byte(std::sqrt(std::max(0.0f, 1.0f - maps.at(normal_x, x, y) * maps.at(normal_x, x, y) -
                                                              maps.at(normal_y, x, y) * maps.at(normal_y, x, y))));
              break;
            default: {
              double rgb[3];
              hue(2.0 * maps.at(rotation, x, y) + std::numbers::pi, rgb);
              for (int k = 0; k < 3; ++k) pixel[k] = raw_byte(rgb[k]);
            }
          }
          const std::size_t offset =
              (std::size_t(row * (size + gap) + y) * sheet_width + std::size_t(column * (size + gap) + x)) * 3;
          for (int k = 0; k < 3; ++k) sheet[offset + std::size_t(k)] = pixel[k];
        }
      }
    }
  }
  const std::string temporary = output + ".tmp.png";
  if (!stbi_write_png(temporary.c_str(), sheet_width, sheet_height, 3, sheet.data(), sheet_width * 3) ||
      std::rename(temporary.c_str(), output.c_str()) != 0) {
    std::fprintf(stderr, "procedural_gallery: cannot write %s\n", output.c_str());
    std::remove(temporary.c_str());
    return 1;
  }
  std::printf("wrote %s (%d x %d)\n", output.c_str(), sheet_width, sheet_height);
  return 0;
}
