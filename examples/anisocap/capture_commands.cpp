// `anisocap capture`, `eval` and `demo`: the commands that run capture_material; `plan`, which reads a capture's result.
#include "commands.hpp"
#include "commands/capture.hpp"
#include "commands/demo.hpp"
#include "commands/eval.hpp"
#include "commands/plan.hpp"

namespace anisocap::commands {

void register_capture(CLI::App& app) { add_capture_command(app); }
void register_eval(CLI::App& app) { add_eval_command(app); }
void register_demo(CLI::App& app) { add_demo_command(app); }
void register_plan(CLI::App& app) { add_plan_command(app); }

}  // namespace anisocap::commands
