#pragma once
// Options of the program as a whole: --threads and --kernel-isa (before or after the command) and
// the closest command to a mistyped one.
#include <omp.h>

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

namespace anisocap::commands {

/// Adds `--threads` to `app`: 0 (the default) uses every core; a count above the machine's
/// hardware threads is capped there with a note (more threads than cores only contend).
inline void add_threads_option(CLI::App* app) {
  app->add_option_function<long>(
         "--threads",
         [](long n) {
           const long hardware = std::max(1, omp_get_num_procs());
           if (n > hardware) {
             std::fprintf(stderr, "anisocap: note: --threads %ld is more than the %ld hardware threads here; using %ld\n", n, hardware,
                          hardware);
             n = hardware;
           }
           if (n > 0) omp_set_num_threads(int(n));
         },
         "worker threads (0: all cores; at most the machine's hardware threads)")
      ->check(CLI::Validator(
          [](std::string& text) -> std::string {
            try {
              std::size_t used = 0;
              const long n = std::stol(text, &used);
              if (used != text.size()) return "--threads takes a whole number, got '" + text + "'";
              if (n < 0) return "--threads must be 0 (all cores) or a positive count, got " + text;
            } catch (const std::exception&) {
              return "--threads takes a whole number, got '" + text + "'";
            }
            return {};
          },
          "INT >= 0"))
      ->default_str("0");
}

/// Adds `--kernel-isa` to `app`. The launcher of a dispatching build reads it to choose the module
/// (launcher/main.cpp); here it is checked against `compiled`, the instruction set this code was built
/// for, so that a build without modules says so instead of ignoring the request.
inline void add_kernel_isa_option(CLI::App* app, const std::string& compiled) {
  app->add_option_function<std::string>(
         "--kernel-isa", [](const std::string&) {},
         "instruction set of the kernels: in a build with modules per instruction set (ANISOCAP_KERNEL_ISAS), one of "
         "x86-64-v4-bf16 (AVX-512 with BF16, for --network-precision bf16), x86-64-v4 (AVX-512), x86-64-v3 (AVX2), x86-64-v2, "
         "x86-64; the default is the best one this CPU runs (also "
         "the environment's ANISOCAP_KERNEL_ISA). This program runs " + compiled)
      ->type_name("ISA")
      ->check(CLI::Validator(
          [compiled](std::string& isa) -> std::string {
            if (isa == compiled) return {};
            return isa + ": this program has only the " + compiled +
                   " kernels (a build with -DANISOCAP_KERNEL_ISAS=\"x86-64;x86-64-v3;x86-64-v4;x86-64-v4-bf16\" has one module per instruction set)";
          },
          ""));
}

/// Edit distance between two names (Levenshtein).
inline std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

/// When the first word that is not an option is no command of `app`, prints the closest command
/// (within a third of its length in edits) as a suggestion.
inline void suggest_command(CLI::App& app, int argc, char** argv) {
  std::vector<std::string> names;
  for (const CLI::App* c : app.get_subcommands([](const CLI::App*) { return true; })) names.push_back(c->get_name());
  for (int i = 1; i < argc; ++i) {
    const std::string word = argv[i];
    if (word.empty() || word[0] == '-') {
      if (word == "--threads" && i + 1 < argc) ++i;
      continue;
    }
    if (std::find(names.begin(), names.end(), word) != names.end()) return;
    std::string best;
    std::size_t best_distance = word.size();
    for (const auto& n : names) {
      const std::size_t d = edit_distance(word, n);
      if (d < best_distance) best_distance = d, best = n;
    }
    if (!best.empty() && best_distance <= std::max<std::size_t>(2, best.size() / 3))
      std::fprintf(stderr, "anisocap: '%s' is not a command; did you mean '%s'?\n", word.c_str(), best.c_str());
    return;
  }
}

}  // namespace anisocap::commands
