#pragma once
// `anisocap demo`: synthesize a procedural fabric, capture it with the default schedule, and
// compare the errors with the paper's Table 1.
#include <memory>

#include "capture.hpp"
#include "synthesize.hpp"

namespace anisocap::commands {

/// The paper's Table 1 row "12, refined, set alpha", beside this run's errors.
inline void print_error_table(const nlohmann::json& errors) {
  struct row { const char* name; const char* key; double paper; };
  const row rows[] = {{"diffuse a_d", "diffuse", 0.0002}, {"specular a'_s", "specular", 0.0019},
                      {"normal n_s", "normal", 0.0016},   {"lobes sigma", "lobes", 0.0068},
                      {"rotation alpha (mod pi)", "rotation", 0.50}, {"Fresnel F0", "fresnel", 0.059}};
  std::printf("\n| parameter | MSE (this run) | paper, N=12 refined, set alpha |\n|---|---|---|\n");
  for (const auto& r : rows) std::printf("| %s | %.5f | %.4f |\n", r.name, errors[r.key].get<double>(), r.paper);
  if (!errors["rotation_anisotropic"].is_null())
    std::printf("| rotation, anisotropic texels only | %.5f | - |\n", errors["rotation_anisotropic"].get<double>());
  std::printf("| novel-view image loss (3 unseen views) | %.5f | - |\n\n", errors["novel_view_image_loss"].get<double>());
}

/// Registers `anisocap demo`.
inline void add_demo_command(CLI::App& app) {
  auto syn = std::make_shared<synthesize_settings>();
  auto cap = std::make_shared<capture_settings>();
  syn->out = "anisocap-demo";
  auto* c = app.add_subcommand("demo", "synthesize a procedural fabric, capture it, report per-parameter errors");
  c->add_option("-o,--out", syn->out, "output folder");
  c->add_option("--seed", syn->seed, "material seed");
  c->add_option("--size", syn->width, "material size (square)");
  c->add_option(capture_flag("pipeline_stages"), cap->stages, "stages to run (see capture --help)");
  add_model_options(c, cap->models);
  add_optimiser_options(c, cap->options);
  c->callback([syn, cap, c] {
    naming_options(capture_field_flags, [&] {
      syn->height = syn->width;
      const fs::path root = syn->out;
      output_lock lock(root);  // the whole demo folder: a second demo cannot rewrite the inputs this one reads
      synthesize_settings input = *syn;
      input.out = root / "input";
      synthesize(input);
      capture_settings run = *cap;
      run.capture_file = input.out / "capture.json";
      run.truth = input.out / "truth";
      run.out = root / "result";
      const auto report = run_capture_command(run, c);
      print_error_table(report["errors"]);
      std::printf("inputs and true maps: %s\nestimated maps, re-renders and report.json: %s\n", input.out.c_str(), run.out.c_str());
    });
  });
}

}  // namespace anisocap::commands
