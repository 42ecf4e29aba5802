#pragma once
/// @file
/// The trained networks of a capture behind one type, and where their weights are found.
///
/// A weight file names its network preset (networks/presets.hpp); `load_networks` reads the files,
/// dispatches on those presets once, and returns a `networks` value that runs the pipeline's stages
/// without the caller naming a template. It holds the estimator and the auto-encoder of the first
/// prior and, where the weights folder has one, a second prior: another auto-encoder (with the
/// first prior's estimator) that capture_material tries where the first fit is poor.
///
/// Weights are looked for, in this order: the folder the caller names; the environment variable
/// ANISOCAP_MODELS; beside the running program (`<program's folder>/../share/anisocap/models`, as
/// installed, then `<program's folder>/share/anisocap/models`, the build tree's copy); the folder
/// the CMake package compiles in as ANISOCAP_MODELS_DIR (the installed package's
/// share/anisocap/models, or the build tree's copy for add_subdirectory).
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "anisocap/networks/presets.hpp"
#include "anisocap/pipeline/capture.hpp"

namespace anisocap {

/// Trained networks for capture_material: empty (the capture then runs the first guess and the
/// refine alone), or a first prior and optionally a second one. Cheap to copy (shared, immutable);
/// each capture works on its own copy of the weights, so one value serves many captures, also
/// from several threads.
class networks {
 public:
  /// One prior: an estimator and an auto-encoder of fixed presets, able to run the stages.
  class prior {
   public:
    virtual ~prior() = default;
    /// One run of the stages in `o` (capture_once) on fresh copies of the loaded weights.
    virtual capture_result run(const capture& cap, const std::vector<image>& photos, const capture_options& o,
                               const material_maps* start, const std::vector<image>& masks) const = 0;
    std::filesystem::path folder;  ///< the weights folder (holding <preset>/...safetensors)
    std::string estimator_preset, autoencoder_preset;
    /// "the compact weights in FOLDER (estimator P, auto-encoder Q)".
    std::string describe() const {
      return "the weights in " + folder.string() + " (estimator " + estimator_preset + ", auto-encoder " + autoencoder_preset + ")";
    }
  };

  networks() = default;
  networks(std::shared_ptr<const prior> first, std::shared_ptr<const prior> second) : first_(std::move(first)), second_(std::move(second)) {
    if (!first_ && second_) throw std::invalid_argument("networks: a second prior needs a first");
  }
  /// Whether no weights are held (the capture runs without the network stages).
  bool empty() const noexcept { return !first_; }
  /// Whether a second prior is held.
  bool has_second_prior() const noexcept { return bool(second_); }
  /// The first prior (null when empty).
  const prior* first() const noexcept { return first_.get(); }
  /// The second prior (null when there is none).
  const prior* second() const noexcept { return second_.get(); }
  /// These networks without their second prior.
  networks without_second_prior() const { return networks(first_, nullptr); }
  /// In words, for logs: which weights from where.
  std::string describe() const {
    if (!first_) return "no networks";
    return first_->describe() + (second_ ? "; second prior: auto-encoder " + second_->autoencoder_preset + " in " + second_->folder.string() : "");
  }

 private:
  std::shared_ptr<const prior> first_, second_;
};

namespace networks_detail {

template <class EstimatorPreset, class AutoEncoderPreset>
class prior_of final : public networks::prior {
 public:
  prior_of(const std::filesystem::path& estimator_file, const std::filesystem::path& autoencoder_file) {
    nn::load_weights(estimator_file, estimator_);
    nn::load_weights(autoencoder_file, autoencoder_);
    estimator_preset = EstimatorPreset::name;
    autoencoder_preset = AutoEncoderPreset::name;
  }
  capture_result run(const capture& cap, const std::vector<image>& photos, const capture_options& o, const material_maps* start,
                     const std::vector<image>& masks) const override {
    // The fine-tune changes the decoder's weights: every run starts from the loaded ones.
    estimation_network<EstimatorPreset> estimator = estimator_;
    auto_encoder<AutoEncoderPreset> autoencoder = autoencoder_;
    return capture_once(cap, photos, estimator, autoencoder, o, start, masks);
  }

 private:
  estimation_network<EstimatorPreset> estimator_;
  auto_encoder<AutoEncoderPreset> autoencoder_;
};

/// The prior of these two files, dispatched on the presets they record among `EstimatorPresets`
/// and `AutoEncoderPresets` (`paper`, where `Paper`: the paper pair).
template <class EstimatorPresets, class AutoEncoderPresets, bool Paper>
std::shared_ptr<const networks::prior> load_prior(const std::filesystem::path& folder, const std::string& preset,
                                                         const std::filesystem::path& estimator_file,
                                                         const std::filesystem::path& autoencoder_file) {
  std::shared_ptr<networks::prior> p;
  if (preset == "paper") {
    if constexpr (Paper) p = std::make_shared<prior_of<estimator_paper, autoencoder_paper>>(estimator_file, autoencoder_file);
    else throw std::invalid_argument("this program was built without the paper preset's pipeline (load_networks<..., true>)");
  } else {
    p = with_estimator_preset<EstimatorPresets>(estimator_file, [&]<class E>() -> std::shared_ptr<networks::prior> {
      return with_autoencoder_preset<AutoEncoderPresets>(
          autoencoder_file, [&]<class A>() -> std::shared_ptr<networks::prior> { return std::make_shared<prior_of<E, A>>(estimator_file, autoencoder_file); });
    });
  }
  p->folder = folder;
  return p;
}

/// The running program's folder (empty where it cannot be read).
inline std::filesystem::path program_folder() {
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? std::filesystem::path() : exe.parent_path();
}

}  // namespace networks_detail

/// The folder of the second prior inside a weights folder: `also/`.
inline constexpr const char* second_prior_folder_name = "also";

/// The places the weights are looked for when the caller names none, in order (see the file
/// comment): the environment's ANISOCAP_MODELS, beside the running program, and the compiled-in
/// ANISOCAP_MODELS_DIR.
inline std::vector<std::filesystem::path> models_search_path() {
  std::vector<std::filesystem::path> places;
  if (const char* env = std::getenv("ANISOCAP_MODELS"); env && *env) places.emplace_back(env);
  if (const auto here = networks_detail::program_folder(); !here.empty()) {
    places.push_back(here.parent_path() / "share" / "anisocap" / "models");
    places.push_back(here / "share" / "anisocap" / "models");
  }
#ifdef ANISOCAP_MODELS_DIR
  places.emplace_back(ANISOCAP_MODELS_DIR);
#endif
  return places;
}

/// Whether `folder` holds both weight files of `preset`.
inline bool has_weights(const std::filesystem::path& folder, const std::string& preset = "compact") {
  std::error_code ec;
  return std::filesystem::is_regular_file(folder / preset / "estimator.safetensors", ec) &&
         std::filesystem::is_regular_file(folder / preset / "autoencoder.safetensors", ec);
}

/// The first folder of models_search_path() that holds the weights of `preset`; empty when none does.
inline std::filesystem::path find_models_folder(const std::string& preset = "compact") {
  for (const auto& place : models_search_path())
    if (has_weights(place, preset)) return place;
  return {};
}

/// What load_networks loads.
struct network_options {
  std::string preset = "compact";  ///< "compact" or "paper": the subfolder of the weights folder
  /// The second prior's weights folder: unset, the weights folder's `also/` where it holds
  /// `<preset>/autoencoder.safetensors` (the first prior's estimator is used unless it has its
  /// own); an empty path: no second prior.
  std::optional<std::filesystem::path> second_prior;
};

/// Loads the networks in `folder` (holding `<preset>/estimator.safetensors` and
/// `<preset>/autoencoder.safetensors`), or, when `folder` is empty, in the first folder of
/// models_search_path() that has them, with the second prior (network_options::second_prior).
/// Throws std::invalid_argument naming the files or the places searched when weights are missing,
/// and the loader's errors (naming the file) when a file is unreadable or of another preset.
///
/// The files' presets are looked up in `EstimatorPresets` and `AutoEncoderPresets` (the shipped
/// ones by default; compact_estimator_presets and compact_autoencoder_presets add the experimental
/// ones), and `Paper` adds the paper's pair. Each pair is a compiled pipeline (some 20 s of
/// compile time): call this in one translation unit of a program, with the presets it needs.
template <class EstimatorPresets = shipped_estimator_presets, class AutoEncoderPresets = shipped_autoencoder_presets,
          bool Paper = false>
networks load_networks(const std::filesystem::path& folder = {}, const network_options& options = {}) {
  namespace fs = std::filesystem;
  if (options.preset != "compact" && options.preset != "paper")
    throw std::invalid_argument("network preset '" + options.preset + "': compact or paper");
  fs::path where = folder;
  if (where.empty()) {
    where = find_models_folder(options.preset);
    if (where.empty()) {
      throw std::invalid_argument("no " + options.preset + " network weights found (looked in: " + join_names(models_search_path(), ", ") +
                                  "); set ANISOCAP_MODELS to the folder holding " + options.preset +
                                  "/estimator.safetensors and autoencoder.safetensors");
    }
  } else if (!has_weights(where, options.preset)) {
    throw std::invalid_argument(where.string() + ": no " + options.preset + " network weights there (" +
                                (where / options.preset / "estimator.safetensors").string() + " and " +
                                (where / options.preset / "autoencoder.safetensors").string() + ")");
  }
  const fs::path estimator_file = where / options.preset / "estimator.safetensors";
  auto first = networks_detail::load_prior<EstimatorPresets, AutoEncoderPresets, Paper>(where, options.preset, estimator_file, where / options.preset / "autoencoder.safetensors");
  std::shared_ptr<const networks::prior> second;
  const fs::path second_folder = options.second_prior ? *options.second_prior : where / second_prior_folder_name;
  std::error_code ec;
  const fs::path second_autoencoder = second_folder / options.preset / "autoencoder.safetensors";
  if (!second_folder.empty()) {
    if (fs::is_regular_file(second_autoencoder, ec)) {
      const fs::path own_estimator = second_folder / options.preset / "estimator.safetensors";
      second = networks_detail::load_prior<EstimatorPresets, AutoEncoderPresets, Paper>(second_folder, options.preset, fs::is_regular_file(own_estimator, ec) ? own_estimator : estimator_file,
                                           second_autoencoder);
    } else if (options.second_prior) {
      throw std::invalid_argument(second_folder.string() + ": no second prior there (" + second_autoencoder.string() + " not found)");
    }
  }
  return networks(std::move(first), std::move(second));
}

}  // namespace anisocap
