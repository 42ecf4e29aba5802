#pragma once
/// @file
/// Early stopping of an optimisation on its loss curve, the one rule of the fine-tune and the
/// refine (bench/sweep.cpp replays recorded loss curves with it).
#include <algorithm>

namespace anisocap::nn {

/// Every `patience` steps the loss (the step's own, or with `window_mean` the mean over the last
/// `patience` steps) is compared with the lowest such value so far; the run stops when it improved
/// by less than `tolerance` (0: never stops).
class early_stopping {
 public:
  early_stopping(double tolerance, int patience, bool window_mean = false)
      : tolerance_(tolerance), patience_(patience), window_mean_(window_mean) {}
  /// Feeds the loss of step `step` (counted from 0 over the whole run); true: stop after it.
  bool stop_after(int step, double loss) {
    sum_ += loss;
    if (tolerance_ <= 0 || patience_ <= 0 || (step + 1) % patience_ != 0) return false;
    const double compared = window_mean_ ? sum_ / patience_ : loss;
    sum_ = 0;
    if (compared > best_ * (1.0 - tolerance_)) return true;
    best_ = std::min(best_, compared);
    return false;
  }

 private:
  double tolerance_;
  int patience_;
  bool window_mean_;
  double best_ = 1e300, sum_ = 0;
};

}  // namespace anisocap::nn
