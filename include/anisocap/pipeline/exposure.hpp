#pragma once
/// @file
/// Exposure normalisation: the capture pipeline's answer does not depend on the units of the
/// photographs.
///
/// Multiplying every photograph and every light intensity by the same factor describes the same
/// physical capture, so the material maps should not change. The image loss (docs/method.md section 5) is not
/// scale-free, though: its epsilon 0.01 assumes pixel values near the range [0, 1] (a white
/// Lambertian texel facing the light renders 1 in this project's synthetic captures). A capture in
/// other units (1e-4 of that: the loss sees only the epsilon and the gradients vanish; 1e4: the
/// networks see inputs far outside their training range) is therefore rescaled first:
///
///   s = 1 / median_k( mean_c(I_k,c) * cos(theta_k) / (pi |l_k|^2) ),
///
/// the reciprocal of the median over images of the irradiance at the material's centre relative to
/// the synthetic captures' convention (I = pi d^2, render/configurations.hpp). Photographs and
/// intensities are both multiplied by s; the maps are unchanged by construction, and a capture
/// scaled by any factor gives the same s * I and s * B up to float rounding (relative 1e-6).
#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <vector>

#include "anisocap/core/image.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// The factor s of the file comment for a capture (> 0). Throws std::invalid_argument when no
/// light lies above the material or an intensity is not a positive finite number.
inline double exposure_scale(const capture& cap) {
  std::vector<double> irradiance;
  for (std::size_t k = 0; k < cap.images.size(); ++k) {
    const auto& im = cap.images[k];
    const double mean_i = (double(im.intensity[0]) + im.intensity[1] + im.intensity[2]) / 3.0;
    if (!(std::isfinite(mean_i) && mean_i > 0))
      throw std::invalid_argument("capture image " + std::to_string(k) + " (" + im.file + "): light intensity must be positive and finite");
    const double lx = im.light[0], ly = im.light[1], lz = im.light[2];
    const double r2 = lx * lx + ly * ly + lz * lz;
    if (lz <= 0 || !(r2 > 0)) continue;  // a light at or below the plane lights nothing at the centre
    irradiance.push_back(mean_i * (lz / std::sqrt(r2)) / (std::numbers::pi * r2));
  }
  if (irradiance.empty()) throw std::invalid_argument("exposure_scale: no light lies above the material");
  const auto mid = irradiance.begin() + std::ptrdiff_t(irradiance.size() / 2);
  std::nth_element(irradiance.begin(), mid, irradiance.end());
  double median = *mid;
  if (irradiance.size() % 2 == 0) median = 0.5 * (median + *std::max_element(irradiance.begin(), mid));
  return 1.0 / median;
}

/// Multiplies every light intensity of `cap` and every pixel of `photos` by `scale`.
inline void apply_exposure(capture& cap, std::vector<image>& photos, double scale) {
  const auto s = float(scale);
  for (auto& im : cap.images)
    for (float& i : im.intensity) i *= s;
  for (auto& p : photos)
    for (int c = 0; c < p.channels(); ++c) {
      float* d = p.plane(c);
      for (std::size_t k = 0; k < p.pixel_count(); ++k) d[k] *= s;
    }
}

}  // namespace anisocap
