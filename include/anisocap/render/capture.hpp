#pragma once
/// @file
/// A capture: for each photograph, the camera and point-light positions and the light intensity.
/// Positions are in units of the material's longest side, origin at the material's centre, z up,
/// the material in the plane z = 0; image rows run top to bottom along -y (docs/method.md section 4).
#include <array>
#include <string>
#include <vector>

#include "anisocap/core/photo_encoding.hpp"

namespace anisocap {

/// Three floats (a position or an RGB triple).
using vec3f = std::array<float, 3>;

/// One photograph's configuration.
struct capture_image {
  std::string file;        ///< image file name, relative to the capture description's folder
  vec3f camera{0, 0, 1};   ///< camera position
  vec3f light{0, 0, 1};    ///< point-light position
  vec3f intensity{1, 1, 1};///< light intensity per colour channel
  /// Optional mask image, relative like `file`: pixels that are zero in every channel are left
  /// out of the image loss (empty: every pixel is used).
  std::string mask;
  float exposure = 1.0f;   ///< factor the photograph's linear values are multiplied by on loading
  /// Level, in the file's own linear values, below which they are not measurements (a JPEG's
  /// darkest codes); the image loss takes photograph and render as at least floor x exposure
  /// (render/renderer.hpp, loss_targets). 0: none.
  float floor = 0.0f;
  /// How the photograph's file (or the one it was rectified from) stored its values: 8-bit codes
  /// and JPEG's lossy colour leave an error alike in every photograph, which the residuals cannot
  /// show, so the per-texel deviations use the calibration fitted on such photographs
  /// (pipeline/uncertainty.hpp, calibration_for). It changes nothing else of the capture.
  photo_encoding encoding = photo_encoding::lossless;
};

/// The configurations of all photographs of one material.
struct capture {
  std::vector<capture_image> images;
};

/// Texel centre position in scene units for texel (x, y) of a width x height material
/// (longest side = 1, centred, row 0 at the top, i.e. largest y).
inline std::array<float, 2> texel_position(int x, int y, int width, int height) {
  const float n = float(width > height ? width : height);
  return {(float(x) + 0.5f - 0.5f * float(width)) / n, (0.5f * float(height) - (float(y) + 0.5f)) / n};
}

}  // namespace anisocap
