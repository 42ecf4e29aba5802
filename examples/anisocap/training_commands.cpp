// `anisocap train-estimator`, `train-autoencoder`, `eval-networks` and `convert-weights`.
#include "commands.hpp"
#include "commands/train.hpp"

namespace anisocap::commands {

void register_training(CLI::App& app) { add_train_commands(app); }

}  // namespace anisocap::commands
