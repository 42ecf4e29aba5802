// The `anisocap` program: synthesize procedural captures, render map sets, capture materials from
// photographs, evaluate, train the networks, a self-contained demo, the calibration of real
// photographs (markers, photograph, rectify), the viewer page, exports and batches of captures. One file per command under
// examples/anisocap/commands/, compiled in groups; `anisocap --help` and `anisocap <command> --help` list every option with its
// default.
//
// In a dispatching build (-DANISOCAP_KERNEL_ISAS) this file and the commands are compiled once per
// instruction set into modules, and `anisocap_module_main` below is what the launcher
// (launcher/main.cpp) calls in the module it chose; otherwise it is the program's `main`.
#include <omp.h>

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>

#include "commands.hpp"
#include "commands/options.hpp"

#include "anisocap/core/simd.hpp"
#include "anisocap/nn/precision.hpp"

namespace {

int run_program(int argc, char** argv) {
  CLI::App app{"anisocap: capture anisotropic SVBRDFs (Ward + Fresnel) from a few photographs"};
  app.option_defaults()->always_capture_default();
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("anisocap ") + ANISOCAP_VERSION + " (kernels: " + ANISOCAP_KERNEL_ISA + ", " +
                                        anisocap::simd::arch_name() + (anisocap::nn::bf16_available() ? ", bf16" : "") + ")");
  anisocap::commands::register_synthesize(app);
  anisocap::commands::register_render(app);
  anisocap::commands::register_capture(app);
  anisocap::commands::register_eval(app);
  anisocap::commands::register_training(app);
  anisocap::commands::register_demo(app);
  anisocap::commands::register_plan(app);
  anisocap::commands::register_view(app);
  anisocap::commands::register_export(app);
  anisocap::commands::register_rectify(app);
  anisocap::commands::register_photograph(app);
  anisocap::commands::register_markers(app);
  anisocap::commands::register_batch(app);
  anisocap::commands::add_threads_option(&app);  // before the command or after it
  anisocap::commands::add_kernel_isa_option(&app, ANISOCAP_KERNEL_ISA);
  for (CLI::App* command : app.get_subcommands([](CLI::App*) { return true; })) {
    anisocap::commands::add_threads_option(command);
    anisocap::commands::add_kernel_isa_option(command, ANISOCAP_KERNEL_ISA);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    anisocap::commands::suggest_command(app, argc, argv);
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "anisocap: error: %s\n", e.what());
    return 1;
  }
  return 0;
}

}  // namespace

#if defined(ANISOCAP_KERNEL_MODULE)
extern "C" __attribute__((visibility("default"))) int anisocap_module_main(int argc, char** argv) { return run_program(argc, argv); }
#else
int main(int argc, char** argv) { return run_program(argc, argv); }
#endif
