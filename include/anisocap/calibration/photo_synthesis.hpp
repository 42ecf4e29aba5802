#pragma once
/// @file
/// Synthetic perspective photographs of a procedural material, to test the path from a camera to
/// a capture without a camera: a pinhole camera at each configuration of a capture, aimed at the
/// sample's centre, sees the material's maps (bilinear lookup) shaded by the renderer's own
/// per-texel evaluation (render/renderer.hpp, docs/method.md sections 3-4) under a point light
/// that is either where the configuration puts it or fixed to the camera (a flash). Each photo is
/// exposed so that a chosen fraction of the sample's pixels stays below white, gets simulated
/// sensor noise, is clipped to [0, 1], sRGB-encoded to 8 bits and stored as a JPEG, as a phone
/// would (or losslessly as an 8-bit PNG, or as linear float EXR, a RAW developed linearly); the
/// photos.json beside them gives the exact corners, the light and intensity x exposure.
#include <stb/stb_image_write.h>

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/calibration/camera.hpp"
#include "anisocap/calibration/photos_description.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"

namespace anisocap {

/// One synthetic photograph's camera and light.
struct photo_setup {
  pinhole_camera camera;                   ///< intrinsics
  planar_pose pose;                        ///< sample -> camera
  Eigen::Vector3d light_mm{0, 0, 100};     ///< light position, sample coordinates (mm)
  vec3f intensity{1, 1, 1};                ///< light intensity in the capture's units (texture-space renderer's)
};

/// A flat, matte print lying around the sample in its plane (e.g. the marker frame of
/// calibration/markers.hpp): a 1-channel albedo image centred on the sample, rows along -y.
struct printed_surround {
  image albedo;                       ///< diffuse albedo, 1 channel
  double width_mm = 0, height_mm = 0; ///< the print's extent
};

/// How a photograph reads the material's maps between texel centres.
enum class texture_lookup {
  bilinear,  ///< interpolate the parameters between texel centres (a smooth material)
  nearest,   ///< each texel a patch of constant material: the maps describe exactly what is photographed
};

/// Bilinear lookup of every parameter plane of `maps` at continuous texture coordinate (u, v)
/// (texel (x, y) spans [x, x+1) x [y, y+1)), clamped at the edges. The rotation is interpolated
/// as the doubled angle (cos 2a, sin 2a): the lobe is the same at a and a + pi, so the shorter way
/// round is the right one.
inline void lookup_parameters(const material_maps& maps, double u, double v, float (&out)[parameter_count]) {
  const double tx = std::clamp(u - 0.5, 0.0, double(maps.width() - 1)), ty = std::clamp(v - 0.5, 0.0, double(maps.height() - 1));
  const int x0 = std::min(int(tx), maps.width() - 1), y0 = std::min(int(ty), maps.height() - 1);
  const int x1 = std::min(x0 + 1, maps.width() - 1), y1 = std::min(y0 + 1, maps.height() - 1);
  const double fx = tx - x0, fy = ty - y0;
  const double w[4] = {(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
  const int xs[4] = {x0, x1, x0, x1}, ys[4] = {y0, y0, y1, y1};
  for (int k = 0; k < parameter_count; ++k) {
    if (k == rotation) continue;
    double s = 0;
    for (int t = 0; t < 4; ++t) s += w[t] * maps.at(k, xs[t], ys[t]);
    out[k] = float(s);
  }
  double c = 0, s = 0;
  for (int t = 0; t < 4; ++t) {
    const double a = 2.0 * maps.at(rotation, xs[t], ys[t]);
    c += w[t] * std::cos(a);
    s += w[t] * std::sin(a);
  }
  out[rotation] = float(0.5 * std::atan2(s, c));
}

namespace photo_synthesis_detail {

/// The parameters seen at point (sx, sy) of the sample's plane (mm, centre at 0): the maps' where
/// the point lies on the sample, read by `lookup`, else the surround's albedo where it lies on the
/// print. Returns false (params untouched) where the point misses both.
inline bool parameters_at(const material_maps& maps, double longest_mm, double sx, double sy, texture_lookup lookup,
                          const printed_surround* surround, float (&params)[parameter_count]) {
  const double n = std::max(maps.width(), maps.height());
  const double u = sx / longest_mm * n + 0.5 * maps.width(), v = 0.5 * maps.height() - sy / longest_mm * n;
  if (u >= 0 && v >= 0 && u <= maps.width() && v <= maps.height()) {
    if (lookup == texture_lookup::bilinear) {
      lookup_parameters(maps, u, v, params);
    } else {
      const int tx = std::min(int(u), maps.width() - 1), ty = std::min(int(v), maps.height() - 1);
      for (int k = 0; k < parameter_count; ++k) params[k] = maps.at(k, tx, ty);
    }
    return true;
  }
  if (!surround) return false;
  const double fx = (sx / surround->width_mm + 0.5) * surround->albedo.width();
  const double fy = (0.5 - sy / surround->height_mm) * surround->albedo.height();
  if (!(fx >= 0 && fy >= 0 && fx < surround->albedo.width() && fy < surround->albedo.height())) return false;
  const float a = surround->albedo.at(0, int(fx), int(fy));
  params[diffuse_r] = params[diffuse_g] = params[diffuse_b] = a;
  return true;
}

/// The renderer's configuration of `setup`, in its units (the sample's longest side).
inline capture_image photo_configuration(const photo_setup& setup, double longest_mm) {
  const Eigen::Vector3d centre = setup.pose.camera_centre();
  capture_image config;
  config.camera = {float(centre.x() / longest_mm), float(centre.y() / longest_mm), float(centre.z() / longest_mm)};
  config.light = {float(setup.light_mm.x() / longest_mm), float(setup.light_mm.y() / longest_mm), float(setup.light_mm.z() / longest_mm)};
  config.intensity = setup.intensity;
  return config;
}

/// Adds `weight` times the radiance of each pixel that is `on_sample` into photo: the renderer's
/// texel kernel evaluated on the pixels' parameters `hit` at their points (px, py) of the plane.
template <class Configuration>
void add_shaded_pixels(const material_maps& hit, const aligned_buffer<float>& px, const aligned_buffer<float>& py,
                       const std::vector<std::uint8_t>& on_sample, const Configuration& configuration, float weight, image& photo) {
  using V = simd::batch<float>;
  constexpr std::size_t L = simd::lanes_v<V>;
  const float inv_pi = 1.0f / std::numbers::pi_v<float>;
  const std::size_t blocks = (photo.pixel_count() + L - 1) / L;
#pragma omp parallel for schedule(static)
  for (std::ptrdiff_t b = 0; b < std::ptrdiff_t(blocks); ++b) {
    const std::size_t i = std::size_t(b) * L;
    detail::texel_state<all_features, V, 0> t;
    t.load(hit, i, simd::load<V>(px.data() + i), simd::load<V>(py.data() + i));
    const auto s = detail::shade<all_features, V, 0>(t, configuration, -1e31f);
    alignas(simd::alignment) float values[L];
    for (int c = 0; c < 3; ++c) {
      const V radiance = (t.diffuse[c] * V(inv_pi) + t.specular[c] * s.lobe) * s.geometry.value * V(configuration.intensity[c]);
      simd::store<V>(values, radiance);
      for (std::size_t l = 0; l < L && i + l < photo.pixel_count(); ++l)
        if (on_sample[i + l]) photo.plane(c)[i + l] += weight * values[l];
    }
  }
}

}  // namespace photo_synthesis_detail

/// Renders the linear photograph (width x height, 3 channels, in the renderer's radiance units)
/// of a sample carrying `maps` whose longest side is `longest_mm`, with `samples_per_axis`^2
/// samples per pixel (box filter), reading the maps by `lookup`. Pixels that miss the sample see
/// `surround` where it lies (a matte print), else black.
inline image render_photograph(const material_maps& maps, double longest_mm, const photo_setup& setup, int width, int height,
                               int samples_per_axis = 2, texture_lookup lookup = texture_lookup::bilinear,
                               const printed_surround* surround = nullptr) {
  if (width < 1 || height < 1 || samples_per_axis < 1) throw std::invalid_argument("render_photograph: sizes must be positive");
  const Eigen::Matrix3d k_inverse = setup.camera.matrix().inverse();
  const Eigen::Vector3d centre = setup.pose.camera_centre();
  capture one;
  one.images.push_back(photo_synthesis_detail::photo_configuration(setup, longest_mm));
  const auto configuration = detail::to_constants(one)[0];
  image photo(width, height, 3);
  for (int c = 0; c < 3; ++c) std::fill_n(photo.plane(c), photo.pixel_count(), 0.0f);
  // One pass per sub-pixel offset: the pixels' interpolated parameters form a map set of the
  // photo's size, evaluated by the renderer's texel kernel at the hit points.
  material_maps hit(width, height);
  aligned_buffer<float> px(hit.plane_stride()), py(hit.plane_stride());
  std::vector<std::uint8_t> on_sample(photo.pixel_count());
  const float weight = 1.0f / float(samples_per_axis * samples_per_axis);
  for (int sj = 0; sj < samples_per_axis; ++sj)
    for (int si = 0; si < samples_per_axis; ++si) {
#pragma omp parallel for schedule(static)
      for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
          const std::size_t i = std::size_t(y) * width + x;
          // Pixel centres at integers: the pixel spans [x - 0.5, x + 0.5).
          const Eigen::Vector3d ray = setup.pose.rotation.transpose() *
                                      (k_inverse * Eigen::Vector3d(x - 0.5 + (si + 0.5) / samples_per_axis,
                                                                    y - 0.5 + (sj + 0.5) / samples_per_axis, 1.0));
          float params[parameter_count] = {0, 0, 0, 0, 0, 0, 0.1f, 0.1f, 1, 0, 0, 0};
          bool hits = false;
          double sx = 0, sy = 0;
          if (ray.z() < 0) {
            const double s = -centre.z() / ray.z();
            sx = centre.x() + s * ray.x();
            sy = centre.y() + s * ray.y();
            hits = photo_synthesis_detail::parameters_at(maps, longest_mm, sx, sy, lookup, surround, params);
          }
          on_sample[i] = hits;
          for (int k = 0; k < parameter_count; ++k) hit.plane(k)[i] = params[k];
          px[i] = float(sx / longest_mm);
          py[i] = float(sy / longest_mm);
        }
      photo_synthesis_detail::add_shaded_pixels(hit, px, py, on_sample, configuration, weight, photo);
    }
  return photo;
}

/// How photograph_capture stores its photographs.
enum class photo_format {
  jpeg,       ///< 8-bit sRGB JPEG (photo_NN.jpg), clipped to [0, 1]: what a phone writes
  png,        ///< 8-bit sRGB PNG (photo_NN.png), clipped to [0, 1]: the JPEG's quantisation without its compression
  linear_exr  ///< linear float EXR (photo_NN.exr), clipped to [0, 1] but not quantised: a RAW developed linearly; rectify with --saturation 1
};

/// Options of photograph_capture.
struct photo_synthesis_options {
  int width = 800, height = 600;       ///< photo size in pixels
  int samples_per_axis = 2;            ///< supersampling per pixel and axis
  texture_lookup lookup = texture_lookup::bilinear;  ///< how the maps are read between texel centres
  double longest_mm = 100;             ///< the sample's longest side in mm
  double fill = 0.9;                   ///< the sample's image spans at most this fraction of the frame (sets each photo's focal length)
  double white_fraction = 0.99;        ///< exposure: this fraction of the sample's pixels stays below white (the rest clips)
  bool flash = false;                  ///< light fixed to the camera at flash_offset_mm instead of the configuration's light
  std::array<double, 3> flash_offset_mm{0, 0, 0};  ///< flash offset in camera coordinates (x right, y down, z forward)
  /// Empty: `flash` holds for every photograph. Else one entry per configuration: whether that
  /// photograph's light is the flash (1) or the configuration's light (0), as when a plan's lamp
  /// photographs (pipeline/plan_io.hpp) are added to flash ones.
  std::vector<std::uint8_t> flash_per_photo;
  sensor_noise noise;                  ///< sensor noise on the exposed linear values, before clipping
  std::uint64_t seed = 1;              ///< noise seed
  photo_format format = photo_format::jpeg;  ///< how the photographs are stored
  int jpeg_quality = 95;               ///< JPEG quality (1-100)
  std::shared_ptr<const printed_surround> surround;  ///< a print around the sample (e.g. the marker frame), or none
};

/// Synthetic photographs of one material with their description.
struct synthetic_photographs {
  photos_description description;          ///< photos.json (files photo_NN.jpg, exact corners)
  std::vector<std::vector<unsigned char>> encoded;  ///< the encoded photographs (options.format)
  std::vector<photo_setup> setups;         ///< the true camera, pose and light of each photo
  std::vector<double> exposures;           ///< each photo's exposure factor (pixel = exposure x radiance)
  capture texture_capture;                 ///< the same configurations for the texture-space renderer (flash: light at the flash)
};

/// The camera pose of a capture configuration: at `camera` (capture units) times longest_mm, aimed
/// at the sample's centre, the image's up towards +z (or +y when looking nearly straight down).
inline planar_pose configuration_pose(const vec3f& camera, double longest_mm) {
  const Eigen::Vector3d c = Eigen::Vector3d(camera[0], camera[1], camera[2]) * longest_mm;
  const Eigen::Vector3d forward = (-c).normalized();
  const Eigen::Vector3d up = std::abs(forward.z()) > 0.95 ? Eigen::Vector3d(0, 1, 0) : Eigen::Vector3d(0, 0, 1);
  return look_at(c, Eigen::Vector3d::Zero(), up);
}

namespace photo_synthesis_detail {

/// The focal length (pixels) that fits every corner of the sample into `fill` of a width x height
/// frame seen from `pose`; throws std::invalid_argument naming configuration `index` when the
/// sample is behind the camera.
inline double framing_focal_length(const planar_pose& pose, const std::array<Eigen::Vector3d, 4>& corners, const photo_synthesis_options& o,
                                   std::size_t index) {
  double focal = 1e30;
  for (const auto& p : corners) {
    const Eigen::Vector3d q = pose.rotation * p + pose.translation;
    if (!(q.z() > 0)) throw std::invalid_argument("photograph: configuration " + std::to_string(index) + " has the sample behind the camera");
    const double ax = std::abs(q.x() / q.z()), ay = std::abs(q.y() / q.z());
    if (ax > 0) focal = std::min(focal, o.fill * 0.5 * o.width / ax);
    if (ay > 0) focal = std::min(focal, o.fill * 0.5 * o.height / ay);
  }
  return focal;
}

/// The exposure that maps the white_fraction quantile of the photo's brightest channel (over the
/// pixels that see anything) to 1; 1 for a black photo.
inline double photo_exposure(const image& photo, double white_fraction) {
  std::vector<float> values;
  for (std::size_t k = 0; k < photo.pixel_count(); ++k) {
    const float v = std::max({photo.plane(0)[k], photo.plane(1)[k], photo.plane(2)[k]});
    if (v > 0) values.push_back(v);
  }
  if (values.empty()) return 1;
  const std::size_t q = std::min(values.size() - 1, std::size_t(white_fraction * double(values.size())));
  std::nth_element(values.begin(), values.begin() + std::ptrdiff_t(q), values.end());
  return values[q] > 0 ? 1.0 / values[q] : 1.0;
}

/// The file bytes of an exposed linear photo in o.format: linear EXR clipped at 1, or 8-bit sRGB
/// JPEG or PNG clipped to [0, 1]. `name` names it in errors.
inline std::vector<unsigned char> encode_photo(image photo, const photo_synthesis_options& o, const std::string& name) {
  if (o.format == photo_format::linear_exr) {
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < photo.pixel_count(); ++k) photo.plane(c)[k] = std::min(photo.plane(c)[k], 1.0f);
    return detail::encode_exr(photo, name);
  }
  std::vector<unsigned char> pixels(photo.pixel_count() * 3), bytes;
  for (std::size_t k = 0; k < photo.pixel_count(); ++k)
    for (int c = 0; c < 3; ++c)
      pixels[k * 3 + std::size_t(c)] =
          static_cast<unsigned char>(std::lround(255.0 * linear_to_srgb(std::clamp(double(photo.plane(c)[k]), 0.0, 1.0))));
  auto append = [](void* context, void* data, int size) {
    auto* b = static_cast<std::vector<unsigned char>*>(context);
    b->insert(b->end(), static_cast<unsigned char*>(data), static_cast<unsigned char*>(data) + size);
  };
  const bool written = o.format == photo_format::jpeg
                           ? stbi_write_jpg_to_func(append, &bytes, photo.width(), photo.height(), 3, pixels.data(), o.jpeg_quality)
                           : stbi_write_png_to_func(append, &bytes, photo.width(), photo.height(), 3, pixels.data(), photo.width() * 3);
  if (!written) throw std::runtime_error("photograph: image encoding failed");
  return bytes;
}

}  // namespace photo_synthesis_detail

/// Photographs `maps` from every configuration of `configurations` (capture units, e.g. set_alpha)
/// with a pinhole camera whose focal length frames the sample (options.fill); see the file comment.
inline synthetic_photographs photograph_capture(const material_maps& maps, const capture& configurations,
                                                const photo_synthesis_options& o) {
  using namespace photo_synthesis_detail;
  if (o.width < 2 || o.height < 2) throw std::invalid_argument("photograph: photo size must be at least 2 x 2");
  if (!(o.fill > 0 && o.fill <= 1)) throw std::invalid_argument("photograph: fill must be in (0, 1]");
  if (!(o.white_fraction > 0 && o.white_fraction <= 1)) throw std::invalid_argument("photograph: white fraction must be in (0, 1]");
  if (o.jpeg_quality < 1 || o.jpeg_quality > 100) throw std::invalid_argument("photograph: JPEG quality must be in 1..100");
  o.noise.validate();
  if (!o.flash_per_photo.empty() && o.flash_per_photo.size() != configurations.images.size())
    throw std::invalid_argument("photograph: " + std::to_string(o.flash_per_photo.size()) + " flash settings for " +
                                std::to_string(configurations.images.size()) + " configurations");
  const double n = std::max(maps.width(), maps.height());
  synthetic_photographs out;
  out.description.width_mm = maps.width() / n * o.longest_mm;
  out.description.height_mm = maps.height() / n * o.longest_mm;
  out.description.camera.focal_length_px = 1000.0;  // each photo carries its own (a zoom), see below
  const auto corners = sample_corners(out.description.width_mm, out.description.height_mm);
  for (std::size_t i = 0; i < configurations.images.size(); ++i) {
    const capture_image& config = configurations.images[i];
    photo_setup setup;
    setup.pose = configuration_pose(config.camera, o.longest_mm);
    setup.camera.principal_point = {0.5 * (o.width - 1), 0.5 * (o.height - 1)};
    setup.camera.focal_length = framing_focal_length(setup.pose, corners, o, i);
    capture_image texture_config = config;
    photo_entry entry;
    char name[32];
    const char* extension = o.format == photo_format::jpeg ? "jpg" : o.format == photo_format::png ? "png" : "exr";
    std::snprintf(name, sizeof name, "photo_%02zu.%s", i, extension);
    entry.file = name;
    if (o.flash_per_photo.empty() ? o.flash : o.flash_per_photo[i] != 0) {
      const auto& f = o.flash_offset_mm;
      setup.light_mm = setup.pose.to_sample(Eigen::Vector3d(f[0], f[1], f[2]));
      const double d = setup.light_mm.norm() / o.longest_mm;  // the flash aims at the centre: pi d^2 as configurations do
      const float intensity = float(std::numbers::pi * d * d);
      setup.intensity = {intensity, intensity, intensity};
      texture_config.light = {float(setup.light_mm.x() / o.longest_mm), float(setup.light_mm.y() / o.longest_mm),
                              float(setup.light_mm.z() / o.longest_mm)};
      texture_config.intensity = setup.intensity;
      entry.light.flash_offset_mm = f;
    } else {
      setup.light_mm = Eigen::Vector3d(config.light[0], config.light[1], config.light[2]) * o.longest_mm;
      setup.intensity = config.intensity;
      entry.light.position_mm = {setup.light_mm.x(), setup.light_mm.y(), setup.light_mm.z()};
    }
    image photo = render_photograph(maps, o.longest_mm, setup, o.width, o.height, o.samples_per_axis, o.lookup, o.surround.get());
    const double exposure = photo_exposure(photo, o.white_fraction);
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < photo.pixel_count(); ++k) photo.plane(c)[k] *= float(exposure);
    add_sensor_noise(photo, o.noise, hash64(o.seed + 0x70686f746fULL * (i + 1)));
    corner_pixels c;
    for (int k = 0; k < 4; ++k) c[std::size_t(k)] = project(setup.camera, setup.pose, corners[std::size_t(k)]);
    entry.corners = c;
    const float scaled = float(exposure);
    entry.intensity = {setup.intensity[0] * scaled, setup.intensity[1] * scaled, setup.intensity[2] * scaled};
    camera_description camera;
    camera.focal_length_px = setup.camera.focal_length;
    entry.camera = camera;
    texture_config.file = config.file;
    out.description.photos.push_back(entry);
    out.encoded.push_back(encode_photo(std::move(photo), o, entry.file));
    out.setups.push_back(setup);
    out.exposures.push_back(exposure);
    out.texture_capture.images.push_back(texture_config);
  }
  return out;
}

/// Writes the photographs and photos.json into `out` (created if needed), all or nothing.
inline void write_synthetic_photographs(const synthetic_photographs& s, const std::filesystem::path& out) {
  std::filesystem::create_directories(out);
  file_transaction files;
  for (std::size_t i = 0; i < s.encoded.size(); ++i) files.stage(out / s.description.photos[i].file, s.encoded[i].data(), s.encoded[i].size());
  files.stage(out / "photos.json", photos_description_to_json(s.description));
  files.commit();
}

}  // namespace anisocap
