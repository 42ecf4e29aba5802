#pragma once
/// @file
/// Photographs for the image loss: any input format of data/image_io.hpp read as linear radiance,
/// an optional exposure factor, and a mask of the pixels the loss may use.
///
/// A clipped pixel (the sensor or the encoder saturated) no longer measures the radiance, so fitting
/// it pulls the specular lobes towards a flat top. Such pixels are found on reading, counted, and
/// masked out of the loss (render/renderer.hpp, loss_targets): a pixel is clipped when any colour
/// channel holds the format's largest code (255 in 8-bit PNG and JPEG, 65535 in 16-bit PNG) or,
/// when a saturation level is given, reaches that level in the file's own linear values (before the
/// exposure factor); linear files (EXR, HDR) have no largest code, so only the level finds clipping
/// there. A mask file given by the capture description (zero in every channel: ignore) combines
/// with the clipped pixels: a pixel is used only when both allow it.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/image.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"

namespace anisocap {

/// How photographs are read.
struct photo_options {
  /// Linear level at or above which a pixel counts as clipped in any format, compared with the
  /// file's linear values before `exposure` (0: off; integer formats are still clipped at their
  /// largest code).
  float saturation = 0.0f;
  /// Clipped pixels are left out of the loss (mask 0). False: they are still counted and reported,
  /// but fitted like every other pixel (for comparisons; not recommended).
  bool exclude_clipped = true;
  float exposure = 1.0f;  ///< factor the linear values are multiplied by after decoding
};

/// One photograph ready for the loss.
struct photo {
  image pixels;              ///< 3-channel linear radiance, exposure applied
  image mask;                ///< 1 channel, same size: the pixel's weight in the loss (1 = full, 0 = left out)
  std::size_t clipped = 0;   ///< pixels found clipped (counted whether or not they are excluded)
  std::size_t masked = 0;    ///< pixels with mask 0 (clipped, given mask, or both)
  /// How the file stored the values: lossless (EXR, HDR, 16-bit PNG), as 8-bit codes, or as a JPEG
  /// with its colour at full or lower resolution (capture_image::encoding says what it changes).
  photo_encoding encoding = photo_encoding::lossless;

  /// Share of clipped pixels in [0, 1].
  double clipped_fraction() const { return pixels.empty() ? 0.0 : double(clipped) / double(pixels.pixel_count()); }
  /// Share of pixels left out of the loss in [0, 1].
  double masked_fraction() const { return pixels.empty() ? 0.0 : double(masked) / double(pixels.pixel_count()); }
};

namespace detail {

/// Number of zeros in a 1-channel mask.
inline std::size_t count_masked(const image& mask) {
  std::size_t n = 0;
  for (std::size_t i = 0; i < mask.pixel_count(); ++i) n += mask.plane(0)[i] == 0.0f;
  return n;
}

}  // namespace detail

/// Reads a photograph of any type read_image accepts, checks its pixels (finite, non-negative),
/// finds clipped pixels (see the file comment), applies the exposure factor and builds the mask.
/// Throws io_error naming the file.
inline photo read_photo(const std::filesystem::path& path, const photo_options& options = {}) {
  if (!(std::isfinite(options.exposure) && options.exposure > 0))
    throw io_error(path, "exposure must be a positive finite number (got " + std::to_string(options.exposure) + ")");
  if (!(std::isfinite(options.saturation) && options.saturation >= 0))
    throw io_error(path, "saturation must be a finite number >= 0 (0: off), got " + std::to_string(options.saturation));
  photo p;
  std::vector<std::uint8_t> at_maximum;
  const std::string ext = detail::lower_extension(path);
  if (ext == ".png") p.pixels = detail::read_srgb(path, detail::srgb_format::png, &at_maximum, &p.encoding);
  else if (ext == ".jpg" || ext == ".jpeg") p.pixels = detail::read_srgb(path, detail::srgb_format::jpeg, &at_maximum, &p.encoding);
  else p.pixels = read_image(path);
  validate_pixels(p.pixels, path);
  const std::size_t n = p.pixels.pixel_count();
  p.mask = image(p.pixels.width(), p.pixels.height(), 1);
  for (std::size_t i = 0; i < n; ++i) {
    bool clipped = !at_maximum.empty() && at_maximum[i] != 0;
    if (options.saturation > 0)
      for (int c = 0; c < 3; ++c) clipped = clipped || p.pixels.plane(c)[i] >= options.saturation;
    p.clipped += clipped;
    p.mask.plane(0)[i] = clipped && options.exclude_clipped ? 0.0f : 1.0f;
  }
  p.masked = detail::count_masked(p.mask);
  if (options.exposure != 1.0f)
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < n; ++i) p.pixels.plane(c)[i] *= options.exposure;
  return p;
}

/// Reads a mask image (any type read_image accepts, one channel or RGB) of `width` x `height`: each
/// pixel's weight in the loss, the largest of its channels, read as stored (PNG and JPEG codes over
/// their largest code, not sRGB-decoded: 255 = 1, 128 = 0.5; EXR and HDR values as they are),
/// capped at 1. 0 in every channel = ignore; black and white masks use a pixel fully or not at all.
/// Throws io_error naming the file when it cannot be read, holds NaN or negative values, or
/// differs in size.
inline image read_mask(const std::filesystem::path& path, int width, int height) {
  const image m = read_image(path);
  validate_pixels(m, path);
  if (m.width() != width || m.height() != height)
    throw io_error(path, "the mask is " + std::to_string(m.width()) + "x" + std::to_string(m.height()) + " but its photograph is " +
                             std::to_string(width) + "x" + std::to_string(height));
  const std::string ext = detail::lower_extension(path);
  const bool encoded = ext == ".png" || ext == ".jpg" || ext == ".jpeg";
  image out(width, height, 1);
  for (std::size_t i = 0; i < out.pixel_count(); ++i) {
    const float v = std::max({m.plane(0)[i], m.plane(1)[i], m.plane(2)[i]});
    out.plane(0)[i] = v == 0.0f ? 0.0f : std::min(1.0f, encoded ? float(linear_to_srgb(v)) : v);
  }
  return out;
}

/// Multiplies `p`'s mask by `mask` (1 channel of weights, 0 = ignore): a pixel that either leaves
/// out stays out (for 0/1 masks, AND), and recounts `p.masked`.
inline void combine_mask(photo& p, const image& mask) {
  for (std::size_t i = 0; i < p.mask.pixel_count(); ++i) p.mask.plane(0)[i] *= mask.plane(0)[i];
  p.masked = detail::count_masked(p.mask);
}

/// Loads a capture's photographs, file and mask names taken relative to `capture_dir` (the folder
/// of capture.json): each through read_photo with the image's own exposure factor (times
/// `options.exposure`), its mask file combined when given. Errors name the file and the image
/// index: unreadable or bad pixels, a size that differs from image 0's, a mask of another size,
/// and a photograph whose every pixel is left out of the loss.
inline std::vector<photo> load_capture_photos(const capture& c, const std::filesystem::path& capture_dir,
                                              const photo_options& options = {}) {
  detail::check_capture(c, capture_dir / "capture.json");
  std::vector<photo> photos;
  photos.reserve(c.images.size());
  for (std::size_t i = 0; i < c.images.size(); ++i) {
    const capture_image& entry = c.images[i];
    const std::filesystem::path file = capture_dir / entry.file;
    const std::string which = " (capture image " + std::to_string(i) + ")";
    photo_options o = options;
    o.exposure = options.exposure * entry.exposure;
    photo p;
    try {
      p = read_photo(file, o);
      if (!entry.mask.empty()) combine_mask(p, read_mask(capture_dir / entry.mask, p.pixels.width(), p.pixels.height()));
    } catch (const io_error& e) {
      throw io_error(e.path(), e.problem() + which);
    }
    if (!photos.empty() && (p.pixels.width() != photos[0].pixels.width() || p.pixels.height() != photos[0].pixels.height()))
      throw io_error(file, "image " + std::to_string(i) + " is " + std::to_string(p.pixels.width()) + "x" +
                               std::to_string(p.pixels.height()) + " but image 0 (" + c.images[0].file + ") is " +
                               std::to_string(photos[0].pixels.width()) + "x" + std::to_string(photos[0].pixels.height()) +
                               "; all capture images must have the same size");
    if (p.masked == p.pixels.pixel_count())
      throw io_error(entry.mask.empty() ? file : capture_dir / entry.mask,
                     "every pixel of " + entry.file + " is clipped or masked; nothing of this photograph is left for the loss" + which);
    photos.push_back(std::move(p));
  }
  return photos;
}

/// The capture's photographs alone (load_capture_photos with clipping not excluded and masks
/// ignored): 3-channel linear images, exposure applied, pixels and sizes checked.
inline std::vector<image> load_capture_images(const capture& c, const std::filesystem::path& capture_dir) {
  capture plain = c;
  for (auto& im : plain.images) im.mask.clear();
  photo_options o;
  o.exclude_clipped = false;
  std::vector<image> images;
  for (photo& p : load_capture_photos(plain, capture_dir, o)) images.push_back(std::move(p.pixels));
  return images;
}

/// Sets each image's encoding in `c` from its photograph's file (one photograph per image, as
/// load_capture_photos returns them), keeping the description's where it names a lossier one (a
/// rectified photograph stored losslessly from a JPEG).
inline void set_photo_encodings(capture& c, const std::vector<photo>& photos) {
  if (photos.size() != c.images.size()) throw std::invalid_argument("set_photo_encodings: one photograph per image of the capture");
  for (std::size_t i = 0; i < photos.size(); ++i) c.images[i].encoding = std::max(c.images[i].encoding, photos[i].encoding);
}

/// The pixels of each photograph (for the estimator and first guesses).
inline std::vector<image> photo_pixels(const std::vector<photo>& photos) {
  std::vector<image> out;
  out.reserve(photos.size());
  for (const photo& p : photos) out.push_back(p.pixels);
  return out;
}

/// The loss mask of each photograph (for make_loss_targets).
inline std::vector<image> photo_masks(const std::vector<photo>& photos) {
  std::vector<image> out;
  out.reserve(photos.size());
  for (const photo& p : photos) out.push_back(p.mask);
  return out;
}

/// A capture description (capture.json) with its photographs loaded as a capture reads them.
struct capture_photographs {
  capture description;
  std::vector<photo> photos;  ///< one per configuration: pixels (exposure applied), mask, clipped counts
  /// The photographs' pixels (photo_pixels).
  std::vector<image> pixels() const { return photo_pixels(photos); }
  /// Their masks: the weight of each pixel in the loss (photo_masks).
  std::vector<image> masks() const { return photo_masks(photos); }
};

/// Reads `capture_file` (read_capture) and loads its photographs and masks relative to its folder
/// (load_capture_photos with `options`), and sets each image's encoding from its file
/// (set_photo_encodings). Throws io_error naming the file and the problem.
inline capture_photographs read_capture_photographs(const std::filesystem::path& capture_file, const photo_options& options = {}) {
  capture_photographs c;
  c.description = read_capture(capture_file);
  c.photos = load_capture_photos(c.description, capture_file.parent_path(), options);
  set_photo_encodings(c.description, c.photos);
  return c;
}

}  // namespace anisocap
