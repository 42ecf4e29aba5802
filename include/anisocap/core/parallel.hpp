#pragma once
/// @file
/// Independent jobs over threads (OpenMP) where any may throw: the exception of the lowest index
/// that threw is rethrown once every job has ended, as a serial loop would have thrown it.
#include <algorithm>
#include <cstddef>
#include <exception>
#include <functional>
#include <numeric>
#include <utility>
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

/// Jobs gathered from several producers and run together, so that no thread waits at the end of
/// each producer's share: a capture's files (maps, uncertainty, re-renders, contact sheet, novel
/// views), each encoded on one thread, run as one list. `run` starts the costliest first (a long
/// job started last would leave the other threads idle while it finishes).
class job_batch {
 public:
  /// Adds `job`, with its cost in any unit (only the order of the costs matters). A job must be
  /// safe to run concurrently with the others, and what it reads must live until `run` returns.
  void add(std::function<void()> job, double cost) { jobs_.push_back({std::move(job), cost}); }
  /// The jobs not yet run.
  std::size_t size() const { return jobs_.size(); }
  /// Runs every job on the OpenMP threads, the costliest first (ties in the order added), and
  /// empties the batch. Every job runs even when another throws; then the exception of the first
  /// job added that threw is rethrown.
  void run() {
    std::vector<entry> jobs = std::move(jobs_);
    jobs_.clear();
    std::vector<std::size_t> order(jobs.size());
    std::iota(order.begin(), order.end(), std::size_t(0));
    std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return jobs[a].cost > jobs[b].cost; });
    std::vector<std::exception_ptr> failures(jobs.size());
    for_each_index_in_parallel(order.size(), [&](std::size_t i) {
      try {
        jobs[order[i]].job();
      } catch (...) {
        failures[order[i]] = std::current_exception();
      }
    });
    for (const std::exception_ptr& failure : failures)
      if (failure) std::rethrow_exception(failure);
  }

 private:
  struct entry {
    std::function<void()> job;
    double cost;
  };
  std::vector<entry> jobs_;
};

}  // namespace anisocap
