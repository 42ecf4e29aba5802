#pragma once
/// @file
/// Batches of consecutive training steps, the next one built on a second thread while the caller
/// trains on the current one. A batch is a pure function of its step (training.hpp: every random
/// choice depends on (run seed, step, batch entry)), so prefetching changes when a batch is built,
/// never what it holds: a prefetching run is bit-identical to one that builds each batch in turn.
#include <functional>
#include <future>
#include <utility>

#include <omp.h>

namespace anisocap::training {

/// Hands out the batch of each step in turn; with prefetching on, take(step) also starts building
/// the batch of step + 1 on a second thread (below `end`), so that sample generation overlaps the
/// optimiser step. The building thread runs its OpenMP regions on `threads` threads (the caller's
/// own count is untouched). An exception thrown while building a batch surfaces from the take()
/// that asks for it, as the same exception; a batch still being built when the prefetcher is
/// destroyed (an exception in the step, a stopped run) is waited for and dropped.
template <class Batch>
class prefetcher {
 public:
  /// `build(step)` makes the batch of a step; no step at or after `end` is prefetched; `threads`:
  /// OpenMP threads of the building thread (a new thread does not inherit the caller's
  /// omp_set_num_threads, so pass omp_get_max_threads() to build with the caller's count).
  prefetcher(std::function<Batch(long)> build, long end, bool prefetch, int threads)
      : build_(std::move(build)), end_(end), prefetch_(prefetch), threads_(threads) {}
  prefetcher(const prefetcher&) = delete;
  prefetcher& operator=(const prefetcher&) = delete;
  ~prefetcher() {
    if (pending_.valid()) pending_.wait();
  }

  /// The batch of `step` (prefetched when the previous call asked for step - 1, built here
  /// otherwise); starts prefetching step + 1.
  Batch take(long step) {
    Batch batch;
    if (pending_.valid() && pending_step_ == step) {
      batch = pending_.get();  // rethrows what the building thread threw
    } else {
      if (pending_.valid()) pending_.wait();  // a batch of another step: not used
      pending_ = {};
      batch = build_(step);
    }
    if (prefetch_ && step + 1 < end_) {
      pending_step_ = step + 1;
      pending_ = std::async(std::launch::async, [this, next = step + 1] {
        omp_set_num_threads(threads_);  // this thread's OpenMP regions only
        return build_(next);
      });
    }
    return batch;
  }

 private:
  std::function<Batch(long)> build_;
  long end_;
  bool prefetch_;
  int threads_;
  std::future<Batch> pending_;
  long pending_step_ = -1;
};

}  // namespace anisocap::training
