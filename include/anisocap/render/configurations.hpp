#pragma once
/// @file
/// View and light configuration samplers (the paper's section 3.6, docs/method.md section 6) and the input sets
/// built from them (set alpha, set beta, the estimator's training set, the render-loss set).
///
/// Scene units (docs/method.md section 4): the longest side n of the material is 1, the material spans
/// [-W/2n, W/2n] x [-H/2n, H/2n] in the plane z = 0, z up. Every sampler draws from a
/// `random_generator`, so one seed gives the same capture on every machine; positions are computed
/// in double and rounded to float.
///
/// Light intensity (**decision**, the paper gives none): a point light at distance d from the
/// point it aims at gives that point an irradiance I cos(theta) / d^2. We set I = pi d^2
/// (`configuration_irradiance` = pi), so a white Lambertian texel facing the light renders with
/// radiance 1 whatever d is: configurations at n and at 4n are equally well exposed, diffuse
/// values stay in [0, 1] as the network's input transform (docs/method.md section 5, eq. 7) expects, and only
/// specular highlights exceed 1. A constant intensity would make 4n images 16 times darker than
/// n images and push them into the +0.01 offset of the log loss.
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <numbers>
#include <stdexcept>
#include <string>
#include <utility>

#include "anisocap/core/random.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// I cos(theta) / d^2 at the aimed point divided by cos(theta): the irradiance a light delivers at
/// normal incidence. pi makes a white diffuse texel render as 1 (see the file comment).
inline constexpr double configuration_irradiance = std::numbers::pi;

/// Nearest and farthest distance of a camera or light from its point in anisotropic, independent
/// and mirror configurations, in units of n (the paper: "between n and 4n").
inline constexpr double configuration_min_distance = 1.0;
inline constexpr double configuration_max_distance = 4.0;  ///< see configuration_min_distance

/// Largest angle from the vertical of a sampled direction (**decision**). The paper samples
/// cosine-distributed directions; their tail reaches the horizon, where a camera at z ~ 0 sees
/// nothing. 75 degrees keeps every camera and light at least sin(15 deg) * n ~ 0.26n above the
/// plane and still includes strongly oblique views.
inline constexpr double configuration_max_zenith = 75.0 * std::numbers::pi / 180.0;

/// Fresnel configuration bounds (the paper: camera "beside the material roughly along the centre
/// axes with a distance of up to 0.5n and a height of 0.1n to 0.4n").
inline constexpr double fresnel_max_distance = 0.5;   ///< horizontal distance beyond the material's edge
inline constexpr double fresnel_min_height = 0.1;     ///< lowest camera height
inline constexpr double fresnel_max_height = 0.4;     ///< highest camera height
/// How far (as a fraction of the half extent) the Fresnel mirror point and the camera may stray
/// from the centre axis: "roughly along the centre axes", "approximate mirroring configuration".
inline constexpr double fresnel_axis_jitter = 0.2;
/// Highest elevation of the Fresnel camera seen from its mirror point (**decision**). On a square
/// material the paper's bounds never exceed it; beside the short side of an elongated material
/// (e.g. 1024 x 350) the camera is moved out along the axis until it holds, so the view stays
/// grazing whatever the aspect ratio.
inline constexpr double fresnel_max_elevation = 45.0 * std::numbers::pi / 180.0;

/// Half extents (W/2n, H/2n) of a width x height material in scene units.
inline std::array<double, 2> material_half_extent(int width, int height) {
  if (width <= 0 || height <= 0) throw std::invalid_argument("configurations: material size must be positive");
  const double n = double(width > height ? width : height);
  return {0.5 * width / n, 0.5 * height / n};
}

/// The file name of input image i: input_00.exr, input_01.exr, ... (three digits from 100 on).
inline std::string input_file_name(int i) {
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "input_%02d.exr", i);
  return buffer;
}

namespace configuration_detail {

using vec3d = std::array<double, 3>;

inline vec3f to_float(const vec3d& v) { return {float(v[0]), float(v[1]), float(v[2])}; }

inline double distance(const vec3d& a, const vec3d& b) {
  const double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

/// A uniformly random point of the material (z = 0).
inline vec3d random_point(random_generator& rng, const std::array<double, 2>& half) {
  return {rng.uniform(-half[0], half[0]), rng.uniform(-half[1], half[1]), 0.0};
}

/// A cosine-distributed unit direction of the upper hemisphere, zenith at most
/// configuration_max_zenith (Malley's method: uniform on the disk of radius sin(max zenith),
/// lifted to the hemisphere).
inline vec3d cosine_direction(random_generator& rng) {
  const double max_radius = std::sin(configuration_max_zenith);
  const double r = max_radius * std::sqrt(rng.uniform());
  const double phi = 2.0 * std::numbers::pi * rng.uniform();
  return {r * std::cos(phi), r * std::sin(phi), std::sqrt(1.0 - r * r)};
}

inline vec3d along(const vec3d& point, const vec3d& direction, double d) {
  return {point[0] + d * direction[0], point[1] + d * direction[1], point[2] + d * direction[2]};
}

/// A capture_image whose light aims at `target`, with intensity pi * d^2 (file comment).
inline capture_image make_image(const vec3d& camera, const vec3d& light, const vec3d& target) {
  capture_image image;
  image.camera = to_float(camera);
  image.light = to_float(light);
  const double d = distance(light, target);
  const auto intensity = float(configuration_irradiance * d * d);
  image.intensity = {intensity, intensity, intensity};
  return image;
}

}  // namespace configuration_detail

/// Fresnel configuration (paper 3.6): the camera low beside the material near one of its centre
/// axes (side chosen at random among four), at most fresnel_max_distance beyond the edge and at a
/// height in [min_height, max_height] (units of n; the paper's are fresnel_min_height and
/// fresnel_max_height, lower is more grazing); the light mirrors it about the vertical
/// through a point near the material's centre, on the opposite side, so the view and light
/// directions at that point are both grazing (elevation at most fresnel_max_elevation, down to
/// ~5.7 degrees) and the Schlick term rises towards 1 there.
inline capture_image fresnel_configuration(random_generator& rng, int width, int height, double min_height, double max_height) {
  using namespace configuration_detail;
  if (!(min_height > 0) || !(max_height >= min_height))
    throw std::invalid_argument("fresnel_configuration: camera heights must satisfy 0 < min <= max");
  const auto half = material_half_extent(width, height);
  const int axis = int(rng.uniform_int(2));            // 0: camera beside a side along x, 1: along y
  const double side = rng.uniform_int(2) ? 1.0 : -1.0;  // which of the two sides
  const int other = 1 - axis;
  vec3d centre{0, 0, 0};
  centre[axis] = rng.uniform(-fresnel_axis_jitter, fresnel_axis_jitter) * half[axis];
  centre[other] = rng.uniform(-fresnel_axis_jitter, fresnel_axis_jitter) * half[other];
  vec3d camera{0, 0, 0};
  camera[axis] = side * (half[axis] + rng.uniform(0.0, fresnel_max_distance));
  camera[other] = rng.uniform(-fresnel_axis_jitter, fresnel_axis_jitter) * half[other];
  camera[2] = rng.uniform(min_height, max_height);
  const double min_reach = camera[2] / std::tan(fresnel_max_elevation);
  if (std::abs(camera[axis] - centre[axis]) < min_reach) camera[axis] = centre[axis] + side * min_reach;
  const vec3d light{2 * centre[0] - camera[0], 2 * centre[1] - camera[1], camera[2]};
  return make_image(camera, light, centre);
}

/// The paper's Fresnel configuration: camera height in [fresnel_min_height, fresnel_max_height].
inline capture_image fresnel_configuration(random_generator& rng, int width, int height) {
  return fresnel_configuration(rng, width, height, fresnel_min_height, fresnel_max_height);
}

/// Mirror configuration about a given point: camera at distance d_view along `direction`, light at
/// distance d_light along the mirrored direction (-x, -y, z), so the half vector at `point` is
/// vertical and the specular highlight of a flat texel there is centred (paper 3.6).
inline capture_image mirror_configuration_at(const std::array<double, 3>& point, const std::array<double, 3>& direction,
                                             double view_distance, double light_distance) {
  using namespace configuration_detail;
  const vec3d mirrored{-direction[0], -direction[1], direction[2]};
  return make_image(along(point, direction, view_distance), along(point, mirrored, light_distance), point);
}

/// Anisotropic configuration pair (paper 3.6): a random point of the material, a cosine-distributed
/// view direction with the light in the mirror direction, each at its own random distance in
/// [n, 4n]; the second image is the first rotated by 90 degrees about the vertical through the
/// point (same distances), so the highlight there is seen along two perpendicular azimuths and
/// the lobe's two widths and its rotation become separable.
inline std::pair<capture_image, capture_image> anisotropic_configuration_pair(random_generator& rng, int width,
                                                                             int height) {
  using namespace configuration_detail;
  const auto half = material_half_extent(width, height);
  const vec3d point = random_point(rng, half);
  const vec3d direction = cosine_direction(rng);
  const double view_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  const double light_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  const vec3d rotated{-direction[1], direction[0], direction[2]};  // +90 degrees about z
  return {mirror_configuration_at(point, direction, view_distance, light_distance),
          mirror_configuration_at(point, rotated, view_distance, light_distance)};
}

/// Mirror configuration (set beta of the paper's Table 1): one image of the anisotropic kind, camera and light
/// mirror-symmetric about the vertical through a random point, each at a random distance in [n, 4n].
inline capture_image mirror_configuration(random_generator& rng, int width, int height) {
  using namespace configuration_detail;
  const auto half = material_half_extent(width, height);
  const vec3d point = random_point(rng, half);
  const vec3d direction = cosine_direction(rng);
  const double view_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  const double light_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  return mirror_configuration_at(point, direction, view_distance, light_distance);
}

/// Independent configuration (paper 3.6): camera and light each above its own random point of the
/// material, along its own cosine-distributed direction (**decision**: the paper names no
/// direction law; the same as the anisotropic one), at its own random distance in [n, 4n].
/// The light's intensity is set for the point it aims at.
inline capture_image independent_configuration(random_generator& rng, int width, int height) {
  using namespace configuration_detail;
  const auto half = material_half_extent(width, height);
  const vec3d camera_point = random_point(rng, half);
  const vec3d camera_direction = cosine_direction(rng);
  const double camera_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  const vec3d light_point = random_point(rng, half);
  const vec3d light_direction = cosine_direction(rng);
  const double light_distance = rng.uniform(configuration_min_distance, configuration_max_distance);
  return make_image(along(camera_point, camera_direction, camera_distance),
                    along(light_point, light_direction, light_distance), light_point);
}

/// A phone's flash photograph: the camera of an independent configuration, the light at the camera
/// moved by `offset` (scene units; zero: at the lens). The intensity is the independent
/// configuration's.
inline capture_image flash_configuration(random_generator& rng, int width, int height, const vec3f& offset = {}) {
  capture_image im = independent_configuration(rng, width, height);
  for (int i = 0; i < 3; ++i) im.light[std::size_t(i)] = im.camera[std::size_t(i)] + offset[std::size_t(i)];
  return im;
}

/// `count` flash photographs (flash_configuration) drawn from `rng`, as a synthetic phone capture.
inline capture flash_set(int count, random_generator& rng, int width, int height, const vec3f& offset = {}) {
  capture c;
  for (int i = 0; i < count; ++i) c.images.push_back(flash_configuration(rng, width, height, offset));
  return c;
}

namespace configuration_detail {

/// The generator of one kind of set: the seed is salted per set, so that a material and its capture
/// drawn from the same seed (as `anisocap synthesize` does) use unrelated streams, and set alpha
/// and set beta of one seed are unrelated too.
inline random_generator set_generator(std::uint64_t seed, std::uint64_t salt) { return random_generator(hash64(seed ^ salt)); }

/// Appends an image and names it input_NN.exr by its position.
inline void push(capture& c, capture_image image) {
  image.file = input_file_name(int(c.images.size()));
  c.images.push_back(std::move(image));
}

inline void push_pair(capture& c, random_generator& rng, int width, int height) {
  auto [first, second] = anisotropic_configuration_pair(rng, width, height);
  push(c, std::move(first));
  push(c, std::move(second));
}

}  // namespace configuration_detail

/// How many Fresnel configurations set alpha holds and how grazing they are. The defaults are the
/// paper's set alpha; more, lower Fresnel configurations separate a'_s from F0 on metals better
/// (studies/README.md, "Grazing configurations on metals").
struct fresnel_options {
  int count = 2;                           ///< Fresnel configurations (>= 0)
  double min_height = fresnel_min_height;  ///< lowest camera height, units of n
  double max_height = fresnel_max_height;  ///< highest camera height, units of n
};

/// Set alpha for `image_count` inputs (paper 5, docs/method.md section 6): `fresnel.count` Fresnel (2 by
/// default), then anisotropic pairs, then 2 independent. When the slots left for pairs are odd in
/// number, the last one gets a third independent configuration (**decision**). Images are named
/// input_00.exr, ... With the default fresnel_options the set is the paper's, image for image.
/// Throws std::invalid_argument for fewer than fresnel.count + 2 images or bad heights.
inline capture set_alpha(int image_count, std::uint64_t seed, int width, int height, const fresnel_options& fresnel = {}) {
  using namespace configuration_detail;
  if (fresnel.count < 0) throw std::invalid_argument("set_alpha: the number of Fresnel configurations must be >= 0");
  if (image_count < fresnel.count + 2)
    throw std::invalid_argument("set_alpha: needs at least " + std::to_string(fresnel.count + 2) + " images (" +
                                std::to_string(fresnel.count) + " Fresnel + 2 independent), got " + std::to_string(image_count));
  random_generator rng = set_generator(seed, 0x616c706861ULL);
  capture c;
  c.images.reserve(std::size_t(image_count));
  for (int i = 0; i < fresnel.count; ++i)
    push(c, fresnel_configuration(rng, width, height, fresnel.min_height, fresnel.max_height));
  const int rest = image_count - fresnel.count - 2;
  for (int i = 0; i < rest / 2; ++i) push_pair(c, rng, width, height);
  const int independent = 2 + rest % 2;
  for (int i = 0; i < independent; ++i) push(c, independent_configuration(rng, width, height));
  return c;
}

/// Set beta for `image_count` inputs (paper 5): independent and mirror configurations only,
/// ceil(N/2) independent first, then floor(N/2) mirror (**decision**: the paper gives no split).
/// Throws std::invalid_argument for fewer than 1 image.
inline capture set_beta(int image_count, std::uint64_t seed, int width, int height) {
  using namespace configuration_detail;
  if (image_count < 1)
    throw std::invalid_argument("set_beta: needs at least 1 image, got " + std::to_string(image_count));
  random_generator rng = set_generator(seed, 0x62657461ULL);
  capture c;
  c.images.reserve(std::size_t(image_count));
  const int mirror = image_count / 2;
  for (int i = 0; i < image_count - mirror; ++i) push(c, independent_configuration(rng, width, height));
  for (int i = 0; i < mirror; ++i) push(c, mirror_configuration(rng, width, height));
  return c;
}

/// The estimator's 5 training inputs (paper 4.2): 1 Fresnel, 1 anisotropic pair, 2 independent,
/// in that order.
inline capture training_set(std::uint64_t seed, int width, int height) {
  using namespace configuration_detail;
  random_generator rng = set_generator(seed, 0x747261696eULL);
  capture c;
  push(c, fresnel_configuration(rng, width, height));
  push_pair(c, rng, width, height);
  for (int i = 0; i < 2; ++i) push(c, independent_configuration(rng, width, height));
  return c;
}

/// The 4 configurations of the training render loss (paper 4.2, eq. 8; docs/method.md section 6): 1 anisotropic pair,
/// 1 Fresnel, 1 independent, in that order.
inline capture render_loss_set(std::uint64_t seed, int width, int height) {
  using namespace configuration_detail;
  random_generator rng = set_generator(seed, 0x72656e646572ULL);
  capture c;
  push_pair(c, rng, width, height);
  push(c, fresnel_configuration(rng, width, height));
  push(c, independent_configuration(rng, width, height));
  return c;
}

}  // namespace anisocap
