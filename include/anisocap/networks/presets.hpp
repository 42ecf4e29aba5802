#pragma once
/// @file
/// Which network preset a weight file holds, and a call of a template with that preset.
///
/// A weight file written by the trainer (training/training.hpp) names its preset in the
/// safetensors metadata ("preset": "compact", "compact-orientation", ...). A folder of compact
/// weights may hold an estimator of one of the compact variants, which all share the compact
/// auto-encoder's parameters, and an auto-encoder of the compact, compact-wide, compact-fine,
/// compact-fine-wide, compact-fine-wider or compact-fine-widest preset; the program, the pipeline
/// studies and the GPU training tool dispatch on the file through these.
#include <filesystem>
#include <stdexcept>
#include <string>

#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/nn/safetensors.hpp"

namespace anisocap {

/// The "preset" entry of a weight file's metadata; "" when the file has none (weights written
/// before the trainer recorded it are compact). Reads the file's header only; throws
/// nn::safetensors_error for a missing or malformed file (a header that does not fit the file's size
/// included).
inline std::string weights_preset(const std::filesystem::path& file) {
  for (const auto& [key, value] : nn::read_safetensors_header(file).metadata)
    if (key == "preset") return value;
  return "";
}

/// Calls `f.template operator()<P>()` with the compact estimator preset P that `file` names:
/// estimator_compact (also for a file without a preset), estimator_compact_orientation,
/// estimator_compact_doubled_angle or estimator_compact_orientation_doubled_angle. Throws
/// std::invalid_argument naming the file for any other preset (e.g. "paper", whose weights do not
/// fit a compact network).
template <class F>
decltype(auto) with_compact_estimator_preset(const std::filesystem::path& file, F&& f) {
  const std::string preset = weights_preset(file);
  if (preset.empty() || preset == estimator_compact::name) return f.template operator()<estimator_compact>();
  if (preset == estimator_compact_orientation::name) return f.template operator()<estimator_compact_orientation>();
  if (preset == estimator_compact_doubled_angle::name) return f.template operator()<estimator_compact_doubled_angle>();
  if (preset == estimator_compact_orientation_doubled_angle::name)
    return f.template operator()<estimator_compact_orientation_doubled_angle>();
  throw std::invalid_argument(file.string() + ": an estimator of preset \"" + preset +
                              "\", not a compact one (compact, compact-orientation, compact-doubled-angle, "
                              "compact-orientation-doubled-angle)");
}

/// Calls `f.template operator()<P>()` with the compact auto-encoder preset P that `file` names:
/// autoencoder_compact (also for a file without a preset), autoencoder_compact_wide,
/// autoencoder_compact_fine, autoencoder_compact_fine_wide, autoencoder_compact_fine_wider or
/// autoencoder_compact_fine_widest. Throws std::invalid_argument naming the file for any other
/// preset.
template <class F>
decltype(auto) with_compact_autoencoder_preset(const std::filesystem::path& file, F&& f) {
  const std::string preset = weights_preset(file);
  if (preset.empty() || preset == autoencoder_compact::name) return f.template operator()<autoencoder_compact>();
  if (preset == autoencoder_compact_wide::name) return f.template operator()<autoencoder_compact_wide>();
  if (preset == autoencoder_compact_fine::name) return f.template operator()<autoencoder_compact_fine>();
  if (preset == autoencoder_compact_fine_wide::name) return f.template operator()<autoencoder_compact_fine_wide>();
  if (preset == autoencoder_compact_fine_wider::name) return f.template operator()<autoencoder_compact_fine_wider>();
  if (preset == autoencoder_compact_fine_widest::name) return f.template operator()<autoencoder_compact_fine_widest>();
  throw std::invalid_argument(file.string() + ": an auto-encoder of preset \"" + preset +
                              "\", not a compact one (compact, compact-wide, compact-fine, compact-fine-wide, compact-fine-wider, "
                              "compact-fine-widest)");
}

}  // namespace anisocap
