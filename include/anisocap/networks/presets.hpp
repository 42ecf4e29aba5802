#pragma once
/// @file
/// Which network preset a weight file holds, and a call of a template with that preset.
///
/// A weight file written by the trainer (training/training.hpp) names its preset in the
/// safetensors metadata ("preset": "compact", "compact-orientation", ...). A folder of compact
/// weights may hold an estimator of one of the compact variants, which all share the compact
/// auto-encoder's parameters, and an auto-encoder of one of the compact auto-encoder presets
/// (compact_estimator_presets, compact_autoencoder_presets); the program, the pipeline studies and
/// the GPU training tool dispatch on the file through these, and the trainer's --preset choices come
/// from the same lists.
#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/core/text.hpp"
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

/// A list of network presets (types with a `name`, the name a weight file records): the one place
/// that says which presets a command, the dispatch below and its error messages know.
template <class... P>
struct preset_list {
  static_assert(sizeof...(P) > 0, "preset_list: at least one preset");
  /// The presets' names, in the list's order.
  static std::vector<std::string> names() { return {std::string(P::name)...}; }
  /// The names joined by ", " (error messages).
  static std::string joined() { return join_names(names(), ", "); }
  /// Whether `name` is one of the presets' names.
  static bool contains(std::string_view name) { return ((name == P::name) || ...); }
  /// Returns `f.template operator()<Q>()` with the preset Q of the list named `name`. Throws
  /// std::invalid_argument with `unknown()`'s text for a name not in the list.
  template <class F, class Unknown>
  static decltype(auto) call(std::string_view name, F&& f, Unknown&& unknown) {
    return call_from<P...>(name, f, unknown);
  }

 private:
  template <class First, class... Rest, class F, class Unknown>
  static decltype(auto) call_from(std::string_view name, F& f, Unknown& unknown) {
    if (name == First::name) return f.template operator()<First>();
    if constexpr (sizeof...(Rest) == 0) throw std::invalid_argument(unknown());
    else return call_from<Rest...>(name, f, unknown);
  }
};

/// The compact estimator presets, which all share the compact auto-encoder's parameters: a folder
/// of compact weights may hold any of them. The first is what a file without a preset holds.
using compact_estimator_presets = preset_list<estimator_compact, estimator_compact_orientation, estimator_compact_doubled_angle,
                                              estimator_compact_orientation_doubled_angle>;

/// The compact auto-encoder presets a folder of compact weights may hold (experimental but the
/// first, which is also what a file without a preset holds).
using compact_autoencoder_presets =
    preset_list<autoencoder_compact, autoencoder_compact_wide, autoencoder_compact_fine, autoencoder_compact_fine_wide,
                autoencoder_compact_fine_wider, autoencoder_compact_fine_widest, autoencoder_compact_fine_512>;

/// The estimator preset a capture runs by default: the shipped estimator's. The program also runs
/// the trainer's default (estimator_compact; trainable_estimator_presets); the others of
/// compact_estimator_presets are experimental.
using shipped_estimator_presets = preset_list<estimator_compact_orientation_doubled_angle>;

/// The compact estimator presets the program trains and captures with: the trainer's default and
/// the shipped one.
using trainable_estimator_presets = preset_list<estimator_compact, estimator_compact_orientation_doubled_angle>;

/// The compact auto-encoder presets a capture runs by default: the shipped first and second
/// priors'. The others of compact_autoencoder_presets are experimental.
using shipped_autoencoder_presets = preset_list<autoencoder_compact, autoencoder_compact_fine_512>;

/// Calls `f.template operator()<P>()` with the estimator preset P of `List` that `file` names
/// (estimator_compact for a file without a preset). Throws std::invalid_argument naming the file
/// and `List`'s presets for any other.
template <class List, class F>
decltype(auto) with_estimator_preset(const std::filesystem::path& file, F&& f) {
  const std::string preset = weights_preset(file);
  return List::call(preset.empty() ? estimator_compact::name : preset, f, [&] {
    return file.string() + ": an estimator of preset \"" + preset + "\", not one this build runs (" + List::joined() + ")";
  });
}

/// Calls `f.template operator()<P>()` with the auto-encoder preset P of `List` that `file` names
/// (autoencoder_compact for a file without a preset). Throws std::invalid_argument naming the file
/// and `List`'s presets for any other.
template <class List, class F>
decltype(auto) with_autoencoder_preset(const std::filesystem::path& file, F&& f) {
  const std::string preset = weights_preset(file);
  return List::call(preset.empty() ? autoencoder_compact::name : preset, f, [&] {
    return file.string() + ": an auto-encoder of preset \"" + preset + "\", not one this build runs (" + List::joined() + ")";
  });
}

/// Calls `f.template operator()<P>()` with the compact estimator preset P that `file` names (one of
/// compact_estimator_presets; estimator_compact for a file without a preset). Throws
/// std::invalid_argument naming the file for any other preset (e.g. "paper", whose weights do not
/// fit a compact network).
template <class F>
decltype(auto) with_compact_estimator_preset(const std::filesystem::path& file, F&& f) {
  return with_estimator_preset<compact_estimator_presets>(file, f);
}

/// Calls `f.template operator()<P>()` with the compact auto-encoder preset P that `file` names (one
/// of compact_autoencoder_presets; autoencoder_compact for a file without a preset). Throws
/// std::invalid_argument naming the file for any other preset.
template <class F>
decltype(auto) with_compact_autoencoder_preset(const std::filesystem::path& file, F&& f) {
  return with_autoencoder_preset<compact_autoencoder_presets>(file, f);
}

}  // namespace anisocap
