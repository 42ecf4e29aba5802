#pragma once
/// @file
/// A capture: for each photograph, the camera and point-light positions and the light intensity.
/// Positions are in units of the material's longest side, origin at the material's centre, z up,
/// the material in the plane z = 0; image rows run top to bottom along -y (docs/method.md section 4).
#include <array>
#include <string>
#include <vector>

namespace anisocap {

/// Three floats (a position or an RGB triple).
using vec3f = std::array<float, 3>;

/// One photograph's configuration.
struct capture_image {
  std::string file;        ///< image file name, relative to the capture description's folder
  vec3f camera{0, 0, 1};   ///< camera position
  vec3f light{0, 0, 1};    ///< point-light position
  vec3f intensity{1, 1, 1};///< light intensity per colour channel
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
