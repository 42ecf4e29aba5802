#pragma once
/// @file
/// How a photograph's file stored its values (photo_encoding): what the per-texel uncertainty's
/// calibration follows (pipeline/uncertainty.hpp), read from the files (data/photo_io.hpp) and
/// written in capture.json (data/capture_io.hpp).
#include <iterator>
#include <optional>
#include <string>
#include <string_view>

namespace anisocap {

/// How a photograph's file stored its values, ordered from the least to the most lossy.
enum class photo_encoding {
  lossless,         ///< EXR, Radiance HDR or 16-bit PNG
  eight_bit,        ///< 8-bit PNG: every value rounded to one of 256 codes
  jpeg,             ///< JPEG with its colour at full resolution (4:4:4)
  jpeg_subsampled,  ///< JPEG with its colour at a lower resolution than its brightness (4:2:0, 4:2:2): most phones' JPEGs
};

/// The name of `e` in capture.json and report.json: "lossless", "eight_bit", "jpeg",
/// "jpeg_subsampled".
inline const char* photo_encoding_name(photo_encoding e) {
  switch (e) {
    case photo_encoding::eight_bit: return "eight_bit";
    case photo_encoding::jpeg: return "jpeg";
    case photo_encoding::jpeg_subsampled: return "jpeg_subsampled";
    default: return "lossless";
  }
}

/// Every encoding, in order.
inline constexpr photo_encoding photo_encodings[] = {photo_encoding::lossless, photo_encoding::eight_bit, photo_encoding::jpeg,
                                                     photo_encoding::jpeg_subsampled};

/// The encoding `name` names (photo_encoding_name), or none.
inline std::optional<photo_encoding> photo_encoding_from_name(std::string_view name) {
  for (const photo_encoding e : photo_encodings)
    if (name == photo_encoding_name(e)) return e;
  return std::nullopt;
}

/// The names an encoding may have, for messages, each between `quote`s: "lossless", "eight_bit",
/// "jpeg" or "jpeg_subsampled".
inline std::string photo_encoding_choices(char quote) {
  std::string text;
  for (std::size_t i = 0; i < std::size(photo_encodings); ++i) {
    if (i > 0) text += i + 1 == std::size(photo_encodings) ? " or " : ", ";
    text += quote;
    text += photo_encoding_name(photo_encodings[i]);
    text += quote;
  }
  return text;
}

}  // namespace anisocap
