// The program's network weights: the one translation unit that instantiates the pipeline for
// every preset a capture can run (load_networks), so that the others compile without it. The
// per-texel kernels (the fine-tune's, the refine's and the renderer) are compiled here too, once
// for the program.
#include <cstdio>

#include "anisocap/pipeline/networks.hpp"
#include "anisocap/pipeline/uncertainty.hpp"
#include "commands/program.hpp"

ANISOCAP_TEXEL_KERNELS()

namespace {
// The per-texel uncertainty (texel_uncertainty, and texel_information, which plan uses too) is
// made of inline functions rather than templates, so ANISOCAP_TEXEL_KERNELS cannot declare it.
// Its callers are in the commands unit, compiled at -O1, where it runs 5x slower. Referencing it
// here emits an -O3 copy in this unit, which the linker reads first and keeps
// (examples/CMakeLists.txt). Without it the capture with the refine alone took 1.07x the time.
[[gnu::used]] auto* const uncertainty_kernel = &anisocap::texel_uncertainty;
[[gnu::used]] auto* const information_kernel = &anisocap::texel_information;
}  // namespace

namespace anisocap::commands {

networks load_program_networks(const model_choice& m) {
  try {
    return load_networks<program_estimator_presets, program_autoencoder_presets, program_has_paper_preset>(m.models, m.options());
  } catch (const std::invalid_argument& e) {
    // Name the options a user gives, beside the library's message.
    throw std::invalid_argument(std::string(e.what()) + " (--models, --preset, --also-models)");
  }
}

networks find_program_networks(const model_choice& m) {
  if (!m.models.empty()) return load_program_networks(m);
  if (const auto found = find_models_folder(m.preset); !found.empty()) {
    model_choice at = m;
    at.models = found;  // load_networks need not search again
    return load_program_networks(at);
  }
  std::fprintf(stderr, "capture: no %s network weights found (looked in %s): running the per-texel refine alone (set "
               "ANISOCAP_MODELS or pass --models)\n", m.preset.c_str(), join_names(models_search_path(), ", ").c_str());
  return {};
}

}  // namespace anisocap::commands
