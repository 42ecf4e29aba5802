#pragma once
// Ranks as threads of one process: a communicator (core/distributed.hpp) whose collectives
// exchange pointers between the threads, with MPI's semantics, so that tests of a computation over
// several ranks need no MPI (tests/mpi runs the program under mpirun), and run_on_loopback_ranks,
// which runs one function per rank.
#include <doctest/doctest.h>

#include <barrier>
#include <cstring>
#include <exception>
#include <functional>
#include <numeric>
#include <thread>
#include <vector>

#include "anisocap/core/distributed.hpp"

namespace anisocap::testing {

/// State shared by the threads that stand for the ranks.
struct loopback_world {
  explicit loopback_world(int n) : ranks(n), sync(n), sends(std::size_t(n)), send_counts(std::size_t(n)) {}
  int ranks;
  std::barrier<> sync;
  std::vector<const unsigned char*> sends;
  std::vector<std::vector<std::size_t>> send_counts;
};

/// Rank `me` of a loopback_world: every collective exchanges pointers through the world between two
/// barriers.
class loopback_communicator : public communicator {
 public:
  loopback_communicator(loopback_world& w, int me) : w_(w), me_(me) {}
  int rank() const noexcept override { return me_; }
  int size() const noexcept override { return w_.ranks; }
  void all_gather_bytes(const void* send, void* receive, const std::vector<std::size_t>& counts) const override {
    w_.sends[std::size_t(me_)] = static_cast<const unsigned char*>(send);
    w_.sync.arrive_and_wait();
    auto* out = static_cast<unsigned char*>(receive);
    for (int r = 0; r < w_.ranks; ++r) {
      std::memcpy(out, w_.sends[std::size_t(r)], counts[std::size_t(r)]);
      out += counts[std::size_t(r)];
    }
    w_.sync.arrive_and_wait();
  }
  void all_to_all_bytes(const void* send, const std::vector<std::size_t>& send_counts, void* receive,
                        const std::vector<std::size_t>& receive_counts) const override {
    w_.sends[std::size_t(me_)] = static_cast<const unsigned char*>(send);
    w_.send_counts[std::size_t(me_)] = send_counts;
    w_.sync.arrive_and_wait();
    auto* out = static_cast<unsigned char*>(receive);
    for (int s = 0; s < w_.ranks; ++s) {
      const auto& counts = w_.send_counts[std::size_t(s)];
      const std::size_t offset = std::accumulate(counts.begin(), counts.begin() + me_, std::size_t(0));
      REQUIRE(counts[std::size_t(me_)] == receive_counts[std::size_t(s)]);
      std::memcpy(out, w_.sends[std::size_t(s)] + offset, receive_counts[std::size_t(s)]);
      out += receive_counts[std::size_t(s)];
    }
    w_.sync.arrive_and_wait();
  }
  void broadcast_bytes(void* data, std::size_t bytes, int root) const override {
    if (me_ == root) w_.sends[std::size_t(me_)] = static_cast<const unsigned char*>(data);
    w_.sync.arrive_and_wait();
    if (me_ != root) std::memcpy(data, w_.sends[std::size_t(root)], bytes);
    w_.sync.arrive_and_wait();
  }
  void barrier() const override { w_.sync.arrive_and_wait(); }

 private:
  loopback_world& w_;
  int me_;
};

/// Runs `work(comm)` on `ranks` loopback ranks, one thread each, and waits for them; rethrows the
/// first exception a rank threw.
inline void run_on_loopback_ranks(int ranks, const std::function<void(const communicator&)>& work) {
  loopback_world world(ranks);
  std::vector<std::exception_ptr> errors(static_cast<std::size_t>(ranks));
  std::vector<std::thread> threads;
  for (int r = 0; r < ranks; ++r)
    threads.emplace_back([&, r] {
      const loopback_communicator comm(world, r);
      try {
        work(comm);
      } catch (...) {
        errors[std::size_t(r)] = std::current_exception();
      }
    });
  for (auto& t : threads) t.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
}

}  // namespace anisocap::testing
