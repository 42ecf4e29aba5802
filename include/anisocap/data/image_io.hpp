#pragma once
/// @file
/// Image files: linear OpenEXR and Radiance HDR, sRGB PNG and JPEG in; float32 EXR and 8-bit sRGB
/// PNG previews out. Inputs are photographs of the material in texture space (docs/method.md section 4), so the
/// loss of docs/method.md section 5 needs linear radiance: EXR and HDR are taken as linear, PNG (8 or 16 bit) and
/// JPEG as sRGB and linearised with the exact sRGB curve.
///
/// Every write goes to a temporary file beside its target and is renamed over it only once it is
/// complete (`file_transaction`), so a failure never leaves a half-written file under the real
/// name. Every error is an `io_error` whose message starts with the file's path.
#include <tinyexr.h>
#include <stb/stb_image.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <random>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "anisocap/core/files.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/core/photo_encoding.hpp"
#include "anisocap/core/srgb.hpp"

namespace anisocap {

// ---- validation --------------------------------------------------------------------------------

/// Checks that every pixel of `img` is finite and not negative, as radiance must be; throws
/// io_error naming `path`, the first bad pixel (x, y, channel), its value and how many are bad.
inline void validate_pixels(const image& img, const std::filesystem::path& path) {
  std::size_t bad = 0, first_index = img.pixel_count();
  int first_c = 0;
  float first_value = 0;
  for (int c = 0; c < img.channels(); ++c) {
    const float* p = img.plane(c);
    for (std::size_t i = 0; i < img.pixel_count(); ++i) {
      if (!(p[i] >= 0.0f) || std::isinf(p[i])) {  // NaN fails the comparison
        ++bad;
        if (i < first_index) first_index = i, first_c = c, first_value = p[i];  // first in reading order
      }
    }
  }
  if (bad == 0) return;
  const int first_x = int(first_index % std::size_t(img.width())), first_y = int(first_index / std::size_t(img.width()));
  static constexpr const char* channel_names[] = {"R", "G", "B"};
  const std::string channel = img.channels() == 3 ? channel_names[first_c] : std::to_string(first_c);
  const char* what = std::isnan(first_value) ? "NaN" : std::isinf(first_value) ? "infinite" : "negative";
  char value[64];
  std::snprintf(value, sizeof value, "%g", double(first_value));
  std::string message = "pixel (x=" + std::to_string(first_x) + ", y=" + std::to_string(first_y) + ") channel " +
                        channel + " is " + what + " (" + value + "); images must hold finite, non-negative radiance";
  if (bad > 1) message += " (" + std::to_string(bad) + " bad values in all)";
  throw io_error(path, message);
}

// ---- EXR ---------------------------------------------------------------------------------------

namespace detail {

/// Owns tinyexr's header, image and error string for one call.
struct exr_resources {
  EXRHeader header;
  EXRImage image;
  bool header_loaded = false, image_loaded = false;
  const char* error = nullptr;
  exr_resources() {
    InitEXRHeader(&header);
    InitEXRImage(&image);
  }
  ~exr_resources() {
    if (image_loaded) FreeEXRImage(&image);
    if (header_loaded) FreeEXRHeader(&header);
    if (error) FreeEXRErrorMessage(error);
  }
  exr_resources(const exr_resources&) = delete;
  exr_resources& operator=(const exr_resources&) = delete;
  /// tinyexr's message, or a generic one.
  std::string message(const char* what) const {
    return std::string(what) + (error ? std::string(": ") + error : std::string());
  }
};

/// Encodes planes (each width*height floats, row-major) as an EXR file in memory, ZIP-compressed,
/// with the given channel names (OpenEXR readers expect alphabetical order, e.g. B, G, R) and
/// float32 or half storage. Used by write_exr, and by tests to make half/one-channel inputs.
inline std::vector<unsigned char> encode_exr(const float* const* planes, const char* const* names, int channels,
                                             int width, int height, bool half, const std::filesystem::path& path) {
  EXRHeader header;
  InitEXRHeader(&header);
  EXRImage exr;
  InitEXRImage(&exr);
  std::vector<EXRChannelInfo> info(static_cast<std::size_t>(channels));
  std::vector<int> pixel_types(std::size_t(channels), TINYEXR_PIXELTYPE_FLOAT);
  std::vector<int> requested(std::size_t(channels), half ? TINYEXR_PIXELTYPE_HALF : TINYEXR_PIXELTYPE_FLOAT);
  for (int c = 0; c < channels; ++c) {
    std::memset(&info[std::size_t(c)], 0, sizeof(EXRChannelInfo));
    std::snprintf(info[std::size_t(c)].name, sizeof info[std::size_t(c)].name, "%s", names[c]);
  }
  header.num_channels = channels;
  header.channels = info.data();
  header.pixel_types = pixel_types.data();
  header.requested_pixel_types = requested.data();
  header.compression_type = TINYEXR_COMPRESSIONTYPE_ZIP;
  exr.num_channels = channels;
  exr.width = width;
  exr.height = height;
  exr.images = reinterpret_cast<unsigned char**>(const_cast<float**>(planes));
  unsigned char* memory = nullptr;
  const char* error = nullptr;
  const std::size_t size = SaveEXRImageToMemory(&exr, &header, &memory, &error);
  if (size == 0) {
    std::string message = "cannot encode EXR";
    if (error) {
      message += std::string(": ") + error;
      FreeEXRErrorMessage(error);
    }
    std::free(memory);
    throw io_error(path, message);
  }
  std::vector<unsigned char> bytes(memory, memory + size);
  std::free(memory);
  return bytes;
}

/// Lower-case extension of a path, with the dot (".exr").
inline std::string lower_extension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace detail

/// Reads a linear OpenEXR file (scanline or tiled, single part, half or float channels) into a
/// 3-channel image: R, G, B by name (A and other channels ignored); a file with one channel (Y, R
/// or any name) or with Y but no R, G, B is replicated into all three. Throws io_error naming the
/// file when it is missing, corrupt, deep or multi-part, subsampled, or has no usable channels.
inline image read_exr(const std::filesystem::path& path) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  EXRVersion version;
  if (ParseEXRVersionFromMemory(&version, bytes.data(), bytes.size()) != TINYEXR_SUCCESS)
    throw io_error(path, "not an OpenEXR file (bad magic number or truncated)");
  if (version.multipart) throw io_error(path, "multi-part EXR files are not supported; save one part");
  if (version.non_image) throw io_error(path, "deep EXR files are not supported");
  detail::exr_resources r;
  const int header_status = ParseEXRHeaderFromMemory(&r.header, &version, bytes.data(), bytes.size(), &r.error);
  r.header_loaded = true;  // tinyexr fills the header even when parsing fails: free it either way
  if (header_status != TINYEXR_SUCCESS) throw io_error(path, r.message("corrupt EXR header"));
  const int n = r.header.num_channels;
  for (int c = 0; c < n; ++c) {
    const EXRChannelInfo& ch = r.header.channels[c];
    if (r.header.pixel_types[c] == TINYEXR_PIXELTYPE_UINT)
      throw io_error(path, std::string("channel ") + ch.name + " holds unsigned integers; expected half or float radiance");
    if (ch.x_sampling != 1 || ch.y_sampling != 1)
      throw io_error(path, std::string("channel ") + ch.name + " is subsampled; only full-resolution channels are supported");
    r.header.requested_pixel_types[c] = TINYEXR_PIXELTYPE_FLOAT;  // half -> float on load
  }
  if (LoadEXRImageFromMemory(&r.image, &r.header, bytes.data(), bytes.size(), &r.error) != TINYEXR_SUCCESS)
    throw io_error(path, r.message("corrupt or truncated EXR data"));
  r.image_loaded = true;

  int source[3] = {-1, -1, -1};
  auto find = [&](const char* name) {
    for (int c = 0; c < n; ++c) if (std::strcmp(r.header.channels[c].name, name) == 0) return c;
    return -1;
  };
  source[0] = find("R"), source[1] = find("G"), source[2] = find("B");
  if (source[0] < 0 || source[1] < 0 || source[2] < 0) {
    const int y = find("Y");
    const int single = n == 1 ? 0 : y;
    if (single < 0) {
      std::string names;
      for (int c = 0; c < n; ++c) names += std::string(c ? ", " : "") + r.header.channels[c].name;
      throw io_error(path, "expected channels R, G, B (or one channel, or Y), found: " + names);
    }
    source[0] = source[1] = source[2] = single;
  }
  const int width = r.image.width, height = r.image.height;
  if (width <= 0 || height <= 0) throw io_error(path, "empty EXR image");
  image out(width, height, 3);
  if (!r.header.tiled) {
    for (int c = 0; c < 3; ++c) {
      const float* src = reinterpret_cast<const float*>(r.image.images[source[c]]);
      std::copy(src, src + out.pixel_count(), out.plane(c));
    }
  } else {
    // Level 0 tiles: tile (offset_x, offset_y) covers tile_size pixels from offset * tile_size.
    const int tx = r.header.tile_size_x, ty = r.header.tile_size_y;
    for (int t = 0; t < r.image.num_tiles; ++t) {
      const EXRTile& tile = r.image.tiles[t];
      for (int c = 0; c < 3; ++c) {
        const float* src = reinterpret_cast<const float*>(tile.images[source[c]]);
        for (int j = 0; j < ty; ++j) {
          const int y = tile.offset_y * ty + j;
          if (y >= height) break;
          for (int i = 0; i < tx; ++i) {
            const int x = tile.offset_x * tx + i;
            if (x >= width) break;
            out.at(c, x, y) = src[j * tx + i];
          }
        }
      }
    }
  }
  return out;
}

namespace detail {
/// A 1- or 3-channel image as float32, ZIP-compressed EXR bytes (channels Y, or B G R); io_error
/// naming `path` for other channel counts.
inline std::vector<unsigned char> encode_exr(const image& img, const std::filesystem::path& path) {
  if (img.empty()) throw io_error(path, "cannot write an empty image");
  if (img.channels() == 3) {
    const float* planes[3] = {img.plane(2), img.plane(1), img.plane(0)};
    const char* names[3] = {"B", "G", "R"};
    return encode_exr(planes, names, 3, img.width(), img.height(), false, path);
  }
  if (img.channels() == 1) {
    const float* planes[1] = {img.plane(0)};
    const char* names[1] = {"Y"};
    return encode_exr(planes, names, 1, img.width(), img.height(), false, path);
  }
  throw io_error(path, "EXR output takes 1 or 3 channels, the image has " + std::to_string(img.channels()));
}
}  // namespace detail

/// Writes a 1- or 3-channel image as a float32, ZIP-compressed EXR (channels Y, or B G R),
/// atomically. Values are written as they are (validate first where that matters).
inline void write_exr(const image& img, const std::filesystem::path& path, file_transaction& transaction) {
  const auto bytes = detail::encode_exr(img, path);
  transaction.stage(path, bytes.data(), bytes.size());
}

/// Writes a 1- or 3-channel image as a float32 EXR, atomically (see the transaction overload).
inline void write_exr(const image& img, const std::filesystem::path& path) {
  file_transaction t;
  write_exr(img, path, t);
  t.commit();
}

// ---- PNG ---------------------------------------------------------------------------------------

/// How a PNG preview maps values to 8-bit codes.
enum class png_encoding {
  srgb,    ///< colours (radiance, albedo): clamp to [0,1], sRGB-encode (what displays expect)
  linear,  ///< data (lobe widths, mapped normals): clamp to [0,1], store as is, so a code reads as the value
};

/// Whether the JPEG in `bytes` stores its colour at a lower resolution than its brightness (chroma
/// subsampling: 4:2:0, 4:2:2, 4:1:1), read from its frame header: some component is sampled less
/// often than the most finely sampled one in either direction. False for a grey JPEG, for colour at
/// full resolution (4:4:4), and for bytes that are not a JPEG or end before the frame header.
/// Encoders choose it by quality: stb_image_write subsamples at quality 90 and below, phones
/// usually do at every quality.
inline bool jpeg_colour_subsampled(std::span<const unsigned char> bytes) {
  if (bytes.size() < 4 || bytes[0] != 0xFF || bytes[1] != 0xD8) return false;
  std::size_t at = 2;
  while (at + 4 <= bytes.size()) {
    if (bytes[at] != 0xFF) return false;  // not at a marker: damaged
    const unsigned char marker = bytes[at + 1];
    if (marker == 0xFF) {  // a fill byte before the marker
      ++at;
      continue;
    }
    at += 2;
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD7)) continue;  // markers without a length
    if (marker == 0xD9 || marker == 0xDA) return false;                   // the end, or the scan, before any frame header
    const std::size_t length = std::size_t(bytes[at]) << 8 | bytes[at + 1];
    if (length < 2 || at + length > bytes.size()) return false;
    // SOF0-SOF15 are frame headers, except DHT (C4), JPG (C8) and DAC (CC).
    if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
      // length (2), precision (1), height (2), width (2), component count (1), then per component
      // its id, its sampling factors (horizontal << 4 | vertical) and its table.
      const std::size_t count = length >= 8 ? bytes[at + 7] : 0;
      if (count < 3 || length < 8 + 3 * count) return false;
      int most_h = 0, most_v = 0;
      for (std::size_t c = 0; c < count; ++c) {
        const unsigned char factors = bytes[at + 8 + 3 * c + 1];
        most_h = std::max(most_h, factors >> 4);
        most_v = std::max(most_v, factors & 15);
      }
      for (std::size_t c = 0; c < count; ++c) {
        const unsigned char factors = bytes[at + 8 + 3 * c + 1];
        if ((factors >> 4) < most_h || (factors & 15) < most_v) return true;
      }
      return false;
    }
    at += length;
  }
  return false;
}

namespace detail {

/// Integer-coded, sRGB-encoded file formats.
enum class srgb_format { png, jpeg };

/// Reads an sRGB-encoded PNG (8 or 16 bit) or JPEG (8 bit; grey, grey+alpha, RGB or RGBA; alpha
/// ignored, grey replicated), linearised exactly, into a 3-channel image. When `at_maximum` is not
/// null it receives one entry per pixel: 1 where any colour channel holds the format's largest code
/// (255, or 65535 for 16-bit PNG), i.e. where the sensor or the encoder clipped, else 0. When
/// `encoding` is not null it receives how the file stored the values: eight_bit or lossless (16
/// bits) for a PNG, jpeg or jpeg_subsampled (jpeg_colour_subsampled) for a JPEG.
inline image read_srgb(const std::filesystem::path& path, srgb_format format, std::vector<std::uint8_t>* at_maximum,
                       photo_encoding* encoding = nullptr) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  const char* name = format == srgb_format::png ? "PNG" : "JPEG";
  static constexpr unsigned char png_signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  static constexpr unsigned char jpeg_signature[3] = {0xFF, 0xD8, 0xFF};
  if (format == srgb_format::png && (bytes.size() < 8 || std::memcmp(bytes.data(), png_signature, 8) != 0))
    throw io_error(path, "not a PNG file (bad signature)");
  if (format == srgb_format::jpeg && (bytes.size() < 3 || std::memcmp(bytes.data(), jpeg_signature, 3) != 0))
    throw io_error(path, "not a JPEG file (bad signature)");
  if (bytes.size() > std::size_t(INT32_MAX)) throw io_error(path, std::string(name) + " file too large");
  const int size = int(bytes.size());
  int width = 0, height = 0, channels = 0;
  const bool sixteen = format == srgb_format::png && stbi_is_16_bit_from_memory(bytes.data(), size) != 0;
  if (encoding)
    *encoding = format == srgb_format::png ? (sixteen ? photo_encoding::lossless : photo_encoding::eight_bit)
                : jpeg_colour_subsampled(bytes) ? photo_encoding::jpeg_subsampled
                                                : photo_encoding::jpeg;
  std::unique_ptr<void, void (*)(void*)> pixels(nullptr, &stbi_image_free);
  if (sixteen) pixels.reset(stbi_load_16_from_memory(bytes.data(), size, &width, &height, &channels, 0));
  else pixels.reset(stbi_load_from_memory(bytes.data(), size, &width, &height, &channels, 0));
  if (!pixels) {
    const char* reason = stbi_failure_reason();
    throw io_error(path, std::string("corrupt ") + name + (reason ? std::string(" (") + reason + ")" : std::string()));
  }
  if (width <= 0 || height <= 0 || channels < 1 || channels > 4) throw io_error(path, std::string("unsupported ") + name + " layout");
  // Exact sRGB decoding through a table of every code (256 or 65536 entries, computed in double).
  const int levels = sixteen ? 65536 : 256;
  std::vector<float> table(static_cast<std::size_t>(levels));
  for (int i = 0; i < levels; ++i) table[std::size_t(i)] = float(srgb_to_linear(double(i) / double(levels - 1)));
  image out(width, height, 3);
  const int colour_channels = channels >= 3 ? 3 : 1;
  const std::size_t count = out.pixel_count();
  if (at_maximum) at_maximum->assign(count, 0);
  auto decode = [&](const auto* src) {
    const unsigned top = unsigned(levels - 1);
    for (int c = 0; c < 3; ++c) {
      const int src_c = colour_channels == 3 ? c : 0;
      float* dst = out.plane(c);
      for (std::size_t i = 0; i < count; ++i) {
        const unsigned code = src[i * std::size_t(channels) + std::size_t(src_c)];
        dst[i] = table[code];
        if (at_maximum && code == top) (*at_maximum)[i] = 1;
      }
    }
  };
  if (sixteen) decode(static_cast<const std::uint16_t*>(pixels.get()));
  else decode(static_cast<const std::uint8_t*>(pixels.get()));
  return out;
}

}  // namespace detail

/// Reads an 8- or 16-bit PNG (grey, grey+alpha, RGB or RGBA; alpha ignored, grey replicated),
/// taken as sRGB and linearised exactly, into a 3-channel image. Throws io_error naming the file
/// when it is missing, not a PNG, or corrupt.
inline image read_png(const std::filesystem::path& path) { return detail::read_srgb(path, detail::srgb_format::png, nullptr); }

/// Reads a JPEG (baseline or progressive, 8 bit, grey or RGB), taken as sRGB and linearised
/// exactly, into a 3-channel image. Throws io_error naming the file when it is missing, not a JPEG,
/// or corrupt.
inline image read_jpeg(const std::filesystem::path& path) { return detail::read_srgb(path, detail::srgb_format::jpeg, nullptr); }

/// Reads a Radiance RGBE (.hdr) file, linear radiance, into a 3-channel image. Throws io_error
/// naming the file when it is missing, not a Radiance file, or corrupt.
inline image read_hdr(const std::filesystem::path& path) {
  const std::vector<unsigned char> bytes = read_file_bytes(path);
  if (bytes.size() > std::size_t(INT32_MAX)) throw io_error(path, "Radiance HDR file too large");
  const int size = int(bytes.size());
  // stbi_loadf would also accept an 8-bit file and gamma-expand it; only true HDR files pass here.
  if (!stbi_is_hdr_from_memory(bytes.data(), size)) throw io_error(path, "not a Radiance HDR file (expected a \"#?RADIANCE\" or \"#?RGBE\" header)");
  int width = 0, height = 0, channels = 0;
  std::unique_ptr<float, void (*)(void*)> pixels(stbi_loadf_from_memory(bytes.data(), size, &width, &height, &channels, 3),
                                                 &stbi_image_free);
  if (!pixels) {
    const char* reason = stbi_failure_reason();
    throw io_error(path, std::string("corrupt Radiance HDR file") + (reason ? std::string(" (") + reason + ")" : std::string()));
  }
  if (width <= 0 || height <= 0) throw io_error(path, "empty Radiance HDR image");
  image out(width, height, 3);
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < out.pixel_count(); ++i) out.plane(c)[i] = pixels.get()[i * 3 + std::size_t(c)];
  return out;
}

namespace detail {

/// The 8-bit code of a linear value under a png_encoding: the value clamped to [0, 1] (NaN -> 0),
/// encoded and rounded, computed without a pow per value. Code k covers encoded values
/// [(k - 0.5)/255, (k + 0.5)/255); in linear terms its upper bound is bound[k] (the curve is
/// monotonic), so the code of v is the number of bounds at or below v. A table indexed by v's
/// exponent and leading mantissa bits gives that count at the start of v's bucket, and at most a
/// few steps up the bounds finish it: the same code as rounding the exactly encoded value.
class eight_bit_quantizer {
 public:
  explicit eight_bit_quantizer(png_encoding encoding) {
    for (int k = 0; k < 255; ++k) {
      const double encoded = (k + 0.5) / 255.0;
      bound_[k] = encoding == png_encoding::srgb ? srgb_to_linear(encoded) : encoded;
    }
    bound_[255] = std::numeric_limits<double>::infinity();  // stops the steps at code 255
    // Every bound lies in [lowest, 1): below lowest the code is 0, at 1 and above it is 255.
    for (int b = 0; b < buckets; ++b) {
      const double edge = std::bit_cast<double>(lowest_bits + (std::uint64_t(b) << shift));
      start_[std::size_t(b)] = static_cast<unsigned char>(std::upper_bound(bound_, bound_ + 255, edge) - bound_);
    }
  }
  /// The code of v (already scaled by the exposure).
  unsigned char operator()(double v) const {
    if (!(v >= lowest)) return 0;  // also NaN
    if (v >= 1.0) return 255;
    unsigned code = start_[std::size_t((std::bit_cast<std::uint64_t>(v) - lowest_bits) >> shift)];
    while (bound_[code] <= v) ++code;
    return static_cast<unsigned char>(code);
  }

 private:
  static constexpr double lowest = 0x1p-16;  // below every bound: sRGB's first is 1.5e-4, linear's 2.0e-3
  static constexpr int octaves = 16, bucket_bits = 6;  // [2^-16, 1) in 16 octaves of 64 buckets
  static constexpr int buckets = octaves << bucket_bits, shift = 52 - bucket_bits;
  static constexpr std::uint64_t lowest_bits = std::uint64_t(1023 - octaves) << 52;
  double bound_[256];
  std::array<unsigned char, buckets> start_;
};

}  // namespace detail

/// Encodes a 1- or 3-channel image as an 8-bit PNG in memory: each value is multiplied by
/// 2^exposure_stops, clamped to [0,1] (NaN -> 0), encoded per `encoding`, rounded
/// (detail::eight_bit_quantizer).
inline std::vector<unsigned char> encode_png(const image& img, const std::filesystem::path& path, float exposure_stops = 0.0f,
                                             png_encoding encoding = png_encoding::srgb) {
  if (img.empty()) throw io_error(path, "cannot write an empty image");
  const int channels = img.channels();
  if (channels != 1 && channels != 3)
    throw io_error(path, "PNG preview takes 1 or 3 channels, the image has " + std::to_string(channels));
  const double scale = std::exp2(double(exposure_stops));
  const detail::eight_bit_quantizer quantize(encoding);
  std::vector<unsigned char> pixels(img.pixel_count() * std::size_t(channels));
  for (int c = 0; c < channels; ++c) {
    const float* src = img.plane(c);
    for (std::size_t i = 0; i < img.pixel_count(); ++i) pixels[i * std::size_t(channels) + std::size_t(c)] = quantize(double(src[i]) * scale);
  }
  std::vector<unsigned char> bytes;
  auto append = [](void* context, void* data, int size) {
    auto* out = static_cast<std::vector<unsigned char>*>(context);
    out->insert(out->end(), static_cast<unsigned char*>(data), static_cast<unsigned char*>(data) + size);
  };
  if (!stbi_write_png_to_func(append, &bytes, img.width(), img.height(), channels, pixels.data(), img.width() * channels))
    throw io_error(path, "cannot encode PNG");
  return bytes;
}

/// Writes an 8-bit PNG preview (see encode_png) through `transaction`.
inline void write_png(const image& img, const std::filesystem::path& path, file_transaction& transaction,
                      float exposure_stops = 0.0f, png_encoding encoding = png_encoding::srgb) {
  const auto bytes = encode_png(img, path, exposure_stops, encoding);
  transaction.stage(path, bytes.data(), bytes.size());
}

/// Writes an 8-bit sRGB PNG preview atomically: values scaled by 2^exposure_stops, then clamped.
inline void write_png(const image& img, const std::filesystem::path& path, float exposure_stops = 0.0f,
                      png_encoding encoding = png_encoding::srgb) {
  file_transaction t;
  write_png(img, path, t, exposure_stops, encoding);
  t.commit();
}

// ---- by extension ------------------------------------------------------------------------------

/// The input image types read_image accepts, for messages.
inline constexpr const char* readable_image_types = ".exr and .hdr (linear), .png, .jpg and .jpeg (sRGB)";

/// True when read_image reads files with this path's extension (case-insensitive).
inline bool is_readable_image(const std::filesystem::path& path) {
  const std::string ext = detail::lower_extension(path);
  return ext == ".exr" || ext == ".hdr" || ext == ".png" || ext == ".jpg" || ext == ".jpeg";
}

/// Reads an input image by extension into 3 linear channels: .exr and .hdr as linear, .png, .jpg
/// and .jpeg as sRGB (case-insensitive). Does not validate pixel values (see validate_pixels).
inline image read_image(const std::filesystem::path& path) {
  const std::string ext = detail::lower_extension(path);
  if (ext == ".exr") return read_exr(path);
  if (ext == ".hdr") return read_hdr(path);
  if (ext == ".png") return read_png(path);
  if (ext == ".jpg" || ext == ".jpeg") return read_jpeg(path);
  throw io_error(path, "unknown image type '" + path.extension().string() + "' (supported: " + readable_image_types + ")");
}

/// Writes by extension: .exr as float32 EXR, .png as an 8-bit sRGB preview; atomically.
inline void write_image(const image& img, const std::filesystem::path& path) {
  const std::string ext = detail::lower_extension(path);
  if (ext == ".exr") return write_exr(img, path);
  if (ext == ".png") return write_png(img, path);
  throw io_error(path, "unknown image type '" + path.extension().string() + "' (supported: .exr, .png)");
}

}  // namespace anisocap
