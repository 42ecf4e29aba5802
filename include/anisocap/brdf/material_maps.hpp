#pragma once
/// @file
/// The 12 appearance parameters per texel (docs/method.md section 1), stored as planes (structure of arrays) so
/// that renderers and optimisers load 16 consecutive texels of one parameter into one register.
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>

#include "anisocap/core/memory.hpp"

namespace anisocap {

/// Index of each parameter plane. Path 1 of the paper is [0, 9), path 2 is [9, 12).
enum parameter_index : int {
  diffuse_r = 0, diffuse_g = 1, diffuse_b = 2,    ///< diffuse albedo a_d in [0,1]
  specular_r = 3, specular_g = 4, specular_b = 5, ///< specular albedo at normal incidence a'_s in [0,1]
  lobe_x = 6, lobe_y = 7,                         ///< lobe widths sigma_x, sigma_y in (0,1]
  fresnel_f0 = 8,                                 ///< Schlick F0 in [0,1]
  normal_x = 9, normal_y = 10,                    ///< shading normal x, y (z = sqrt(1 - x^2 - y^2))
  rotation = 11,                                  ///< anisotropy rotation alpha in [-pi/2, pi/2]
};

/// Number of appearance parameters per texel.
inline constexpr int parameter_count = 12;

/// Smallest lobe width the library produces or accepts when sanitising (keeps exp() finite).
inline constexpr float min_lobe_width = 1e-4f;
/// log(min_lobe_width): the lower end of the lobe widths' log range (network space, refine).
inline const double log_min_lobe_width = std::log(double(min_lobe_width));

/// A map set: 12 planes of width x height floats, plus an optional height map.
/// Texel (x, y) of plane k is `plane(k)[y * width + x]`; row 0 is the top row (largest y in scene).
class material_maps {
 public:
  material_maps() = default;
  material_maps(int width, int height) : width_(width), height_(height) {
    if (width <= 0 || height <= 0) throw std::invalid_argument("material_maps: size must be positive");
    planes_ = aligned_buffer<float>(plane_stride() * parameter_count);
  }

  int width() const noexcept { return width_; }
  int height() const noexcept { return height_; }
  std::size_t texel_count() const noexcept { return std::size_t(width_) * height_; }
  /// Distance in floats between planes (texel_count rounded up to a multiple of 16, keeps alignment).
  std::size_t plane_stride() const noexcept { return (texel_count() + 15) / 16 * 16; }

  float* plane(int k) noexcept { return planes_.data() + plane_stride() * k; }
  const float* plane(int k) const noexcept { return planes_.data() + plane_stride() * k; }
  float& at(int k, int x, int y) noexcept { return plane(k)[std::size_t(y) * width_ + x]; }
  float at(int k, int x, int y) const noexcept { return plane(k)[std::size_t(y) * width_ + x]; }

  /// Optional height map (empty when absent: flat geometric frame).
  bool has_height() const noexcept { return !height_map_.empty(); }
  float* height_map() noexcept { return height_map_.data(); }
  const float* height_map() const noexcept { return height_map_.data(); }
  void enable_height_map() { if (height_map_.empty()) height_map_ = aligned_buffer<float>(plane_stride()); }
  void drop_height_map() { height_map_ = aligned_buffer<float>(); }

  /// All planes as one array (plane k starts at k * plane_stride()).
  float* data() noexcept { return planes_.data(); }
  const float* data() const noexcept { return planes_.data(); }

  /// Sets every texel to one parameter vector.
  void fill(const float (&values)[parameter_count]) {
    for (int k = 0; k < parameter_count; ++k) {
      float* p = plane(k);
      for (std::size_t i = 0; i < texel_count(); ++i) p[i] = values[k];
    }
  }

 private:
  int width_ = 0, height_ = 0;
  aligned_buffer<float> planes_;
  aligned_buffer<float> height_map_;
};

}  // namespace anisocap
