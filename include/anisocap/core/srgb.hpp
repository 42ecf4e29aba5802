#pragma once
/// @file
/// The sRGB transfer function (IEC 61966-2-1: the piecewise curve, not gamma 2.2), used to read
/// and write 8- and 16-bit images and to linearise the procedural materials' palette colours.
#include <cmath>

namespace anisocap {

/// sRGB-encoded value in [0,1] to linear.
inline double srgb_to_linear(double encoded) noexcept {
  return encoded <= 0.04045 ? encoded / 12.92 : std::pow((encoded + 0.055) / 1.055, 2.4);
}

/// Linear value in [0,1] to sRGB encoding (inverse of srgb_to_linear).
inline double linear_to_srgb(double linear) noexcept {
  return linear <= 0.0031308 ? linear * 12.92 : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
}

}  // namespace anisocap
