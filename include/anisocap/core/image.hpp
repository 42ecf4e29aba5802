#pragma once
/// @file
/// `image`: a planar float image (one plane per channel), the type of input photographs and
/// renderings. Planar so that renderers and losses stream 16 texels of one channel per register.
#include <cstddef>
#include <stdexcept>

#include "anisocap/core/memory.hpp"

namespace anisocap {

/// width x height x channels floats, channel planes one after the other, rows top to bottom.
class image {
 public:
  image() = default;
  image(int width, int height, int channels = 3) : width_(width), height_(height), channels_(channels) {
    if (width <= 0 || height <= 0 || channels <= 0) throw std::invalid_argument("image: size must be positive");
    pixels_ = aligned_buffer<float>(plane_stride() * channels_);
  }

  int width() const noexcept { return width_; }
  int height() const noexcept { return height_; }
  int channels() const noexcept { return channels_; }
  std::size_t pixel_count() const noexcept { return std::size_t(width_) * height_; }
  /// Floats between channel planes (pixel_count rounded up to 16, keeps every plane 64-byte aligned).
  std::size_t plane_stride() const noexcept { return (pixel_count() + 15) / 16 * 16; }
  bool empty() const noexcept { return pixels_.empty(); }

  float* plane(int c) noexcept { return pixels_.data() + plane_stride() * c; }
  const float* plane(int c) const noexcept { return pixels_.data() + plane_stride() * c; }
  float& at(int c, int x, int y) noexcept { return plane(c)[std::size_t(y) * width_ + x]; }
  float at(int c, int x, int y) const noexcept { return plane(c)[std::size_t(y) * width_ + x]; }

 private:
  int width_ = 0, height_ = 0, channels_ = 0;
  aligned_buffer<float> pixels_;
};

}  // namespace anisocap
