// nn/part_gradients.hpp: parts taken from the parameters' gradients, summed over 1, 2 and 3
// ranks to the same bits, losses of a struct of doubles summed field by field, frozen parameters
// left out, and a part of another rank refused.
#include <doctest/doctest.h>

#include <cmath>
#include <mutex>
#include <stdexcept>
#include <utility>
#include <vector>

#include "../support/loopback_communicator.hpp"
#include "anisocap/nn/part_gradients.hpp"

using namespace anisocap;
using anisocap::testing::run_on_loopback_ranks;

namespace {

struct two_terms {
  double total = 0, extra = 0;
};

/// Part k's gradient of value i: irrational steps, so that the order of the additions shows in the bits.
float gradient_of(int k, std::size_t i) { return float(std::sin(0.7 * k + 1.3 * double(i)) * std::pow(10.0, (k % 3) - 1)); }

/// One step of `parts` parts on this rank: the parameters' summed gradient (a, then b) and the loss.
std::pair<std::vector<float>, two_terms> step(const communicator& comm, int parts) {
  nn::parameter a("a", {7}), b("b", {2, 3}), frozen("frozen", {4});
  frozen.frozen = true;
  nn::part_gradients<two_terms> sum(nn::trainable_parameters([&](auto&& f) {
                                      f(a);
                                      f(frozen);
                                      f(b);
                                    }),
                                    comm);
  sum.start(parts);
  for (int k = sum.first(); k < sum.last(); ++k) {
    // A part taken in two pieces adds up (the auto-encoder's decoder, then its encoder).
    for (std::size_t i = 0; i < a.size(); ++i) a.grad[i] = 0.5f * gradient_of(k, i);
    sum.take(k);
    for (std::size_t i = 0; i < a.size(); ++i) {
      REQUIRE(a.grad[i] == 0.0f);  // taken: zeroed
      a.grad[i] = 0.5f * gradient_of(k, i);
    }
    for (std::size_t i = 0; i < b.size(); ++i) b.grad[i] = gradient_of(k, 100 + i);
    for (std::size_t i = 0; i < frozen.size(); ++i) frozen.grad[i] = 99.0f;
    sum.take(k);
    sum.loss(k) = {double(k) + 0.25, 2.0 * k};
  }
  const two_terms loss = sum.sum();
  for (std::size_t i = 0; i < b.size(); ++i) b.grad[i] = -1.0f;  // overwritten by apply()
  sum.apply();
  std::vector<float> out(a.grad.begin(), a.grad.end());
  out.insert(out.end(), b.grad.begin(), b.grad.end());
  for (std::size_t i = 0; i < frozen.size(); ++i) CHECK(frozen.grad[i] == 99.0f);  // never touched
  return {out, loss};
}

}  // namespace

TEST_CASE("part_gradients: the parts' sum is the same bits on 1, 2 and 3 ranks") {
  const int parts = 5;
  const communicator one;
  const auto whole = step(one, parts);
  const std::vector<float>& alone = whole.first;
  const two_terms& loss = whole.second;
  REQUIRE(alone.size() == 13);
  CHECK(loss.total == doctest::Approx(0 + 1 + 2 + 3 + 4 + 5 * 0.25));
  CHECK(loss.extra == doctest::Approx(2.0 * 10));
  // Each value is the sum of its parts (up to rounding: the tree's order is not the loop's).
  for (std::size_t i = 0; i < 7; ++i) {
    double expected = 0;
    for (int k = 0; k < parts; ++k) expected += gradient_of(k, i);
    CHECK(alone[i] == doctest::Approx(expected).epsilon(1e-5));
  }
  for (const int ranks : {2, 3}) {
    std::mutex m;
    run_on_loopback_ranks(ranks, [&](const communicator& comm) {
      const auto spread = step(comm, parts);
      std::lock_guard lock(m);
      CHECK(spread.first == alone);  // bit for bit, on every rank
      CHECK(spread.second.total == loss.total);
      CHECK(spread.second.extra == loss.extra);
    });
  }
}

TEST_CASE("part_gradients: a part another rank holds is refused") {
  run_on_loopback_ranks(2, [](const communicator& comm) {
    nn::parameter a("a", {3});
    nn::part_gradients<double> sum({&a}, comm);
    sum.start(4);  // rank 0: parts 0 and 1; rank 1: 2 and 3
    CHECK(sum.last() - sum.first() == 2);
    const int foreign = comm.rank() == 0 ? 2 : 0;
    CHECK_THROWS_AS(sum.take(foreign), std::logic_error);
    CHECK_THROWS_AS(sum.loss(foreign), std::logic_error);
    for (int k = sum.first(); k < sum.last(); ++k) sum.loss(k) = 1.0;
    CHECK(sum.sum() == 4.0);
  });
}
