#pragma once
/// @file
/// How well the photographs determine each parameter of each texel: the posterior standard
/// deviation of the Laplace approximation at the captured maps (docs/method.md, "Per-texel
/// uncertainty").
///
/// The image loss compares log(B + 0.01) of photograph and render. Read as a likelihood, each
/// used pixel channel is a Gaussian measurement of log(R + 0.01) with standard deviation `noise`
/// (in the loss's units: 0.01 is about 1% of a bright pixel's value), weighed by its mask value;
/// a render at or below its image's floor is no measurement. At the captured parameters theta the
/// Gauss-Newton information of a texel is
///
///     H = sum over images k, channels c of  m_k (d log(R_kc + 0.01) / d theta)^T (...) / noise^2,
///
/// the derivatives exact (forward-mode duals through brdf/ward.hpp). Before any photograph each
/// parameter is spread uniformly over its range (uncertainty_prior_sd), so the posterior
/// covariance is (H + diag(1 / prior_sd^2))^-1: where the photographs say nothing about a
/// parameter (F0 under a flash, alpha of an isotropic texel, the lobe under no highlight) its
/// standard deviation stays the prior's. `noise` is by default the weighted RMS of the residuals at
/// the maps, at least uncertainty_options::min_noise: the capture's own sensor noise and misfit.
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <memory>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/core/parallel.hpp"
#include "anisocap/ad/forward/dual.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/texel_radiance.hpp"

namespace anisocap {

/// Each parameter's spread before any photograph, in the maps' units: the standard deviation of a
/// uniform distribution over its range (range / sqrt(12)). Albedos, lobe widths and F0 over
/// [0, 1], the normal's x and y over [-0.5, 0.5] (60 degrees of tilt), alpha over [-pi/2, pi/2).
inline const std::array<double, parameter_count> uncertainty_prior_sd = [] {
  std::array<double, parameter_count> sd{};
  const double unit = 1.0 / std::sqrt(12.0);
  sd.fill(unit);
  sd[rotation] = std::numbers::pi * unit;
  return sd;
}();

/// The short name of parameter plane k: a_d.r, a_d.g, a_d.b, a_s.r, a_s.g, a_s.b, sigma_x,
/// sigma_y, F0, n_x, n_y, alpha.
inline const char* parameter_name(int k) {
  static constexpr const char* names[parameter_count] = {"a_d.r", "a_d.g", "a_d.b", "a_s.r", "a_s.g", "a_s.b",
                                                         "sigma_x", "sigma_y", "F0", "n_x", "n_y", "alpha"};
  if (k < 0 || k >= parameter_count) throw std::out_of_range("parameter_name: no parameter " + std::to_string(k));
  return names[k];
}

/// Options of texel_uncertainty.
struct uncertainty_options {
  /// Standard deviation of one log-radiance measurement (the loss's units); 0: the weighted RMS of
  /// the residuals at the maps, at least `min_noise`.
  double noise = 0;
  /// The least noise assumed: renders of the maps themselves fit to float rounding, which would
  /// claim every parameter exactly; 0.005 is half a percent of a pixel's value.
  double min_noise = 0.005;
  /// A parameter is determined at a texel where its posterior standard deviation (the Laplace
  /// approximation's, before the calibration) is at most this share of its prior's.
  double determined_ratio = 0.5;
  /// Applies the calibration for the photographs' encoding (calibration_for their
  /// lossiest_encoding) to the Laplace standard deviations (what is written and summarised); off:
  /// the Laplace approximation's own.
  bool calibrated = true;
  /// Throws std::invalid_argument for impossible values.
  void validate() const {
    if (!(noise >= 0) || !std::isfinite(noise)) throw std::invalid_argument("uncertainty noise must be a finite number >= 0");
    if (!(min_noise > 0) || !std::isfinite(min_noise)) throw std::invalid_argument("uncertainty min_noise must be a finite number > 0");
    if (!(determined_ratio > 0 && determined_ratio < 1))
      throw std::invalid_argument("uncertainty determined_ratio must be in (0, 1)");
  }
};

/// How the Laplace standard deviations are widened into calibrated ones: sd' = sqrt((scale_k sd)^2
/// + (floor_k + relative_k |value|)^2) for parameter k. The Laplace approximation sees only the
/// curvature at the solution; the captured value's error also holds what it cannot see: the
/// model's mismatch with the photographs, errors alike in every photograph (8-bit codes, JPEG's
/// colour), and a loss that is not Gaussian (most texels fit better than the residuals' RMS says,
/// a few much worse). The constants are fitted on
/// synthetic captures (docs/results.md, "Per-texel uncertainty: calibration": the study, its seeds
/// and the coverage on other seeds) so that 68% and 95% of true values lie within 1 and 2 sd.
struct uncertainty_calibration_table {
  std::array<double, parameter_count> scale;     ///< factor on the Laplace standard deviation
  std::array<double, parameter_count> floor;     ///< added standard deviation, the parameter's units
  std::array<double, parameter_count> relative;  ///< added standard deviation per unit of |value|
  /// Parameter k's calibrated standard deviation from its Laplace one at `value`.
  double apply(int k, double sd, double value) const {
    const auto i = std::size_t(k);
    const double added = floor[i] + relative[i] * std::abs(value);
    return std::sqrt(scale[i] * scale[i] * sd * sd + added * added);
  }
};

/// The fitted calibration for photographs stored losslessly, as floats or 16-bit codes (see
/// uncertainty_calibration_table), in parameter order a_d (r, g, b), a'_s (r, g, b), sigma_x,
/// sigma_y, F0, n_x, n_y, alpha. Fitted by studies/fit_uncertainty_calibration.py on 48 captures:
/// 8 families under a lamp and a flash, three seed sets, with 8 linear photographs with sensor
/// noise. Where the table shrinks a deviation (scale below 1) most texels fit better than the
/// residuals' RMS says; sigma_x's error grows with its value (relative 0.3).
inline constexpr uncertainty_calibration_table uncertainty_calibration{
    {0.298, 0.27, 0.543, 0.894, 0.894, 0.809, 0.2, 0.491, 0.6, 0.663, 0.663, 0.663},
    {0.002, 0.002, 0.001, 0, 0, 0, 0.002, 0, 0, 0, 0.002, 0},
    {0, 0, 0, 0, 0, 0, 0.3, 0, 0, 0, 0, 0}};

/// The calibration for photographs stored as 8-bit codes without JPEG (photo_encoding::eight_bit,
/// 8-bit PNGs): each value is rounded to one of 256 codes, alike in every photograph where the
/// texel's shading is alike, and the brightest highlights clip. Fitted on 16 captures of the 8
/// families with 12 photographs stored so: wider than uncertainty_calibration for the specular
/// albedo (the clipped and rounded highlights).
inline constexpr uncertainty_calibration_table uncertainty_calibration_eight_bit{
    {0.402, 0.445, 0.402, 1.47, 1.47, 1.33, 0.543, 0.543, 0.491, 0.733, 0.894, 0.6},
    {0.002, 0.002, 0.002, 0, 0, 0, 0.001, 0, 0, 0, 0, 0},
    {0, 0, 0, 0.02, 0, 0, 0.02, 0, 0.5, 0, 0, 0}};

/// The calibration for photographs stored as JPEGs with their colour at full resolution
/// (photo_encoding::jpeg). JPEG quantises the colour more coarsely than the brightness, an error
/// alike in every photograph that the residuals cannot show, so the diffuse albedo and the normal
/// read from the shading need wider deviations than uncertainty_calibration's. Fitted on 16
/// captures of the 8 families with 12 JPEG photographs of quality 95.
inline constexpr uncertainty_calibration_table uncertainty_calibration_jpeg{
    {0.6, 0.6, 0.733, 1.47, 1.47, 1.33, 0.491, 0.491, 0.894, 0.894, 0.988, 0.663},
    {0.002, 0.002, 0.002, 0, 0, 0, 0.05, 0, 0, 0, 0, 0.001},
    {0, 0, 0, 0, 0, 0, 0.02, 0.1, 0, 0.02, 0, 0}};

/// The calibration for JPEGs with their colour at a lower resolution than their brightness
/// (photo_encoding::jpeg_subsampled, most phones' JPEGs): the colour is also blurred, alike in
/// every photograph. Fitted on the same 16 captures stored at quality 90 (4:2:0).
inline constexpr uncertainty_calibration_table uncertainty_calibration_jpeg_subsampled{
    {1.47, 0.809, 1.47, 1.63, 1.47, 1.33, 0.6, 0.364, 0.894, 1.09, 1.33, 0.809},
    {0, 0.002, 0, 0, 0, 0, 0.05, 0, 0, 0.001, 0.002, 0.02},
    {0, 0, 0, 0, 0, 0, 0.02, 0.2, 0, 0.1, 0, 0}};

/// The lossiest encoding among the photographs `cap` describes (capture_image::encoding).
inline photo_encoding lossiest_encoding(const capture& cap) {
  photo_encoding e = photo_encoding::lossless;
  for (const capture_image& im : cap.images) e = std::max(e, im.encoding);
  return e;
}

/// The table for photographs stored with encoding `e`: uncertainty_calibration,
/// uncertainty_calibration_eight_bit, uncertainty_calibration_jpeg or
/// uncertainty_calibration_jpeg_subsampled.
inline const uncertainty_calibration_table& calibration_for(photo_encoding e) {
  switch (e) {
    case photo_encoding::eight_bit: return uncertainty_calibration_eight_bit;
    case photo_encoding::jpeg: return uncertainty_calibration_jpeg;
    case photo_encoding::jpeg_subsampled: return uncertainty_calibration_jpeg_subsampled;
    default: return uncertainty_calibration;
  }
}

/// Per-texel posterior standard deviations and their summary.
struct uncertainty_result {
  /// Plane k holds parameter k's posterior standard deviation, in the maps' units.
  material_maps sd;
  /// Plane k holds parameter k's remaining Gauss-Newton step at each texel (texel_gauss_newton),
  /// -(H + noise^2 prior)^-1 g: how far the least-squares fit of the photographs, damped by the
  /// prior, lies from the captured value, in the maps' units and with its sign. Near 0 where the
  /// capture settled at the photographs' fit, whatever its error.
  material_maps step;
  /// The measurement noise used (uncertainty_options::noise or the residuals' RMS).
  double noise = 0;
  /// The encoding whose table the deviations went through (calibration_for the capture's
  /// lossiest_encoding); empty when they are the Laplace approximation's own.
  std::optional<photo_encoding> calibration;
  /// Per parameter, the share of texels where it is determined (sd <= determined_ratio x prior sd).
  std::array<double, parameter_count> determined_share{};
  /// Whether the photographs determine parameter k on at least half of the texels.
  bool determined(int k) const { return determined_share.at(std::size_t(k)) >= 0.5; }
  /// Each standard deviation over its parameter's before any photograph (uncertainty_prior_sd):
  /// 0 where the photographs fix it, 1 where they say nothing (what the viewer's overlay shows).
  material_maps ratio() const;
};

namespace uncertainty_detail {

using texel_dual = ad::dual<double, parameter_count>;

/// Texel (x, y)'s parameters as the 12 independent variables of a dual.
inline ward_parameters<texel_dual> variables(const material_maps& m, int x, int y) {
  ward_parameters<texel_dual> p;
  for (int c = 0; c < 3; ++c) {
    p.diffuse[c] = texel_dual::variable(m.at(diffuse_r + c, x, y), std::size_t(diffuse_r + c));
    p.specular[c] = texel_dual::variable(m.at(specular_r + c, x, y), std::size_t(specular_r + c));
  }
  p.sx = texel_dual::variable(m.at(lobe_x, x, y), lobe_x);
  p.sy = texel_dual::variable(m.at(lobe_y, x, y), lobe_y);
  p.f0 = texel_dual::variable(m.at(fresnel_f0, x, y), fresnel_f0);
  p.nx = texel_dual::variable(m.at(normal_x, x, y), normal_x);
  p.ny = texel_dual::variable(m.at(normal_y, x, y), normal_y);
  p.alpha = texel_dual::variable(m.at(rotation, x, y), rotation);
  return p;
}

/// Pixel (x, y)'s weight in image k: its mask value (at most 1), 1 without masks.
inline double pixel_weight(const loss_targets& t, std::size_t k, int x, int y) {
  return t.masks.empty() ? 1.0 : std::min(1.0, double(t.masks[k].at(0, x, y)));
}

inline double floor_of(const loss_targets& t, std::size_t k) { return t.floors.empty() ? 0.0 : double(t.floors[k]); }

/// The log residual of render value R in channel c of pixel (x, y) of image k:
/// log(max(R, floor) + 0.01) - log(max(B, floor) + 0.01), the target's max(B, floor) + 0.01 precomputed.
inline double log_residual(const loss_targets& t, std::size_t k, int c, int x, int y, double radiance) {
  return std::log(std::max(radiance, floor_of(t, k)) + double(loss_epsilon)) - std::log(double(t.images[k].at(c, x, y)));
}

}  // namespace uncertainty_detail

namespace uncertainty_detail {

using texel_matrix = Eigen::Matrix<double, parameter_count, parameter_count>;
using texel_vector = Eigen::Matrix<double, parameter_count, 1>;

/// The sums texel_information and texel_gauss_newton share: the information sum m g g^T and,
/// with `residuals`, the gradient sum m g r with r = log(max(R, floor) + 0.01) - log(max(B, floor)
/// + 0.01), B the target. Where the render is at or below its image's floor, g is 0.
template <bool residuals>
void accumulate_texel(const material_maps& maps, const capture& cap, const loss_targets& targets, int x, int y, texel_matrix& h,
                      texel_vector& b) {
  h.setZero();
  b.setZero();
  const ward_parameters<texel_dual> p = variables(maps, x, y);
  for (std::size_t k = 0; k < cap.images.size(); ++k) {
    const double m = pixel_weight(targets, k, x, y);
    if (m <= 0) continue;
    const auto radiance = texel_radiance<texel_dual>(p, cap.images[k], x, y, maps.width(), maps.height());
    for (int c = 0; c < 3; ++c) {
      const double value = radiance[std::size_t(c)].value;
      if (!(value > floor_of(targets, k))) continue;  // max(R, floor) does not move
      texel_vector g;
      const double scale = 1.0 / (value + double(loss_epsilon));
      for (int i = 0; i < parameter_count; ++i) g[i] = radiance[std::size_t(c)].grad[std::size_t(i)] * scale;
      h.noalias() += m * g * g.transpose();
      if constexpr (residuals) b.noalias() += (m * log_residual(targets, k, c, x, y, value)) * g;
    }
  }
}

}  // namespace uncertainty_detail

/// The Gauss-Newton information of texel (x, y) for one measurement noise of 1 (divide by
/// noise^2): sum over images and channels of m g g^T with g = d log(max(R, floor) + 0.01) / d theta.
inline Eigen::Matrix<double, parameter_count, parameter_count> texel_information(const material_maps& maps, const capture& cap,
                                                                               const loss_targets& targets, int x, int y) {
  uncertainty_detail::texel_matrix h;
  uncertainty_detail::texel_vector unused;
  uncertainty_detail::accumulate_texel<false>(maps, cap, targets, x, y, h, unused);
  return h;
}

/// Texel (x, y)'s Gauss-Newton normal equations for one measurement noise of 1: the information
/// (texel_information) and the gradient of half the squared log residuals, sum of m g r with
/// r = log(max(R, floor) + 0.01) - log(max(B, floor) + 0.01). Where the texel's parameters sit at
/// the least-squares fit of the photographs the gradient is 0; the Gauss-Newton step from them is
/// -(information + noise^2 prior)^-1 gradient.
struct texel_normal_equations {
  Eigen::Matrix<double, parameter_count, parameter_count> information;  ///< sum of m g g^T
  Eigen::Matrix<double, parameter_count, 1> gradient;                   ///< sum of m g r
};

/// texel_normal_equations of texel (x, y) of `maps` against the photographs behind `targets`.
inline texel_normal_equations texel_gauss_newton(const material_maps& maps, const capture& cap, const loss_targets& targets, int x,
                                                 int y) {
  texel_normal_equations e;
  uncertainty_detail::accumulate_texel<true>(maps, cap, targets, x, y, e.information, e.gradient);
  return e;
}

/// The weighted RMS of the log residuals log(max(R, floor) + 0.01) - log(max(B, floor) + 0.01) of
/// `maps` against the targets: the noise texel_uncertainty assumes by default.
inline double residual_rms(const material_maps& maps, const capture& cap, const loss_targets& targets) {
  using namespace uncertainty_detail;
  double sum = 0, weight = 0;
#pragma omp parallel for schedule(static) reduction(+ : sum, weight)
  for (int y = 0; y < maps.height(); ++y)
    for (int x = 0; x < maps.width(); ++x) {
      const ward_parameters<double> p = texel_ward_parameters<double>(maps, x, y);
      for (std::size_t k = 0; k < cap.images.size(); ++k) {
        const double m = pixel_weight(targets, k, x, y);
        if (m <= 0) continue;
        const auto radiance = texel_radiance<double>(p, cap.images[k], x, y, maps.width(), maps.height());
        for (int c = 0; c < 3; ++c) {
          const double r = log_residual(targets, k, c, x, y, radiance[std::size_t(c)]);
          sum += m * r * r;
          weight += m;
        }
      }
    }
  return weight > 0 ? std::sqrt(sum / weight) : 0.0;
}

/// Per-texel posterior standard deviations of `maps` captured from the photographs behind
/// `targets` under `cap` (the configurations and targets the capture fitted: exposure-normalised
/// where it normalised). Throws std::invalid_argument when the sizes disagree.
inline uncertainty_result texel_uncertainty(const material_maps& maps, const capture& cap, const loss_targets& targets,
                                            const uncertainty_options& options = {}) {
  options.validate();
  if (targets.width != maps.width() || targets.height != maps.height() || targets.images.size() != cap.images.size())
    throw std::invalid_argument("texel_uncertainty: the maps, the configurations and the photographs' targets disagree in size");
  uncertainty_result result;
  result.noise = options.noise > 0 ? options.noise : std::max(options.min_noise, residual_rms(maps, cap, targets));
  result.sd = material_maps(maps.width(), maps.height());
  result.step = material_maps(maps.width(), maps.height());
  Eigen::Matrix<double, parameter_count, parameter_count> prior = Eigen::Matrix<double, parameter_count, parameter_count>::Zero();
  for (int i = 0; i < parameter_count; ++i) prior(i, i) = 1.0 / (uncertainty_prior_sd[std::size_t(i)] * uncertainty_prior_sd[std::size_t(i)]);
  const photo_encoding encoding = lossiest_encoding(cap);
  const uncertainty_calibration_table& table = calibration_for(encoding);
  if (options.calibrated) result.calibration = encoding;
  const double inv_noise2 = 1.0 / (result.noise * result.noise);
  std::array<double, parameter_count> determined{};
  const int w = maps.width(), h = maps.height();
#pragma omp parallel
  {
    std::array<double, parameter_count> mine{};
#pragma omp for schedule(dynamic, 4)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const texel_normal_equations e = texel_gauss_newton(maps, cap, targets, x, y);
        const Eigen::LDLT<uncertainty_detail::texel_matrix> precision(e.information * inv_noise2 + prior);
        const uncertainty_detail::texel_matrix covariance = precision.solve(uncertainty_detail::texel_matrix::Identity());
        const uncertainty_detail::texel_vector step = -precision.solve(e.gradient * inv_noise2);
        for (int i = 0; i < parameter_count; ++i) {
          result.step.at(i, x, y) = float(step[i]);
          const double laplace = std::sqrt(std::max(0.0, covariance(i, i)));
          result.sd.at(i, x, y) = float(options.calibrated ? table.apply(i, laplace, maps.at(i, x, y)) : laplace);
          // What the photographs determine is the data's information, before the calibration.
          if (laplace <= options.determined_ratio * uncertainty_prior_sd[std::size_t(i)]) mine[std::size_t(i)] += 1;
        }
      }
#pragma omp critical
    for (int i = 0; i < parameter_count; ++i) determined[std::size_t(i)] += mine[std::size_t(i)];
  }
  for (int i = 0; i < parameter_count; ++i) result.determined_share[std::size_t(i)] = determined[std::size_t(i)] / double(maps.texel_count());
  return result;
}

inline material_maps uncertainty_result::ratio() const {
  material_maps r = sd;
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < r.texel_count(); ++i) r.plane(k)[i] = float(r.plane(k)[i] / uncertainty_prior_sd[std::size_t(k)]);
  return r;
}

/// The files of an uncertainty folder: the map set's files (data/map_io.hpp map_file_names, no
/// height), each channel the posterior standard deviation of the parameter the map file holds
/// there (normal.exr: n_x, n_y and 0; fresnel.exr and rotation.exr: the one value in R, G, B).
inline std::vector<image> uncertainty_images(const uncertainty_result& u) {
  material_maps m = u.sd;
  std::vector<image> images = detail::map_images(m);
  std::fill(images[4].plane(2), images[4].plane(2) + images[4].pixel_count(), 0.0f);  // not n_z of the standard deviations
  return images;
}

/// Creates `folder` and adds to `encodes` the jobs that stage uncertainty_images(u) into it as
/// EXRs, within `transaction` (which must live until `encodes` has run; the jobs hold their own
/// copy of the images).
inline void write_uncertainty(const uncertainty_result& u, const std::filesystem::path& folder, file_transaction& transaction,
                              job_batch& encodes) {
  std::filesystem::create_directories(folder);
  const auto images = std::make_shared<const std::vector<image>>(uncertainty_images(u));
  file_transaction* files = &transaction;
  for (std::size_t i = 0; i < images->size(); ++i)
    encodes.add([images, i, folder, files] { write_exr((*images)[i], folder / map_file_names[i], *files); },
                double((*images)[i].pixel_count()) * (*images)[i].channels());
}

/// Writes uncertainty_images(u) into `folder` (created), within `transaction` (data/image_io.hpp):
/// nothing replaces an existing file until the transaction commits.
inline void write_uncertainty(const uncertainty_result& u, const std::filesystem::path& folder, file_transaction& transaction) {
  job_batch encodes;
  write_uncertainty(u, folder, transaction, encodes);
  encodes.run();
}

}  // namespace anisocap
