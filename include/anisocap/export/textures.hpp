#pragma once
/// @file
/// Texture helpers shared by the exporters: a map set converted texel by texel to one target
/// (export/conversion.hpp), and 8-bit PNG encoding of 1-4 channel texel arrays (sRGB or linear).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/conversion.hpp"
#include "anisocap/export/fidelity.hpp"

namespace anisocap::exports {

/// `convert(ward_parameters<float>)` applied to every texel, row 0 (top) first.
template <class Convert>
auto convert_texels(const material_maps& maps, Convert&& convert) {
  std::vector<decltype(convert(texel_parameters(maps, 0)))> out;
  out.reserve(maps.texel_count());
  for (std::size_t i = 0; i < maps.texel_count(); ++i) out.push_back(convert(texel_parameters(maps, i)));
  return out;
}

/// An 8-bit texture of `channels` interleaved channels (values in [0, 1]).
struct texture8 {
  int width = 0, height = 0, channels = 0;
  std::vector<std::uint8_t> texels;
  texture8(int w, int h, int c) : width(w), height(h), channels(c), texels(std::size_t(w) * h * c) {}
  /// Stores `value` (clamped to [0, 1]) at texel i, channel c, sRGB-encoded when `srgb`.
  void set(std::size_t i, int c, double value, bool srgb = false) {
    double v = std::clamp(std::isfinite(value) ? value : 0.0, 0.0, 1.0);
    if (srgb) v = linear_to_srgb(v);
    texels[i * channels + c] = std::uint8_t(std::lround(v * 255));
  }
};

/// PNG file bytes of `t`.
inline std::vector<unsigned char> png_bytes(const texture8& t, const std::filesystem::path& name) {
  std::vector<unsigned char> bytes;
  auto append = [](void* context, void* data, int size) {
    auto* out = static_cast<std::vector<unsigned char>*>(context);
    out->insert(out->end(), static_cast<unsigned char*>(data), static_cast<unsigned char*>(data) + size);
  };
  if (!stbi_write_png_to_func(append, &bytes, t.width, t.height, t.channels, t.texels.data(), t.width * t.channels))
    throw io_error(name, "cannot encode PNG");
  return bytes;
}

/// A float image of the map set's size with channel values from `value(i, c)` (for EXR textures).
template <class Value>
image float_texture(const material_maps& maps, int channels, Value&& value, bool flip_rows = false) {
  image img(maps.width(), maps.height(), channels);
  for (int y = 0; y < maps.height(); ++y)
    for (int x = 0; x < maps.width(); ++x) {
      const std::size_t i = std::size_t(y) * maps.width() + x;
      const int row = flip_rows ? maps.height() - 1 - y : y;
      for (int c = 0; c < channels; ++c) img.at(c, x, row) = float(value(i, c));
    }
  return img;
}

}  // namespace anisocap::exports
