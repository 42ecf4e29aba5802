// Data-parallel training (train_options::data_parallel): a batch's gradient computed material by
// material (the auto-encoder's batch norm synchronised over the materials) equals the whole
// batch's up to rounding, and a run spread over 1, 2 or 3 ranks ends with the same weights bit for
// bit. The ranks are threads of this process (tests/support/loopback_communicator.hpp);
// tests/mpi/check_training_ranks.sh runs the program under mpirun.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <omp.h>

#include "anisocap/training/training.hpp"
#include "../networks/tiny_presets.hpp"
#include "../support/loopback_communicator.hpp"
#include "../support/temp_folders.hpp"
#include "tiny_options.hpp"

using namespace anisocap;
using anisocap::testing::all_weights;
using anisocap::testing::fresh_folder;
using anisocap::testing::run_on_loopback_ranks;
using anisocap::testing::tiny_options;

namespace {

/// Each trainable parameter's gradient, by name.
template <class Net>
std::vector<std::pair<std::string, std::vector<float>>> gradients(Net& net) {
  std::vector<std::pair<std::string, std::vector<float>>> g;
  net.for_each_parameter([&](nn::parameter& p) {
    if (p.trainable()) g.emplace_back(p.name, std::vector<float>(p.grad.begin(), p.grad.end()));
  });
  return g;
}

template <class Net>
void zero_gradients(Net& net) {
  net.for_each_parameter([](nn::parameter& p) { p.zero_grad(); });
}

/// Checks that every parameter's gradient in `b` is `a`'s up to rounding (relative to the
/// parameter's largest entry, or for a gradient that is zero but for rounding, such as a bias
/// before a normalisation, to the largest entry of all) and that the gradients are not all zero.
void check_close(const std::vector<std::pair<std::string, std::vector<float>>>& a,
                 const std::vector<std::pair<std::string, std::vector<float>>>& b) {
  REQUIRE(a.size() == b.size());
  double largest_of_all = 0;
  for (const auto& [name, g] : a)
    for (float x : g) largest_of_all = std::max(largest_of_all, double(std::abs(x)));
  CHECK(largest_of_all > 0);
  for (std::size_t k = 0; k < a.size(); ++k) {
    CAPTURE(a[k].first);
    REQUIRE(a[k].second.size() == b[k].second.size());
    double largest = 0, difference = 0;
    for (std::size_t i = 0; i < a[k].second.size(); ++i) {
      largest = std::max(largest, double(std::abs(a[k].second[i])));
      difference = std::max(difference, double(std::abs(a[k].second[i] - b[k].second[i])));
    }
    CHECK(difference <= 1e-3 * largest + 1e-5 * largest_of_all);
  }
}

}  // namespace

TEST_CASE("data-parallel training: the estimator's gradient computed material by material is the whole batch's") {
  training::train_options o = tiny_options(fresh_folder("data_parallel_estimator_gradient"), 64);
  o.batch = 3;
  const std::vector<training::sample> samples = training::make_batch(o, 0, true);
  estimation_network<testing::estimator_tiny> net(3);
  ad::tape t;
  const training::loss_terms whole = training::estimator_gradient(t, net, samples, o.loss());
  const auto whole_gradients = gradients(net);
  zero_gradients(net);
  const training::loss_terms parts = training::estimator_gradient_parts(t, net, samples, o.batch, o.loss(), serial_communicator());
  CHECK(parts.total == doctest::Approx(whole.total).epsilon(1e-6));
  CHECK(parts.l1 == doctest::Approx(whole.l1).epsilon(1e-6));
  CHECK(parts.render == doctest::Approx(whole.render).epsilon(1e-6));
  check_close(whole_gradients, gradients(net));
  // A rank's materials must be its share of the batch.
  CHECK_THROWS_AS(training::estimator_gradient_parts(t, net, std::span(samples).first(2), o.batch, o.loss(), serial_communicator()),
                  std::invalid_argument);
}

TEST_CASE("data-parallel training: the auto-encoder's gradient with its batch norm synchronised over the materials is the whole batch's") {
  training::train_options o = tiny_options(fresh_folder("data_parallel_autoencoder_gradient"), 64);
  o.batch = 3;
  o.smoothness_weight = 0.5;
  const std::vector<training::sample> samples = training::make_batch(o, 0, false);
  auto_encoder<testing::autoencoder_tiny> whole_net(3), parts_net(3);
  ad::tape t;
  const training::loss_terms whole = training::autoencoder_gradient(t, whole_net, samples, o, 7);
  const training::loss_terms parts = training::autoencoder_gradient_parts(t, parts_net, samples, o.batch, o, 7, serial_communicator());
  CHECK(parts.total == doctest::Approx(whole.total).epsilon(1e-5));
  CHECK(parts.smoothness == doctest::Approx(whole.smoothness).epsilon(1e-5));
  CHECK(parts.smoothness > 0);
  check_close(gradients(whole_net), gradients(parts_net));
  // The running statistics move alike (momentum 0.1 towards the batch's mean and unbiased variance).
  for (int c = 0; c < auto_encoder<testing::autoencoder_tiny>::latent_channels; ++c) {
    CHECK(parts_net.latent_norm.running_mean.value[c] == doctest::Approx(whole_net.latent_norm.running_mean.value[c]).epsilon(1e-4));
    CHECK(parts_net.latent_norm.running_var.value[c] == doctest::Approx(whole_net.latent_norm.running_var.value[c]).epsilon(1e-4));
  }
  CHECK(parts_net.latent_norm.running_var.value[0] != 1.0f);
}

TEST_CASE("data-parallel training: 1, 2 and 3 ranks end with the same weights bit for bit, as one process does") {
  // One OpenMP thread per rank: the convolutions' sums depend on the thread count, not the ranks'.
  auto train_on = [](int ranks, const char* network) {
    const auto dir = fresh_folder(std::string("data_parallel_") + network + "_" + std::to_string(ranks));
    std::vector<std::vector<float>> weights(static_cast<std::size_t>(ranks));
    run_on_loopback_ranks(ranks, [&](const communicator& comm) {
      omp_set_num_threads(1);
      training::train_options o = tiny_options(dir, 64);
      o.smoothness_weight = 0.5;  // the auto-encoder's latent smoothness term, its deltas dealt out too
      o.batch = 3;
      o.steps = 3;
      o.data_parallel = true;
      if (network == std::string("estimator")) {
        estimation_network<testing::estimator_tiny> net(o.seed);
        training::train_estimator(o, net, comm);
        weights[std::size_t(comm.rank())] = all_weights(net);
      } else {
        auto_encoder<testing::autoencoder_tiny> net(o.seed);
        training::train_autoencoder(o, net, comm);
        weights[std::size_t(comm.rank())] = all_weights(net);
      }
    });
    for (const auto& w : weights) CHECK(w == weights[0]);  // every rank holds the same network
    CHECK(std::filesystem::exists(dir / (std::string(network == std::string("estimator") ? "estimator" : "autoencoder") + ".safetensors")));
    return weights[0];
  };
  for (const char* network : {"estimator", "autoencoder"}) {
    CAPTURE(network);
    const std::vector<float> one = train_on(1, network);
    CHECK(train_on(2, network) == one);
    CHECK(train_on(3, network) == one);
    // The weights moved: the runs trained.
    std::vector<float> start;
    if (network == std::string("estimator")) {
      estimation_network<testing::estimator_tiny> net(5);
      start = all_weights(net);
    } else {
      auto_encoder<testing::autoencoder_tiny> net(5);
      start = all_weights(net);
    }
    CHECK(start != one);
  }
}
