// Sample prefetching (training/prefetch.hpp, train_options::prefetch): the prefetcher hands out
// each step's batch once, built ahead on another thread, and surfaces a building thread's
// exception as itself; a prefetching trainer ends with exactly the weights of one that builds each
// batch in turn, straight and after a resume.
#include <doctest/doctest.h>
#include <algorithm>
#include <cmath>

#include <filesystem>
#include <fstream>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <omp.h>
#include <unistd.h>

#include "anisocap/training/training.hpp"
#include "../networks/tiny_presets.hpp"
#include "../support/temp_folders.hpp"
#include "tiny_options.hpp"

using namespace anisocap;
namespace fs = std::filesystem;
using anisocap::testing::all_weights;
using anisocap::testing::fresh_folder;

namespace {
std::string file_text(const fs::path& file) {
  std::ifstream in(file);
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

training::train_options tiny_options(const fs::path& dir, int size, bool prefetch) {
  training::train_options o = testing::tiny_options(dir, size);
  o.prefetch = prefetch;
  return o;
}

/// What a test build saw: the steps it was asked for, on which thread, with how many OpenMP threads.
struct build_log {
  std::mutex mutex;
  std::vector<long> steps;
  std::vector<std::thread::id> threads;
  std::vector<int> omp_threads;
};
}  // namespace

TEST_CASE("prefetcher: each step's batch is built once, ahead, on another thread with its own OpenMP count") {
  build_log seen;
  const int caller_threads = omp_get_max_threads();
  {
    training::prefetcher<long> batches(
        [&](long step) {
          std::lock_guard lock(seen.mutex);
          seen.steps.push_back(step);
          seen.threads.push_back(std::this_thread::get_id());
          seen.omp_threads.push_back(omp_get_max_threads());
          return 10 * step;
        },
        5, true, 1);
    for (long step = 2; step < 5; ++step) CHECK(batches.take(step) == 10 * step);
  }
  // Step 2 is built by the caller, 3 and 4 ahead by other threads; step 5 (= end) is never built.
  CHECK(seen.steps == std::vector<long>{2, 3, 4});
  REQUIRE(seen.threads.size() == 3);
  CHECK(seen.threads[0] == std::this_thread::get_id());
  CHECK(seen.threads[1] != std::this_thread::get_id());
  CHECK(seen.threads[2] != std::this_thread::get_id());
  CHECK(seen.omp_threads == std::vector<int>{caller_threads, 1, 1});
  CHECK(omp_get_max_threads() == caller_threads);  // the caller's count is untouched

  // Without prefetching every batch is built by the caller, when asked for.
  build_log serial;
  training::prefetcher<long> in_turn(
      [&](long step) {
        serial.steps.push_back(step);
        serial.threads.push_back(std::this_thread::get_id());
        return step;
      },
      100, false, 1);
  for (long step = 0; step < 3; ++step) CHECK(in_turn.take(step) == step);
  CHECK(serial.steps == std::vector<long>{0, 1, 2});
  for (const auto& id : serial.threads) CHECK(id == std::this_thread::get_id());

  // A step other than the prefetched one is built when asked for (the prefetched one is dropped).
  training::prefetcher<long> jumping([](long step) { return step; }, 100, true, 1);
  CHECK(jumping.take(0) == 0);
  CHECK(jumping.take(7) == 7);
  CHECK(jumping.take(8) == 8);
}

TEST_CASE("prefetcher: an exception in the building thread surfaces as itself from take, never a hang") {
  auto build = [](long step) -> int {
    if (step == 3) throw std::runtime_error("material of step 3 failed");
    return int(step);
  };
  {
    training::prefetcher<int> batches(build, 10, true, 1);
    for (long step = 0; step < 3; ++step) CHECK(batches.take(step) == step);  // step 3 is being built ahead now
    CHECK_THROWS_WITH_AS(batches.take(3), "material of step 3 failed", std::runtime_error);
    CHECK(batches.take(4) == 4);  // the prefetcher is still usable
  }
  {
    // The exception of a batch that is never asked for is dropped with the prefetcher.
    training::prefetcher<int> batches(build, 10, true, 1);
    CHECK(batches.take(2) == 2);
  }
}

TEST_CASE("training with prefetching: an exception in the step's thread leaves through the trainer while a batch is being built") {
  const fs::path dir = fresh_folder("prefetch_throwing");
  auto o = tiny_options(dir, 64, true);
  o.progress_seconds = 0;  // a progress line after every step
  o.log = [](const std::string& line) {
    if (line.find("step 1/") != std::string::npos) throw std::runtime_error("progress log failed");
  };
  estimation_network<testing::estimator_tiny> net(3);
  // The second step's batch was started with the first step; the log throws after the first step,
  // the trainer waits for that batch and the log's exception arrives as itself.
  CHECK_THROWS_WITH_AS(training::train_estimator(o, net), "progress log failed", std::runtime_error);
  fs::remove_all(dir);
}

namespace {
/// Options of the make_batch tests: 32 x 32 materials, run seed 11, `batch` per step.
training::train_options batch_options(int batch) {
  training::train_options o;
  o.size = 32;
  o.batch = batch;
  o.seed = 11;
  return o;
}
}  // namespace

TEST_CASE("make_batch: entry b of a step is the sample of training_seed(seed, step, b)") {
  const auto batch = training::make_batch(batch_options(3), 4, true);
  REQUIRE(batch.size() == 3);
  for (int b = 0; b < 3; ++b) {
    const auto expected = training::make_sample(training::training_seed(11, 4, b), 32, true);
    const auto& s = batch[b];
    CHECK(std::equal(s.truth_net.data(), s.truth_net.data() + s.truth_net.size(), expected.truth_net.data()));
    REQUIRE(s.photos.size() == expected.photos.size());
    for (std::size_t i = 0; i < expected.photos.size(); ++i)
      CHECK(std::equal(s.photos[i].plane(0), s.photos[i].plane(0) + 32 * 32, expected.photos[i].plane(0)));
  }
  // Different steps and entries draw different materials.
  CHECK_FALSE(std::equal(batch[0].truth_net.data(), batch[0].truth_net.data() + batch[0].truth_net.size(), batch[1].truth_net.data()));
}

TEST_CASE("make_batch with input noise: each material's photographs get noise at its own fraction of the levels, the truth stays") {
  training::train_options o = batch_options(4);
  const auto clean = training::make_batch(o, 4, true);
  o.input_noise = {0.05, 0.01};
  const auto noisy = training::make_batch(o, 4, true), again = training::make_batch(o, 4, true);
  REQUIRE(noisy.size() == clean.size());
  std::vector<double> fractions;
  for (int b = 0; b < o.batch; ++b) {
    const auto& c = clean[b];
    const auto& n = noisy[b];
    CHECK(std::equal(n.truth_net.data(), n.truth_net.data() + n.truth_net.size(), c.truth_net.data()));
    // The drawn levels: one fraction in [0, 1) of both.
    const sensor_noise level = training::training_input_noise(o, training::training_seed(11, 4, b));
    CHECK(level.shot >= 0);
    CHECK(level.shot < 0.05);
    CHECK(level.read == doctest::Approx(level.shot / 5));
    fractions.push_back(level.shot / 0.05);
    // Exactly the sensor model at that level on the clean photographs, deterministic, never negative.
    for (std::size_t i = 0; i < c.photos.size(); ++i) {
      const float* p = n.photos[i].plane(0);
      const float* q = c.photos[i].plane(0);
      const float* r = again[b].photos[i].plane(0);
      double change = 0;
      for (int k = 0; k < 32 * 32; ++k) {
        REQUIRE(p[k] >= 0);
        REQUIRE(p[k] == r[k]);
        change += std::abs(double(p[k]) - q[k]);
      }
      CHECK(change > 0);
    }
    std::vector<image> expected = c.photos;
    add_sensor_noise(expected, level, hash64(training::training_seed(11, 4, b) ^ 0x6e6f697365ULL));
    for (std::size_t i = 0; i < c.photos.size(); ++i)
      CHECK(std::equal(expected[i].plane(2), expected[i].plane(2) + 32 * 32, n.photos[i].plane(2)));
  }
  // The fractions differ between materials.
  CHECK(*std::max_element(fractions.begin(), fractions.end()) - *std::min_element(fractions.begin(), fractions.end()) > 0.05);
}

/// Trains Net (built from a seed) serially, with prefetching, and with prefetching stopped after
/// step 2 and resumed; all three must end with the same weights and validation.csv.
template <class Net, class Train>
void check_prefetching_changes_nothing(int size, Train train) {
  const fs::path serial = fresh_folder("prefetch_serial"), ahead = fresh_folder("prefetch_ahead"), resumed = fresh_folder("prefetch_resumed");
  Net a(3), b(3), c(99);
  train(tiny_options(serial, size, false), a);
  train(tiny_options(ahead, size, true), b);
  {
    Net killed(3);
    auto o = tiny_options(resumed, size, true);
    o.stop_after = 2;
    train(o, killed);
  }
  auto o = tiny_options(resumed, size, true);
  o.resume = true;
  train(o, c);
  const auto wa = all_weights(a), wb = all_weights(b), wc = all_weights(c);
  REQUIRE(wa.size() == wb.size());
  REQUIRE(wa.size() == wc.size());
  CHECK(std::equal(wa.begin(), wa.end(), wb.begin()));
  CHECK(std::equal(wa.begin(), wa.end(), wc.begin()));
  CHECK(file_text(serial / "validation.csv") == file_text(ahead / "validation.csv"));
  CHECK(file_text(serial / "validation.csv") == file_text(resumed / "validation.csv"));
  fs::remove_all(serial);
  fs::remove_all(ahead);
  fs::remove_all(resumed);
}

TEST_CASE("training with prefetching: the same weights as without, straight and resumed") {
  SUBCASE("estimator") {
    check_prefetching_changes_nothing<estimation_network<testing::estimator_tiny>>(
        64, [](const training::train_options& o, auto& net) { training::train_estimator(o, net); });
  }
  SUBCASE("auto-encoder") {
    check_prefetching_changes_nothing<auto_encoder<testing::autoencoder_tiny>>(
        32, [](const training::train_options& o, auto& net) { training::train_autoencoder(o, net); });
  }
}
