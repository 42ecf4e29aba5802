#pragma once
/// @file
/// The next photographs to take: among configurations a person can set up (a phone with its
/// flash, or a camera and a hand-placed lamp, around the sample), the 1-4 that most lower the
/// maps' posterior uncertainty (pipeline/uncertainty.hpp), chosen greedily by expected
/// information.
///
/// A candidate photograph would add, at each texel, the Gauss-Newton information of its one image
/// at the captured maps (texel_information, the same noise as the capture's). Its value is the
/// drop of the total normalised posterior variance, sum over texels and parameters of
/// variance / prior variance, so that a parameter the photographs leave at its prior (F0 under a
/// flash) weighs as much as any other. The best candidate is taken, its information added, and
/// the next chosen against the updated posterior: a second photo of the same kind gains less.
/// Texels are sampled on a grid (plan_options::stride) to keep the search to seconds.
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/pipeline/uncertainty.hpp"

namespace anisocap {

/// Options of plan_photographs.
struct plan_options {
  int photos = 2;       ///< how many photographs to propose, 1-4
  int stride = 4;       ///< every stride-th texel in x and y enters the search
  bool flash = true;    ///< propose phone-with-flash photographs (light at the camera)
  bool lamp = true;     ///< propose camera-and-lamp photographs (the lamp mirrored opposite the camera)
  /// Camera (and lamp) distances from the sample's centre, in units of its longest side.
  std::vector<double> distances{2.0, 3.0};
  /// Elevations above the sample's plane, in degrees (90: straight above).
  std::vector<double> elevations{15.0, 25.0, 40.0, 60.0, 90.0};
  int azimuths = 8;     ///< directions around the sample, evenly spaced from +x
  /// Throws std::invalid_argument for impossible values.
  void validate() const {
    if (photos < 1 || photos > 4) throw std::invalid_argument("plan_options::photos must be 1 to 4");
    if (stride < 1) throw std::invalid_argument("plan: the stride must be at least 1");
    if (!flash && !lamp) throw std::invalid_argument("plan: neither flash nor lamp photographs allowed");
    if (azimuths < 1 || distances.empty() || elevations.empty()) throw std::invalid_argument("plan: no candidate positions");
    for (double d : distances)
      if (!(d > 0.6)) throw std::invalid_argument("plan: every distance must be above 0.6 sample lengths");
    for (double e : elevations)
      if (!(e > 0 && e <= 90)) throw std::invalid_argument("plan: every elevation must be in (0, 90] degrees");
  }
};

/// One photograph a person can take.
struct plan_candidate {
  bool flash = true;         ///< light at the camera (a phone's flash); else a lamp mirrored opposite
  double distance = 2;       ///< camera distance from the centre, sample lengths
  double elevation = 90;     ///< camera elevation, degrees above the plane
  double azimuth = 0;        ///< camera azimuth, degrees counter-clockwise from +x
  capture_image config;      ///< its configuration (capture.json units; irradiance 1 at the centre)
};

/// A proposed photograph, with why.
struct planned_photo {
  plan_candidate candidate;
  /// The drop of the total normalised posterior variance it brings, as a share of the total before it.
  double gain = 0;
  /// Per parameter, the share of (sampled) texels it is determined on before and after this photograph.
  std::array<double, parameter_count> determined_before{}, determined_after{};
  /// The parameter whose determined share rises most (or whose variance drops most), named in `reason`.
  int main_parameter = 0;
  std::string reason;  ///< one sentence in words
};

/// The plan: the proposed photographs in the order to take them.
struct plan_result {
  std::vector<planned_photo> photos;
  double noise = 0;                  ///< the measurement noise assumed (the capture's)
  int candidates = 0;                ///< how many candidates were weighed
};

/// The candidates of `o`: each distance, elevation and azimuth, as a flash photograph and as a
/// camera with the lamp at the same distance and elevation on the opposite side (where a flat
/// sample mirrors it: the highlight at the centre, and at low elevations the Fresnel rise).
/// Intensities give irradiance 1 at the sample's centre.
inline std::vector<plan_candidate> plan_candidates(const plan_options& o) {
  std::vector<plan_candidate> out;
  const double deg = std::numbers::pi / 180;
  auto at = [](double distance, double elevation, double azimuth) {
    return vec3f{float(distance * std::cos(elevation) * std::cos(azimuth)), float(distance * std::cos(elevation) * std::sin(azimuth)),
                 float(distance * std::sin(elevation))};
  };
  for (double d : o.distances)
    for (double e : o.elevations)
      for (int a = 0; a < (e >= 90 ? 1 : o.azimuths); ++a) {
        const double azimuth = 360.0 * a / o.azimuths;
        for (int kind = 0; kind < 2; ++kind) {
          const bool flash = kind == 0;
          if ((flash && !o.flash) || (!flash && !o.lamp)) continue;
          plan_candidate c{flash, d, e, azimuth, {}};
          c.config.camera = at(d, e * deg, azimuth * deg);
          c.config.light = flash ? c.config.camera : at(d, e * deg, (azimuth + 180) * deg);
          const float i = float(std::numbers::pi * d * d / std::sin(e * deg));  // irradiance 1 at the centre
          c.config.intensity = {i, i, i};
          c.config.file = "planned.exr";
          out.push_back(c);
        }
      }
  return out;
}

namespace plan_detail {

using matrix = Eigen::Matrix<double, parameter_count, parameter_count>;

/// sum over parameters of the posterior variance / prior variance of a precision matrix.
inline double normalised_variance(const matrix& precision, std::array<bool, parameter_count>* determined, double ratio) {
  const matrix covariance = precision.ldlt().solve(matrix::Identity());
  double total = 0;
  for (int k = 0; k < parameter_count; ++k) {
    const double prior = uncertainty_prior_sd[std::size_t(k)];
    const double v = std::max(0.0, covariance(k, k)) / (prior * prior);
    total += v;
    if (determined) (*determined)[std::size_t(k)] = std::sqrt(v) <= ratio;
  }
  return total;
}

}  // namespace plan_detail

/// Proposes the next photographs for `maps` captured from the photographs behind `targets` under
/// `cap` (exposure-normalised as the capture saw them), with `noise` the capture's measurement
/// noise (uncertainty_result::noise). Throws std::invalid_argument for impossible options or sizes.
inline plan_result plan_photographs(const material_maps& maps, const capture& cap, const loss_targets& targets, double noise,
                                    const plan_options& o = {}, const uncertainty_options& uo = {}) {
  using plan_detail::matrix;
  o.validate();
  uo.validate();
  if (!(noise > 0) || !std::isfinite(noise)) throw std::invalid_argument("plan: the noise must be a positive number");
  if (targets.width != maps.width() || targets.height != maps.height() || targets.images.size() != cap.images.size())
    throw std::invalid_argument("plan: the maps, the configurations and the photographs' targets disagree in size");
  plan_result result;
  result.noise = noise;
  const double inv_noise2 = 1.0 / (noise * noise);
  // The sampled texels' precision now.
  struct texel { int x, y; matrix precision; };
  std::vector<texel> texels;
  for (int y = o.stride / 2; y < maps.height(); y += o.stride)
    for (int x = o.stride / 2; x < maps.width(); x += o.stride) texels.push_back({x, y, matrix::Zero()});
  matrix prior = matrix::Zero();
  for (int k = 0; k < parameter_count; ++k) prior(k, k) = 1.0 / (uncertainty_prior_sd[std::size_t(k)] * uncertainty_prior_sd[std::size_t(k)]);
#pragma omp parallel for schedule(dynamic, 16)
  for (std::size_t i = 0; i < texels.size(); ++i)
    texels[i].precision = texel_information(maps, cap, targets, texels[i].x, texels[i].y) * inv_noise2 + prior;
  std::vector<plan_candidate> candidates = plan_candidates(o);
  result.candidates = int(candidates.size());
  // One image's information at a texel: texel_information of a capture of that one image, with no
  // mask or floor (the targets' values do not enter it). The one-image captures are made once.
  loss_targets one;
  one.width = maps.width();
  one.height = maps.height();
  one.images.assign(1, image(1, 1, 3));
  std::vector<capture> singles(candidates.size());
  for (std::size_t c = 0; c < candidates.size(); ++c) singles[c].images.push_back(candidates[c].config);
  auto information = [&](std::size_t c, const texel& t) { return texel_information(maps, singles[c], one, t.x, t.y); };
  auto determined_share = [&](const std::vector<texel>& ts) {
    std::array<double, parameter_count> share{};
    for (const texel& t : ts) {
      std::array<bool, parameter_count> d{};
      plan_detail::normalised_variance(t.precision, &d, uo.determined_ratio);
      for (int k = 0; k < parameter_count; ++k) share[std::size_t(k)] += d[std::size_t(k)];
    }
    for (double& s : share) s /= double(ts.size());
    return share;
  };
  for (int photo = 0; photo < o.photos && !candidates.empty(); ++photo) {
    double before = 0;
    for (const texel& t : texels) before += plan_detail::normalised_variance(t.precision, nullptr, uo.determined_ratio);
    std::vector<double> after(candidates.size(), 0.0);
#pragma omp parallel for schedule(dynamic, 1)
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      double total = 0;
      for (const texel& t : texels)
        total += plan_detail::normalised_variance(t.precision + information(c, t) * inv_noise2, nullptr, uo.determined_ratio);
      after[c] = total;
    }
    const std::size_t best = std::size_t(std::min_element(after.begin(), after.end()) - after.begin());
    planned_photo p;
    p.candidate = candidates[best];
    p.gain = before > 0 ? (before - after[best]) / before : 0.0;
    p.determined_before = determined_share(texels);
    for (texel& t : texels) t.precision += information(best, t) * inv_noise2;
    p.determined_after = determined_share(texels);
    int main = 0;
    for (int k = 1; k < parameter_count; ++k)
      if (p.determined_after[std::size_t(k)] - p.determined_before[std::size_t(k)] >
          p.determined_after[std::size_t(main)] - p.determined_before[std::size_t(main)])
        main = k;
    p.main_parameter = main;
    char text[240];
    if (p.determined_after[std::size_t(main)] > p.determined_before[std::size_t(main)])
      std::snprintf(text, sizeof text, "determines %s on %.0f%% of the texels instead of %.0f%%; the total uncertainty drops %.0f%%",
                    parameter_name(main), 100 * p.determined_after[std::size_t(main)], 100 * p.determined_before[std::size_t(main)],
                    100 * p.gain);
    else
      std::snprintf(text, sizeof text, "narrows what the photographs already determine; the total uncertainty drops %.0f%%", 100 * p.gain);
    p.reason = text;
    result.photos.push_back(p);
    candidates.erase(candidates.begin() + std::ptrdiff_t(best));
    singles.erase(singles.begin() + std::ptrdiff_t(best));
  }
  return result;
}

}  // namespace anisocap
