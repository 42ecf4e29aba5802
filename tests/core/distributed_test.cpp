// Tests for core/distributed.hpp: ordered_sum gives the single process's bits on any number of
// ranks. The ranks here are threads of one process sharing buffers (a loopback communicator with
// the same collective semantics as MPI's), so the test needs no MPI; tests/mpi runs the program
// under mpirun.
#include <doctest/doctest.h>

#include <atomic>
#include <barrier>
#include <cmath>
#include <cstring>
#include <numeric>
#include <thread>
#include <vector>

#include "anisocap/core/distributed.hpp"
#include "anisocap/core/random.hpp"
#include "../support/loopback_communicator.hpp"

using namespace anisocap;
using anisocap::testing::loopback_communicator;
using anisocap::testing::loopback_world;

namespace {

/// Parts of n floats of widely different magnitudes, so that the order of additions shows in the bits.
std::vector<float> make_parts(int parts, std::size_t n) {
  random_generator g(7);
  std::vector<float> v(std::size_t(parts) * n);
  for (float& x : v) x = float((g.uniform() - 0.5) * std::pow(10.0, 6.0 * g.uniform() - 3.0));
  return v;
}

/// ordered_sum on `ranks` loopback ranks; every rank's result.
std::vector<std::vector<float>> sum_on(int ranks, int parts, std::size_t n, const std::vector<float>& all) {
  loopback_world world(ranks);
  std::vector<std::vector<float>> results(std::size_t(ranks), std::vector<float>(n, 0.0f));
  std::vector<std::thread> threads;
  for (int r = 0; r < ranks; ++r)
    threads.emplace_back([&, r] {
      const loopback_communicator comm(world, r);
      const auto [first, last] = part_range(parts, ranks, r);
      const std::span<const float> local(all.data() + std::size_t(first) * n, std::size_t(last - first) * n);
      ordered_sum<float>(comm, parts, n, local, results[std::size_t(r)]);
    });
  for (auto& t : threads) t.join();
  return results;
}

}  // namespace

TEST_CASE("ordered_sum: any rank count gives the single process's bits, on every rank") {
  for (int parts : {1, 2, 3, 5, 8, 13, 16}) {
    const std::size_t n = 37;  // not a multiple of any rank count: uneven element slices
    const std::vector<float> all = make_parts(parts, n);
    std::vector<float> serial(n);
    ordered_sum<float>(serial_communicator(), parts, n, all, serial);
    // The tree's sum, up to rounding, is the plain sum.
    for (std::size_t i = 0; i < n; ++i) {
      double exact = 0, magnitude = 0;
      for (int p = 0; p < parts; ++p) {
        exact += all[std::size_t(p) * n + i];
        magnitude += std::abs(all[std::size_t(p) * n + i]);
      }
      CHECK(std::abs(serial[i] - exact) <= 1e-6 * magnitude);
    }
    for (int ranks : {1, 2, 3, 4, 7, 20}) {
      CAPTURE(parts);
      CAPTURE(ranks);
      for (const auto& r : sum_on(ranks, parts, n, all)) CHECK(std::memcmp(r.data(), serial.data(), n * sizeof(float)) == 0);
    }
  }
}

TEST_CASE("ordered_sum: vectors shorter than the rank count (a loss: one element)") {
  for (int parts : {1, 4, 16}) {
    const std::vector<float> all = make_parts(parts, 1);
    std::vector<float> serial(1);
    ordered_sum<float>(serial_communicator(), parts, 1, all, serial);
    for (int ranks : {2, 4, 5})
      for (const auto& r : sum_on(ranks, parts, 1, all)) CHECK(r[0] == serial[0]);
  }
}

TEST_CASE("ordered_sum: the order matters, so the tree is not the left-to-right sum") {
  const int parts = 16;
  const std::size_t n = 256;
  const std::vector<float> all = make_parts(parts, n);
  std::vector<float> tree(n);
  ordered_sum<float>(serial_communicator(), parts, n, all, tree);
  int differ = 0;
  for (std::size_t i = 0; i < n; ++i) {
    float left_to_right = 0;
    for (int p = 0; p < parts; ++p) left_to_right += all[std::size_t(p) * n + i];
    differ += left_to_right != tree[i];
  }
  CHECK(differ > 0);  // else the equality above would prove nothing
}

TEST_CASE("part_range spreads parts evenly and in order; the serial communicator is rank 0 of 1") {
  int next = 0;
  for (int r = 0; r < 3; ++r) {
    const auto [first, last] = part_range(10, 3, r);
    CHECK(first == next);
    CHECK(last - first >= 3);
    next = last;
  }
  CHECK(next == 10);
  CHECK(part_range(2, 4, 0).first == part_range(2, 4, 0).second);  // more ranks than parts: some hold none
  const communicator& one = serial_communicator();
  CHECK(one.rank() == 0);
  CHECK(one.size() == 1);
  CHECK(one.root());
  CHECK_FALSE(one.distributed());
  std::vector<double> v{1, 2, 3}, gathered;
  one.all_gather<double>(v, gathered, {3});
  CHECK(gathered == v);
  CHECK_THROWS_AS(part_range(3, 0, 0), std::invalid_argument);
}

TEST_CASE("root_decides: rank 0 alone asks, every rank gets its answer") {
  for (const bool answer : {true, false}) {
    loopback_world world(3);
    std::atomic<int> asked{0};
    std::vector<int> results(3, -1);
    std::vector<std::thread> threads;
    for (int r = 0; r < 3; ++r)
      threads.emplace_back([&, r] {
        const loopback_communicator comm(world, r);
        // Each rank would answer differently: only rank 0's answer may count.
        results[std::size_t(r)] = comm.root_decides([&] {
          ++asked;
          return r == 0 ? answer : !answer;
        });
      });
    for (auto& t : threads) t.join();
    CHECK(asked == 1);
    CHECK(results == std::vector<int>(3, answer ? 1 : 0));
  }
  CHECK(serial_communicator().root_decides([] { return true; }));
  CHECK_FALSE(serial_communicator().root_decides([] { return false; }));
}
