// `anisocap batch`: many captures, one independent unit per sample.
#include "commands.hpp"
#include "commands/batch.hpp"

namespace anisocap::commands {

void register_batch(CLI::App& app) { add_batch_command(app); }

}  // namespace anisocap::commands
