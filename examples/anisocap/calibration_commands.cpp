// `anisocap rectify`, `photograph` and `markers`: real photographs in.
#include "commands.hpp"
#include "commands/markers.hpp"
#include "commands/photograph.hpp"
#include "commands/rectify.hpp"

namespace anisocap::commands {

void register_rectify(CLI::App& app) { add_rectify_command(app); }
void register_photograph(CLI::App& app) { add_photograph_command(app); }
void register_markers(CLI::App& app) { add_markers_command(app); }

}  // namespace anisocap::commands
