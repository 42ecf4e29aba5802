// Training-step cost of the networks (networks/estimator.hpp, training/training.hpp): one Adam step
// (forward, backward through the render loss and L1, update) of the compact and paper presets,
// without sample generation, and the cost of generating one training sample (material, 5 inputs,
// render-loss targets). Counter `samples_per_s`: materials per second (an estimator sample is a
// set of 5 input images). The paper preset runs once per repetition (it takes seconds).
// Arguments: size, batch, loss (1: L1 + render loss, as training does; 0: L1 in network space only,
// the loss studies/networks_torch.py gives the same networks in PyTorch). Counter `parameters`: the
// trainable parameter count (networks_torch.py checks its PyTorch networks against it).
// `--network-precision=bf16` (the first argument) runs every step's convolutions in bf16
// (nn/precision.hpp; builds for CPUs with AVX-512 BF16).
#include <benchmark/benchmark.h>
#include <omp.h>

#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <memory>
#include <vector>

#include "anisocap/training/training.hpp"

using namespace anisocap;

namespace {

/// Trainable parameters of a network.
template <class Net>
double parameter_total(Net& net) {
  std::size_t n = 0;
  net.for_each_parameter([&](auto& p) { n += p.size(); });
  return double(n);
}

/// The L1 part of training::map_losses alone: mean |u - truth| in network space, its gradient added.
void l1_loss(const tensor<parameter_count>& u, const std::vector<training::sample>& s, tensor<parameter_count>& grad) {
  const std::size_t n = std::size_t(u.height()) * u.width() * parameter_count;
  const float step = float(1.0 / (double(n) * u.batch()));
  for (int b = 0; b < u.batch(); ++b) {
    const float* p = u.pixel(b, 0, 0);
    const float* q = s[b].truth_net.data();
    float* g = grad.pixel(b, 0, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const float d = p[i] - q[i];
      g[i] += d > 0 ? step : (d < 0 ? -step : 0.0f);
    }
  }
}

/// The loss of argument 2: training's (L1 + render) or L1 only.
void step_loss(const tensor<parameter_count>& u, const std::vector<training::sample>& s, tensor<parameter_count>& grad,
          bool render) {
  if (render)
    training::map_losses(u, s, &grad);
  else
    l1_loss(u, s, grad);
}

std::vector<training::sample> samples(int batch, int size, bool photos) {
  std::vector<training::sample> s;
  for (int b = 0; b < batch; ++b) s.push_back(training::make_sample(training::training_seed(7, 0, b), size, photos));
  return s;
}

/// One estimator training step on fixed samples (what train_estimator does after generating them).
template <class Preset>
void estimator_step(benchmark::State& state) {
  const int size = int(state.range(0)), batch = int(state.range(1));
  const bool render = state.range(2) != 0;
  auto net = std::make_unique<estimation_network<Preset>>(1);
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
    step_loss(y.value, s, y.grad, render);
    t.backward();
    opt.step();
  };
  // Two untimed steps: the first sizes the tape's arena in several blocks, the second runs on the one
  // block they are merged into (first touch of its pages); later steps allocate nothing.
  step();
  step();
  for (auto _ : state) step();
  state.counters["samples_per_s"] = benchmark::Counter(double(batch), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["threads"] = omp_get_max_threads();
  state.counters["parameters"] = parameter_total(*net);
}

/// One auto-encoder training step (with the smoothness decode) on fixed samples.
template <class Preset>
void autoencoder_step(benchmark::State& state) {
  const int size = int(state.range(0)), batch = int(state.range(1));
  const bool render = state.range(2) != 0;
  auto net = std::make_unique<auto_encoder<Preset>>(1);
  nn::adam opt(nn::learning_rate_schedule::constant(1e-5));
  opt.add_parameters(*net);
  const auto s = samples(batch, size, false);
  constexpr int Z = auto_encoder<Preset>::latent_channels;
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto x = t.make_variable<parameter_count>(batch, size, size, false);
    for (int b = 0; b < batch; ++b) std::copy_n(s[b].truth_net.data(), s[b].truth_net.size(), x.value.pixel(b, 0, 0));
    auto z = net->encode(t, x);
    auto y = net->decode(t, z);
    step_loss(y.value, s, y.grad, render);
    auto delta = t.make_variable<Z>(z.value.batch(), z.value.height(), z.value.width(), false);
    delta.value.fill(0.01f);
    auto y2 = net->decode(t, nn::add(t, z, delta));
    for (std::size_t i = 0; i < y2.value.size(); ++i) y2.grad.data()[i] = 1e-6f;
    t.backward();
    opt.step();
  };
  step();  // sizes the arena
  step();  // first touch of the merged arena
  for (auto _ : state) step();
  state.counters["samples_per_s"] = benchmark::Counter(double(batch), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["threads"] = omp_get_max_threads();
  state.counters["parameters"] = parameter_total(*net);
}

void sample_generation(benchmark::State& state) {
  const int size = int(state.range(0));
  long seed = 0;
  for (auto _ : state) benchmark::DoNotOptimize(training::make_sample(training::training_seed(3, seed++, 0), size, true));
  state.counters["samples_per_s"] = benchmark::Counter(1, benchmark::Counter::kIsIterationInvariantRate);
}

}  // namespace

// {size, batch, loss}; the training commands' settings are 128 x 2 (estimator) and 128 x 4 (auto-encoder).
BENCHMARK(estimator_step<estimator_compact>)
    ->ArgNames({"size", "batch", "render"})
    ->ArgsProduct({{128, 256}, {2}, {1, 0}})
    ->Args({256, 1, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(estimator_step<estimator_paper>)
    ->ArgNames({"size", "batch", "render"})
    ->ArgsProduct({{256}, {1}, {1, 0}})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(autoencoder_step<autoencoder_compact>)
    ->ArgNames({"size", "batch", "render"})
    ->ArgsProduct({{128}, {4}, {1, 0}})
    ->ArgsProduct({{256}, {1, 4}, {1, 0}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(autoencoder_step<autoencoder_paper>)
    ->ArgNames({"size", "batch", "render"})
    ->ArgsProduct({{256}, {1}, {1, 0}})
    ->Unit(benchmark::kSecond)
    ->Iterations(1)
    ->UseRealTime();
BENCHMARK(sample_generation)->Arg(128)->Arg(256)->Unit(benchmark::kMillisecond)->UseRealTime();

int main(int argc, char** argv) {
  if (argc > 1 && std::strncmp(argv[1], "--network-precision=", 20) == 0) {
    try {
      nn::set_convolution_precision(nn::parse_precision(argv[1] + 20));
    } catch (const std::invalid_argument& e) {
      std::fprintf(stderr, "anisocap_bench_networks: %s\n", e.what());
      return 2;
    }
    for (int i = 1; i + 1 < argc; ++i) argv[i] = argv[i + 1];
    --argc;
  }
  benchmark::AddCustomContext("network_precision", nn::to_string(nn::convolution_precision()));
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
