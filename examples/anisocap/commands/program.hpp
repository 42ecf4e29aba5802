#pragma once
// What the `anisocap` program's commands and its networks unit share, without the command line:
// progress lines, output folders and image writing, and the network weights of a preset. The
// networks unit (networks.cpp, training_runs.cpp) includes this alone, so that it compiles none of
// CLI11; common.hpp adds the options' bindings.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

// The library below calibration/, export/ and training/: each command includes those it uses.
#include "anisocap/core/image.hpp"
#include "anisocap/core/json_parse.hpp"
#include "anisocap/core/memory.hpp"
#include "anisocap/core/parallel.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/srgb.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/core/tensor.hpp"
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/conv.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/layers.hpp"
#include "anisocap/nn/linear.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/nn/normalization.hpp"
#include "anisocap/nn/parameter.hpp"
#include "anisocap/nn/pooling.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/nn/precision.hpp"
#include "anisocap/nn/schedule.hpp"
#include "anisocap/nn/upsample.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/brdf/ward.hpp"
#include "anisocap/render/analysis.hpp"
#include "anisocap/render/capture.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/renderer.hpp"
#include "anisocap/render/sensor_noise.hpp"
#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/contact_sheet.hpp"
#include "anisocap/data/data.hpp"
#include "anisocap/data/family_errors.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/data/map_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/network_layers.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/networks/presets.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/capture_material.hpp"
#include "anisocap/pipeline/encode.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/finetune.hpp"
#include "anisocap/pipeline/fingerprint.hpp"
#include "anisocap/pipeline/networks.hpp"
#include "anisocap/pipeline/progress_line.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/pipeline/texel_kernels.hpp"
#include "field_flags.hpp"

// The per-texel kernels are compiled once, in networks.cpp, not in every unit of the program.
ANISOCAP_TEXEL_KERNELS(extern)

namespace anisocap::commands {

namespace fs = std::filesystem;

/// Prints optimisation progress on one refreshed line on a terminal, or one line per report in logs.
inline void print_progress(const std::string& stage, const optimisation_progress& p) {
  static const bool tty = isatty(fileno(stderr));
  std::fprintf(stderr, "%s  %s step %5d/%d  loss %.5f  %6.1f steps/s  %5.1f s left%s", tty ? "\r" : "", stage.c_str(), p.step,
               p.steps, p.loss, p.steps_per_second, p.seconds_left, tty ? "   " : "\n");
  if (tty && p.step == p.steps) std::fputc('\n', stderr);
  std::fflush(stderr);
}

/// The per-parameter errors as JSON (alpha over anisotropic texels is null when there are none).
inline nlohmann::json errors_to_json(const parameter_errors& e) {
  return {{"diffuse", e.diffuse}, {"specular", e.specular}, {"normal", e.normal}, {"lobes", e.lobes},
          {"rotation", e.rotation},
          {"rotation_anisotropic", std::isnan(e.rotation_anisotropic) ? nlohmann::json(nullptr) : nlohmann::json(e.rotation_anisotropic)},
          {"fresnel", e.fresnel}};
}

/// An exclusive lock on an output folder for the life of a command (flock on the folder itself, so
/// nothing is left behind and the kernel drops it when the process dies): a second run into the
/// same folder fails at once instead of both writing there. Creates the folder; when the command
/// fails (the lock is destroyed by an exception), removes it again if it made it and it stayed empty.
class output_lock {
 public:
  explicit output_lock(const fs::path& folder) : folder_(folder), exceptions_(std::uncaught_exceptions()) {
    created_ = !fs::exists(folder);
    fs::create_directories(folder);
    fd_ = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd_ < 0) throw std::runtime_error(folder.string() + ": cannot open the output folder");
    if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd_);
      fd_ = -1;
      throw std::runtime_error(folder.string() + ": another anisocap run is writing into this folder; wait for it or choose another -o");
    }
  }
  output_lock(const output_lock&) = delete;
  output_lock& operator=(const output_lock&) = delete;
  ~output_lock() {
    if (std::uncaught_exceptions() > exceptions_) release_empty();
    if (fd_ >= 0) ::close(fd_);
  }

 private:
  /// Removes the folder when this lock created it and nothing was written there.
  void release_empty() {
    std::error_code ec;
    if (created_ && fs::is_empty(folder_, ec)) fs::remove(folder_, ec);
  }

  fs::path folder_;
  int exceptions_ = 0;  ///< std::uncaught_exceptions() when the lock was taken
  bool created_ = false;
  int fd_ = -1;
};

/// `out / name` for a file name read from a capture description. Throws std::invalid_argument when
/// the name is absolute or climbs out of `out` (a ".." that leaves it): outputs stay inside the
/// output folder whatever a capture description says.
inline fs::path output_inside(const fs::path& out, const std::string& name) {
  const fs::path n = fs::path(name).lexically_normal();
  if (n.empty() || n.has_root_name() || n.has_root_directory() || *n.begin() == ".." || n == ".")
    throw std::invalid_argument("image file name '" + name + "' would be written outside the output folder " + out.string() +
                                ": a capture's file names must be relative and stay inside its folder");
  return out / n;
}

/// Throws std::invalid_argument when one of `outputs` is one of `inputs` (the same file, however
/// named): a command never overwrites what it reads. `advice` ends the message: what to choose instead.
inline void refuse_overwriting_inputs(const std::vector<fs::path>& outputs, const std::vector<fs::path>& inputs,
                                      const std::string& advice = "choose another output folder (-o)") {
  std::vector<fs::path> existing;
  for (const auto& in : inputs)
    if (fs::exists(in)) existing.push_back(fs::weakly_canonical(in));
  for (const auto& out : outputs) {
    const fs::path o = fs::weakly_canonical(out);
    for (const auto& in : existing)
      if (o == in)
        throw std::invalid_argument(out.string() + ": this output would overwrite one of the command's inputs; " + advice);
  }
}

/// The files write_images writes for `cap` into `out` (each EXR with its PNG preview).
inline std::vector<fs::path> image_outputs(const capture& cap, const fs::path& out) {
  std::vector<fs::path> files;
  for (const auto& i : cap.images) {
    const fs::path target = output_inside(out, i.file);
    files.push_back(target);
    const auto ext = target.extension().string();
    if (ext == ".exr" || ext == ".EXR") files.push_back(fs::path(target).replace_extension(".png"));
  }
  return files;
}

/// The files a capture description names, resolved against its folder, and the description itself.
inline std::vector<fs::path> capture_inputs(const capture& cap, const fs::path& capture_file) {
  std::vector<fs::path> files{capture_file};
  for (const auto& i : cap.images) {
    files.push_back(capture_file.parent_path() / i.file);
    if (!i.mask.empty()) files.push_back(capture_file.parent_path() / i.mask);
  }
  return files;
}

/// The files of a map set folder (read_maps reads them; write_maps writes them with previews).
inline std::vector<fs::path> map_files(const fs::path& folder) {
  std::vector<fs::path> files;
  for (const auto name : map_file_names) {
    files.push_back(folder / name);
    files.push_back(fs::path(folder / name).replace_extension(".png"));
  }
  return files;
}

/// Creates `folder` (and its parents); io_error naming it when that fails (a file in the way).
inline void create_output_folder(const fs::path& folder) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (!fs::is_directory(folder))
    throw io_error(folder, "cannot create the output folder" + (ec ? ": " + ec.message() : std::string()));
}

/// Adds to `encodes` the jobs that stage `images` (one per capture image) for `out` into `files`:
/// one linear EXR per image under its capture file name (a .png name gets an 8-bit sRGB PNG
/// instead), plus a PNG preview beside every EXR. Names stay inside `out` (output_inside) and none
/// may be one of `inputs`. The jobs hold `images`; `files` must live until `encodes` has run.
inline void stage_images(std::shared_ptr<const std::vector<image>> images, const capture& cap, const fs::path& out, file_transaction& files,
                         job_batch& encodes, const std::vector<fs::path>& inputs = {}) {
  refuse_overwriting_inputs(image_outputs(cap, out), inputs);
  create_output_folder(out);
  file_transaction* staged = &files;
  for (std::size_t i = 0; i < images->size(); ++i) {
    fs::path target = output_inside(out, cap.images[i].file);
    if (target.has_parent_path()) create_output_folder(target.parent_path());
    const double cost = double((*images)[i].pixel_count()) * (*images)[i].channels();
    const auto ext = target.extension().string();
    if (ext == ".exr" || ext == ".EXR") {  // each file encoded on a thread of its own
      encodes.add([images, i, target, staged] { write_exr((*images)[i], target, *staged); }, cost);
      encodes.add([images, i, target, staged] { write_png((*images)[i], fs::path(target).replace_extension(".png"), *staged); }, cost);
    } else {
      encodes.add([images, i, target, staged] { write_png((*images)[i], target, *staged); }, cost);
    }
  }
}

/// stage_images with the files encoded and staged before it returns, on every thread.
inline void stage_images(const std::vector<image>& images, const capture& cap, const fs::path& out, file_transaction& files,
                         const std::vector<fs::path>& inputs = {}) {
  job_batch encodes;
  stage_images(std::make_shared<const std::vector<image>>(images), cap, out, files, encodes, inputs);
  encodes.run();
}

/// Writes `images` into `out` as stage_images lays them out; all files appear together or not at all.
inline void write_images(const std::vector<image>& images, const capture& cap, const fs::path& out, const std::vector<fs::path>& inputs = {}) {
  file_transaction files;
  stage_images(images, cap, out, files, inputs);
  files.commit();
}

/// Renders `maps` under `cap` into `out` (write_images).
inline void write_renders(const material_maps& maps, const capture& cap, const fs::path& out, const brdf_features& features = all_features,
                          const std::vector<fs::path>& inputs = {}) {
  write_images(with_features(features, [&]<brdf_features F>() { return render<F>(maps, cap); }), cap, out, inputs);
}

/// Where the program's network weights come from: --preset, --models and the second prior's
/// --also-models / --no-also-models, mapped onto load_networks (pipeline/networks.hpp).
struct model_choice {
  std::string preset = "compact";  ///< compact or paper
  fs::path models;                 ///< --models; empty: the library's search (ANISOCAP_MODELS, the install, beside the program)
  std::optional<fs::path> also;    ///< --also-models (a folder) or --no-also-models (an empty path); unset: MODELS/also
  /// The load_networks options of these choices.
  network_options options() const { return {preset, also}; }
};

/// Loads the networks of `m` (commands/networks.cpp: the preset dispatch is compiled there once).
/// Throws std::invalid_argument naming the option and the files when weights are missing.
networks load_program_networks(const model_choice& m);

#ifdef ANISOCAP_EXPERIMENTAL_PRESETS
/// The estimator presets the program's capture and trainers take: all compact ones (built with
/// -DANISOCAP_EXPERIMENTAL_PRESETS=ON).
using program_estimator_presets = compact_estimator_presets;
/// The auto-encoder presets the program's capture and trainers take: all compact ones.
using program_autoencoder_presets = compact_autoencoder_presets;
/// Whether the program captures with and trains the paper's widths (`--preset paper`).
inline constexpr bool program_has_paper_preset = true;
#else
/// The estimator presets the program's capture and trainers take: the shipped ones (the
/// experimental ones with -DANISOCAP_EXPERIMENTAL_PRESETS=ON, at the cost of a longer build).
using program_estimator_presets = trainable_estimator_presets;
/// The auto-encoder presets the program's capture and trainers take: the shipped ones.
using program_autoencoder_presets = shipped_autoencoder_presets;
/// Whether the program captures with and trains the paper's widths (`--preset paper`). No weights
/// ship for them and they do not train in useful time on a few cores, while their pipeline and
/// trainers are a third of the program's compile time: like the experimental compact presets,
/// they come with -DANISOCAP_EXPERIMENTAL_PRESETS=ON.
inline constexpr bool program_has_paper_preset = false;
#endif

/// load_program_networks where weights are found; empty networks, with a note on stderr, where
/// none are (no --models given and none installed): the capture then runs the refine alone.
networks find_program_networks(const model_choice& m);

/// The shipped compact weight file `name` where the library finds the weights (find_models_folder),
/// else models/compact/`name` (a default for options that name one file).
inline fs::path shipped_weights_file(const char* name) {
  const fs::path folder = find_models_folder("compact");
  return (folder.empty() ? fs::path("models") : folder) / "compact" / name;
}

/// Prints capture_material's choices (capture_options::log) as "capture: ..." lines.
inline void print_capture_choice(const std::string& message) { std::fprintf(stderr, "capture: %s\n", message.c_str()); }

}  // namespace anisocap::commands
