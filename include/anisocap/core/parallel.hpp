#pragma once
/// @file
/// Independent jobs over threads (OpenMP) where any may throw: the exception of the lowest index
/// that threw is rethrown once every job has ended, as a serial loop would have thrown it.
#include <cstddef>
#include <exception>
#include <vector>

namespace anisocap {

/// Calls `job(i)` for i in [0, n), spread over the OpenMP threads one index at a time (for jobs of
/// unequal size: encoding and writing files). Every job runs even when another throws; then the
/// exception of the lowest index that threw is rethrown. `job` must be safe to call concurrently.
template <class Job>
void for_each_index_in_parallel(std::size_t n, Job&& job) {
  std::vector<std::exception_ptr> failures(n);
#pragma omp parallel for schedule(dynamic, 1) if (n > 1)
  for (std::ptrdiff_t i = 0; i < std::ptrdiff_t(n); ++i) {
    try {
      job(std::size_t(i));
    } catch (...) {
      failures[std::size_t(i)] = std::current_exception();
    }
  }
  for (const std::exception_ptr& failure : failures)
    if (failure) std::rethrow_exception(failure);
}

}  // namespace anisocap
