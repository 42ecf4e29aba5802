#pragma once
// Training subcommands of the `anisocap` program (train-estimator, train-autoencoder).
// Registered by examples/anisocap.cpp through add_train_commands(); filled in with issue 4.
#include <CLI/CLI.hpp>

#include <functional>
#include <vector>

namespace anisocap::commands {

/// Adds the training subcommands to `app`. Each returns, through `actions`, the function to run
/// when its subcommand was chosen (the program runs every action whose subcommand parsed).
inline void add_train_commands(CLI::App& app, std::vector<std::pair<CLI::App*, std::function<void()>>>& actions) {
  (void)app;
  (void)actions;
}

}  // namespace anisocap::commands
