#pragma once
// Bit-for-bit comparisons of the image loss run on at most two OpenMP threads.
#include <omp.h>

#include <algorithm>

namespace anisocap::testing {

/// Runs a scope on at most two OpenMP threads: the loss's reduction over threads adds two partial
/// sums in either order (the same bits), while three or more may be added in a different order from
/// run to run, which would blur a bit-for-bit comparison that has nothing to do with masks.
struct two_threads {
  int saved = omp_get_max_threads();
  two_threads() { omp_set_num_threads(std::min(saved, 2)); }
  ~two_threads() { omp_set_num_threads(saved); }
};

}  // namespace anisocap::testing
