#pragma once
// The `anisocap` program's commands, one registration function each. Each is defined in the
// translation unit of its group (capture_commands.cpp, training_commands.cpp, tool_commands.cpp,
// calibration_commands.cpp, batch_commands.cpp), so that the groups compile in parallel; what the
// training commands run is compiled apart from their command lines, in training_runs.cpp.
#include <CLI/CLI.hpp>

namespace anisocap::commands {

void register_synthesize(CLI::App& app);
void register_render(CLI::App& app);
void register_capture(CLI::App& app);
void register_eval(CLI::App& app);
void register_training(CLI::App& app);
void register_demo(CLI::App& app);
void register_plan(CLI::App& app);
void register_view(CLI::App& app);
void register_export(CLI::App& app);
void register_rectify(CLI::App& app);
void register_photograph(CLI::App& app);
void register_markers(CLI::App& app);
void register_batch(CLI::App& app);

}  // namespace anisocap::commands
