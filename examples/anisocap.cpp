// The `anisocap` program: synthesize procedural captures, render map sets, capture materials from
// photographs, evaluate, train the networks, and a self-contained demo. One file per command under
// examples/commands/; `anisocap --help` and `anisocap <command> --help` list every option with its
// default.
#include <omp.h>

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>

#include "commands/capture.hpp"
#include "commands/demo.hpp"
#include "commands/eval.hpp"
#include "commands/render.hpp"
#include "commands/synthesize.hpp"
#include "commands/train.hpp"

int main(int argc, char** argv) {
  CLI::App app{"anisocap: capture anisotropic SVBRDFs (Ward + Fresnel) from a few photographs"};
  app.option_defaults()->always_capture_default();
  app.require_subcommand(1);
  app.add_option_function<int>("--threads", [](int n) { if (n > 0) omp_set_num_threads(n); }, "worker threads (0: all cores)")
      ->check(CLI::NonNegativeNumber)
      ->default_str("0");
  anisocap::commands::add_synthesize_command(app);
  anisocap::commands::add_render_command(app);
  anisocap::commands::add_capture_command(app);
  anisocap::commands::add_eval_command(app);
  anisocap::commands::add_train_commands(app);
  anisocap::commands::add_demo_command(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "anisocap: error: %s\n", e.what());
    return 1;
  }
  return 0;
}
