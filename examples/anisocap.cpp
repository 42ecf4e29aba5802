// The `anisocap` program: synthesize procedural captures, render map sets, capture materials from
// photographs, evaluate, train the networks, a self-contained demo, the calibration of real
// photographs (markers, photograph, rectify), the viewer page and exports. One file per command under
// examples/commands/; `anisocap --help` and `anisocap <command> --help` list every option with its
// default.
#include <omp.h>

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>

#include "commands/options.hpp"

#include "commands/capture.hpp"
#include "commands/demo.hpp"
#include "commands/eval.hpp"
#include "commands/export.hpp"
#include "commands/markers.hpp"
#include "commands/photograph.hpp"
#include "commands/rectify.hpp"
#include "commands/render.hpp"
#include "commands/synthesize.hpp"
#include "commands/train.hpp"
#include "commands/view.hpp"

int main(int argc, char** argv) {
  CLI::App app{"anisocap: capture anisotropic SVBRDFs (Ward + Fresnel) from a few photographs"};
  app.option_defaults()->always_capture_default();
  app.require_subcommand(1);
  app.set_version_flag("--version", std::string("anisocap ") + ANISOCAP_VERSION);
  anisocap::commands::add_synthesize_command(app);
  anisocap::commands::add_render_command(app);
  anisocap::commands::add_capture_command(app);
  anisocap::commands::add_eval_command(app);
  anisocap::commands::add_train_commands(app);
  anisocap::commands::add_demo_command(app);
  anisocap::commands::add_view_command(app);
  anisocap::commands::add_export_command(app);
  anisocap::commands::add_rectify_command(app);
  anisocap::commands::add_photograph_command(app);
  anisocap::commands::add_markers_command(app);
  anisocap::commands::add_threads_option(&app);  // before the command or after it
  for (CLI::App* command : app.get_subcommands([](CLI::App*) { return true; })) anisocap::commands::add_threads_option(command);
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
