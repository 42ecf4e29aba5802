#pragma once
// `anisocap batch`: many captures from a manifest, each sample one independent unit that is
// skipped when done, resumed when interrupted and locked while it runs (pipeline/batch.hpp,
// docs/batch.md). The units run `anisocap capture` as child processes of this program.
#include <omp.h>
#include <unistd.h>

#include <CLI/CLI.hpp>

#include <climits>
#include <cstdio>
#include <cstdlib>
#include <memory>

#include "anisocap/pipeline/batch.hpp"
#include "field_flags.hpp"

namespace anisocap::commands {

/// What the batch command reads besides the manifest's samples.
struct batch_settings {
  std::filesystem::path manifest;  ///< the manifest file
  batch_selection selection;       ///< --sample, --index, --count
  bool list = false;    ///< print the selected samples' names, one a line, and run nothing
  bool status = false;  ///< print each selected sample's state, and run nothing
  double stale_seconds = 600;     ///< --stale-after (batch_options::stale_seconds)
  std::filesystem::path summary;  ///< --summary: the summary as JSON, when given
};

/// This program's own path (each unit runs it as `anisocap capture`).
inline std::filesystem::path this_program() {
  char path[PATH_MAX + 1] = {};
  const ssize_t n = ::readlink("/proc/self/exe", path, PATH_MAX);
  if (n <= 0) throw std::runtime_error("cannot find this program's path (/proc/self/exe) to run its captures");
  return std::string(path, std::size_t(n));
}

/// Runs `anisocap batch`: lists, reports the state of, or runs the selected samples; prints one
/// line per unit and the summary; exits non-zero when a unit failed or the batch was stopped.
inline void run_batch_command(const batch_settings& s, const CLI::App* parsed) {
  const batch_manifest m = read_batch_manifest(s.manifest);
  const std::vector<std::size_t> selected = naming_options(batch_field_flags, [&] { return select_batch_samples(m, s.selection); });
  if (s.list) {
    for (std::size_t i : selected) std::printf("%s\n", m.samples[i].name.c_str());
    return;
  }
  if (s.status) {
    for (std::size_t i : selected) {
      std::string reason;
      const batch_state state = inspect_batch_unit({m.samples[i].out}, check_batch_sample(m, i), s.stale_seconds, &reason);
      std::printf("%-24s %-12s %s%s%s\n", m.samples[i].name.c_str(), batch_state_name(state), m.samples[i].out.c_str(),
                  reason.empty() ? "" : "  ", reason.c_str());
    }
    return;
  }
  batch_options o;
  o.program = this_program();
  // --threads given to the batch (before or after the command) holds for every capture.
  if (parsed->count("--threads") > 0 || (parsed->get_parent() && parsed->get_parent()->count("--threads") > 0))
    o.program_arguments = {"--threads", std::to_string(omp_get_max_threads())};
  o.stale_seconds = s.stale_seconds;
  o.log = [](const std::string& message) { std::fprintf(stderr, "batch: %s\n", message.c_str()); };
  const std::vector<batch_record> records = check_batch_samples(m, selected);  // bad input: refused before any capture
  batch_stop_on_signals();
  std::fprintf(stderr, "batch: %zu of %zu sample%s from %s\n", selected.size(), m.samples.size(), m.samples.size() == 1 ? "" : "s",
               s.manifest.c_str());
  const batch_summary summary = run_batch(m, selected, records, o, [](const batch_outcome& r, std::size_t k, std::size_t n) {
    if (r.result == batch_result::captured)
      std::fprintf(stderr, "batch: [%zu/%zu] %s: captured in %.1f s%s (log %s)\n", k + 1, n, r.name.c_str(), r.seconds,
                   r.state == batch_state::interrupted ? ", resumed" : "", r.log.c_str());
    else
      std::fprintf(stderr, "batch: [%zu/%zu] %s: %s: %s\n", k + 1, n, r.name.c_str(),
                   r.result == batch_result::failed ? "FAILED" : batch_result_name(r.result), r.message.c_str());
  });
  int resumed = 0;
  for (const auto& r : summary.outcomes) resumed += r.result == batch_result::captured && r.state == batch_state::interrupted;
  std::fprintf(stderr, "batch: %zu sample%s in %.1f s: %d captured (%d resumed; %.1f s capturing), %d skipped (done), %d busy (running "
               "elsewhere), %d failed%s\n",
               summary.outcomes.size(), summary.outcomes.size() == 1 ? "" : "s", summary.seconds, summary.count(batch_result::captured), resumed,
               summary.seconds_of(batch_result::captured), summary.count(batch_result::skipped), summary.count(batch_result::busy),
               summary.count(batch_result::failed), summary.count(batch_result::stopped) > 0 ? ", stopped by a signal" : "");
  if (!s.summary.empty()) write_file_atomically(s.summary, summary.to_json().dump(2) + "\n");
  std::fflush(nullptr);
  if (const int sig = batch_stop_requested(); sig != 0) std::exit(128 + sig);
  if (summary.count(batch_result::failed) > 0) std::exit(1);
}

/// Registers `anisocap batch`.
inline void add_batch_command(CLI::App& app) {
  auto s = std::make_shared<batch_settings>();
  auto* c = app.add_subcommand("batch", "capture every sample of a manifest, each an independent unit: skipped when done, resumed when "
                                        "interrupted, locked while it runs (docs/batch.md)");
  c->add_option("manifest", s->manifest, "the manifest: one sample a line, NAME CAPTURE OUT [capture options...]")->required();
  c->add_option(flag_of(batch_field_flags, "batch_selection::names"), s->selection.names, "run only the sample of this name (repeatable; --list names them)");
  c->add_option(flag_of(batch_field_flags, "batch_selection::index"), s->selection.index,
                "run only the sample at this index (0-based, manifest order; e.g. $SLURM_ARRAY_TASK_ID); with --count N, every sample "
                "whose index is this modulo N")
      ->check(CLI::NonNegativeNumber);
  c->add_option(flag_of(batch_field_flags, "batch_selection::count"), s->selection.count, "the number of tasks the samples are divided between (with --index)")->check(CLI::PositiveNumber);
  c->add_flag("--list", s->list, "print the selected samples' names, one a line (for GNU parallel), and run nothing");
  c->add_flag("--status", s->status, "print each selected sample's state (new, done, interrupted, changed, running), and run nothing");
  c->add_option("--stale-after", s->stale_seconds,
                "a lock held from another host that its holder has not refreshed for this many seconds is stale and taken over (the "
                "holder refreshes it every 30 s; on this host a lock is stale as soon as its process is gone)")
      ->check(CLI::PositiveNumber);
  c->add_option("--summary", s->summary, "also write the summary as JSON to this file");
  c->callback([s, c] { run_batch_command(*s, c); });
}

}  // namespace anisocap::commands
