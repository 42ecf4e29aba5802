#pragma once
/// @file
/// Progress of a long optimisation (training, estimate, fine-tune, refine), reported to a callback.
#include <algorithm>

namespace anisocap {

/// Progress of a long optimisation, reported once per `progress_every` steps.
struct optimisation_progress {
  int step = 0;            ///< steps done
  int steps = 0;           ///< steps planned
  double loss = 0;         ///< image loss at this step
  double seconds = 0;      ///< time since the start
  double steps_per_second = 0;
  double seconds_left = 0; ///< estimate

  /// Progress after `step` of `steps` steps, `seconds` after the start of this run, which began at
  /// step `first` (a resumed run counts its rate from there).
  static optimisation_progress at(int step, int steps, double loss, double seconds, int first = 0) {
    optimisation_progress p;
    p.step = step;
    p.steps = steps;
    p.loss = loss;
    p.seconds = seconds;
    p.steps_per_second = (step - first) / std::max(seconds, 1e-9);
    p.seconds_left = (steps - step) / std::max(p.steps_per_second, 1e-9);
    return p;
  }
};

}  // namespace anisocap
