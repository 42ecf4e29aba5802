// `anisocap synthesize`, `render`, `view` and `export`: map sets in and out.
#include "commands.hpp"
#include "commands/export.hpp"
#include "commands/render.hpp"
#include "commands/synthesize.hpp"
#include "commands/view.hpp"

namespace anisocap::commands {

void register_synthesize(CLI::App& app) { add_synthesize_command(app); }
void register_render(CLI::App& app) { add_render_command(app); }
void register_view(CLI::App& app) { add_view_command(app); }
void register_export(CLI::App& app) { add_export_command(app); }

}  // namespace anisocap::commands
