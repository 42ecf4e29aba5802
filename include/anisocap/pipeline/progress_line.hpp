#pragma once
/// @file
/// Progress of a capture as a person reads it: on a terminal one line that updates in place; in a
/// log (not a terminal) one line every few seconds and one at each stage's end, so that a
/// capture's log stays a few dozen lines long. Pass it as capture_options::progress.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

#include "anisocap/nn/progress.hpp"

namespace anisocap {

/// Prints capture progress to a C stream (stderr by default); see the file comment.
class progress_line {
 public:
  /// `every`: seconds between lines when `stream` is not a terminal.
  explicit progress_line(std::FILE* stream = stderr, double every = 5.0)
      : stream_(stream), terminal_(isatty(fileno(stream)) == 1), every_(every) {}

  /// One report of `stage` (estimate, finetune, refine, restart, ...).
  void operator()(const std::string& stage, const optimisation_progress& p) {
    const auto now = std::chrono::steady_clock::now();
    const bool stage_end = p.step >= p.steps;
    const bool new_stage = stage != stage_;
    if (!terminal_ && !stage_end && !new_stage && std::chrono::duration<double>(now - last_).count() < every_) return;
    if (terminal_ && new_stage && open_) std::fputc('\n', stream_);
    stage_ = stage;
    last_ = now;
    char text[200];
    std::snprintf(text, sizeof text, "  %s step %5d/%-5d %3d%%  loss %.5f  %5.1f s left", stage.c_str(), p.step, p.steps,
                  p.steps > 0 ? int(100.0 * p.step / p.steps) : 100, p.loss, p.seconds_left);
    if (terminal_) {
      std::fprintf(stream_, "\r%s\033[K", text);
      open_ = !stage_end;
      if (stage_end) std::fputc('\n', stream_);
    } else {
      std::fprintf(stream_, "%s\n", text);
    }
    std::fflush(stream_);
  }

  /// Ends an open terminal line (call once the capture returns).
  void finish() {
    if (terminal_ && open_) std::fputc('\n', stream_);
    open_ = false;
    std::fflush(stream_);
  }

 private:
  std::FILE* stream_;
  bool terminal_;
  double every_;
  bool open_ = false;
  std::string stage_;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace anisocap
