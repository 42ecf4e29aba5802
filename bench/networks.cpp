// Training-step cost of the networks (pipeline/networks.hpp, pipeline/training.hpp): one Adam step
// (forward, backward through the render loss and L1, update) of the compact and paper presets,
// without sample generation, and the cost of generating one training sample (material, 5 inputs,
// render-loss targets). Counter `samples_per_s`: materials per second (an estimator sample is a
// set of 5 input images). The paper preset runs once per repetition (it takes seconds).
#include <benchmark/benchmark.h>
#include <omp.h>

#include <memory>
#include <vector>

#include "anisocap/pipeline/training.hpp"

using namespace anisocap;

namespace {

std::vector<training::sample> samples(int batch, int size, bool photos) {
  std::vector<training::sample> s;
  for (int b = 0; b < batch; ++b) s.push_back(training::make_sample(training::training_seed(7, 0, b), size, photos));
  return s;
}

/// One estimator training step on fixed samples (what train_estimator does after generating them).
template <class Preset>
void estimator_step(benchmark::State& state) {
  const int size = int(state.range(0)), batch = int(state.range(1));
  auto net = std::make_unique<EstimationNet<Preset>>(1);
  nn::adam opt(nn::learning_rate_schedule::constant(1e-5));
  opt.add_parameters(*net);
  const auto s = samples(batch, size, true);
  const int N = int(s[0].photos.size());
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto x = t.make_variable<3>(batch * N, size, size, false);
    for (int b = 0; b < batch; ++b)
      for (int i = 0; i < N; ++i) network_space::photo_to_network(s[b].photos[i], x.value, b * N + i);
    auto y = net->forward(t, x, N);
    training::map_losses(y.value, s, &y.grad);
    t.backward();
    opt.step();
  };
  step();  // sizes the arena
  for (auto _ : state) step();
  state.counters["samples_per_s"] = benchmark::Counter(double(batch), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["threads"] = omp_get_max_threads();
}

/// One auto-encoder training step (with the smoothness decode) on fixed samples.
template <class Preset>
void autoencoder_step(benchmark::State& state) {
  const int size = int(state.range(0)), batch = int(state.range(1));
  auto net = std::make_unique<AutoEncoder<Preset>>(1);
  nn::adam opt(nn::learning_rate_schedule::constant(1e-5));
  opt.add_parameters(*net);
  const auto s = samples(batch, size, false);
  constexpr int Z = AutoEncoder<Preset>::latent_channels;
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto x = t.make_variable<parameter_count>(batch, size, size, false);
    for (int b = 0; b < batch; ++b) std::copy_n(s[b].truth_net.data(), s[b].truth_net.size(), x.value.pixel(b, 0, 0));
    auto z = net->encode(t, x);
    auto y = net->decode(t, z);
    training::map_losses(y.value, s, &y.grad);
    auto delta = t.make_variable<Z>(z.value.batch(), z.value.height(), z.value.width(), false);
    delta.value.fill(0.01f);
    auto y2 = net->decode(t, nn::add(t, z, delta));
    for (std::size_t i = 0; i < y2.value.size(); ++i) y2.grad.data()[i] = 1e-6f;
    t.backward();
    opt.step();
  };
  step();
  for (auto _ : state) step();
  state.counters["samples_per_s"] = benchmark::Counter(double(batch), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["threads"] = omp_get_max_threads();
}

void sample_generation(benchmark::State& state) {
  const int size = int(state.range(0));
  long seed = 0;
  for (auto _ : state) benchmark::DoNotOptimize(training::make_sample(training::training_seed(3, seed++, 0), size, true));
  state.counters["samples_per_s"] = benchmark::Counter(1, benchmark::Counter::kIsIterationInvariantRate);
}

}  // namespace

BENCHMARK(estimator_step<estimator_compact>)->Args({128, 2})->Args({256, 1})->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(estimator_step<estimator_paper>)->Args({256, 1})->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();
BENCHMARK(autoencoder_step<autoencoder_compact>)->Args({128, 4})->Args({256, 1})->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(autoencoder_step<autoencoder_paper>)->Args({256, 1})->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();
BENCHMARK(sample_generation)->Arg(128)->Arg(256)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
