#pragma once
// Runs a subcommand's work inside its CLI11 callback: any error becomes one line on stderr and
// exit status 1 (CLI11_PARSE in main turns the CLI::RuntimeError into that status).
#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>

namespace anisocap::commands {

/// Calls `work()`; on an exception prints "anisocap: error: <what>" and throws CLI::RuntimeError(1).
template <class Work>
void run_reporting_errors(Work&& work) {
  try {
    work();
  } catch (const CLI::Error&) {
    throw;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "anisocap: error: %s\n", e.what());
    throw CLI::RuntimeError(1);
  }
}

}  // namespace anisocap::commands
