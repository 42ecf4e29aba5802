// Throughput of the non-convolution layers (nn/layers.hpp) at estimator-sized tensors
// (4 x 128 x 128 x 64 floats, 16 MiB), forward and forward + backward, on 1 and 2 threads, beside
// plain scalar references (the loops a user would write; the compiler may auto-vectorise them);
// and of the fine-tune's network-space conversions (networks/network_space.hpp).
// Counter `gbytes_per_s`: bytes the layer must read and write, per second (these layers are
// memory-bound, so bandwidth is the figure that matters).
#include <benchmark/benchmark.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "anisocap/networks/network_space.hpp"
#include "anisocap/nn/layers.hpp"

using namespace anisocap;

namespace {

constexpr int B = 4, H = 128, W = 128, C = 64;
constexpr double elements = double(B) * H * W * C;

template <int Channels = C>
tensor<Channels> input(int height = H, int width = W) {
  tensor<Channels> x(B, height, width);
  nn::random_generator g(1);
  for (std::size_t i = 0; i < x.size(); ++i) x.data()[i] = float(g.symmetric_uniform());
  return x;
}

/// Runs `step` twice before timing: the first pass sizes the tape's arena, the second consolidates
/// it into one block (and touches its pages), so the timed passes are the steady state of training.
template <class F>
void warm_up(F&& step) {
  step();
  step();
}

void set_counters(benchmark::State& s, double bytes_per_element) {
  s.counters["gbytes_per_s"] = benchmark::Counter(elements * bytes_per_element * 1e-9, benchmark::Counter::kIsIterationInvariantRate);
  s.counters["threads"] = double(s.range(0));
}

// ---- leaky ReLU --------------------------------------------------------------------------------

void leaky_relu_forward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  auto step = [&] {
    t.clear();
    auto y = nn::leaky_relu(t, t.leaf(x), 0.2f);
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  set_counters(s, 8);
}

void leaky_relu_forward_scalar(benchmark::State& s) {
  auto x = input();
  std::vector<float> y(x.size());
  for (auto _ : s) {
    const float* p = x.data();
    for (std::size_t i = 0; i < y.size(); ++i) y[i] = p[i] > 0 ? p[i] : 0.2f * p[i];
    benchmark::DoNotOptimize(y.data());
  }
  s.counters["gbytes_per_s"] = benchmark::Counter(elements * 8e-9, benchmark::Counter::kIsIterationInvariantRate);
}

void leaky_relu_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = nn::leaky_relu(t, t.leaf(x, true), 0.2f);
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  // forward 8 B; gradient zeroing 8 B (input and output grads); backward reads gy, x, gx, writes gx: 16 B
  set_counters(s, 32);
}

// ---- instance norm -----------------------------------------------------------------------------

void instance_norm_forward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  nn::instance_norm<C> norm("in");
  norm.weight.frozen = norm.bias.frozen = true;
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = norm(t, t.leaf(x));
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  set_counters(s, 12);  // two statistics passes and one normalising pass read x; one write
}

// A direct reference: per image and channel, mean and variance over the strided pixels.
void instance_norm_forward_scalar(benchmark::State& s) {
  auto x = input();
  std::vector<float> y(x.size());
  const std::size_t pixels = std::size_t(H) * W;
  for (auto _ : s) {
    for (int b = 0; b < B; ++b)
      for (int c = 0; c < C; ++c) {
        const float* p = x.data() + std::size_t(b) * pixels * C + c;
        float mean = 0, var = 0;
        for (std::size_t i = 0; i < pixels; ++i) mean += p[i * C];
        mean /= float(pixels);
        for (std::size_t i = 0; i < pixels; ++i) var += (p[i * C] - mean) * (p[i * C] - mean);
        const float rstd = 1 / std::sqrt(var / float(pixels) + 1e-5f);
        float* q = y.data() + std::size_t(b) * pixels * C + c;
        for (std::size_t i = 0; i < pixels; ++i) q[i * C] = (p[i * C] - mean) * rstd;
      }
    benchmark::DoNotOptimize(y.data());
  }
  s.counters["gbytes_per_s"] = benchmark::Counter(elements * 12e-9, benchmark::Counter::kIsIterationInvariantRate);
}

void instance_norm_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  nn::instance_norm<C> norm("in");
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = norm(t, t.leaf(x, true));
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  // forward 12 B, grad zeroing 8 B, backward: sums read gy and x (8 B), input pass reads gy, x, gx, writes gx (16 B)
  set_counters(s, 44);
}

// The same number of values with 8 channels (the estimator's narrowest layers): channel counts
// below a register go through the flat pattern path.
void instance_norm_8_channels_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input<8>(H, W * 8);
  nn::instance_norm<8> norm("in");
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = norm(t, t.leaf(x, true));
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  set_counters(s, 44);
}

void batch_norm_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  nn::batch_norm<C> norm("bn");
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = norm(t, t.leaf(x, true));
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  set_counters(s, 44);
}

// ---- fusion and resampling ---------------------------------------------------------------------

void max_over_images_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = nn::max_over_images(t, t.leaf(x, true), 4);
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  // forward reads x (4 B) and writes max and argmax of a quarter; backward reads them per image and writes gx
  set_counters(s, 4 + 2 + 4 + 2 + 8);
}

void upsample_forward_backward(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  auto x = input();
  ad::tape t;
  auto step = [&] {
    t.clear();
    auto y = nn::upsample_nearest2x(t, t.leaf(x, true));
    t.backward();
    benchmark::DoNotOptimize(y.value.data());
  };
  warm_up(step);
  for (auto _ : s) step();
  // forward 4 + 16 B, zeroing 4 + 16 B, backward reads 16 B of gy and gx, writes gx (8 B)
  set_counters(s, 4 + 16 + 4 + 16 + 16 + 8);
}

// ---- network space ------------------------------------------------------------------------------

// The fine-tune's per-step conversions between the decoder's 12 output channels and the maps
// (networks/network_space.hpp), at the default capture's 256 x 256: the maps from the outputs,
// and the chain rule back. Counter `mtexels_per_s`.
constexpr int maps_side = 256;

tensor<parameter_count> decoder_outputs() {
  tensor<parameter_count> u(1, maps_side, maps_side);
  nn::random_generator g(3);
  for (std::size_t i = 0; i < u.size(); ++i) u.data()[i] = float(1.1 * g.symmetric_uniform());
  return u;
}

void set_texel_counter(benchmark::State& s) {
  s.counters["mtexels_per_s"] =
      benchmark::Counter(double(maps_side) * maps_side * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
}

void network_to_maps(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  const auto u = decoder_outputs();
  material_maps maps;
  for (auto _ : s) {
    network_space::network_to_maps(u, 0, maps);
    benchmark::DoNotOptimize(maps.plane(0));
  }
  set_texel_counter(s);
}

// The reference: from_network texel by texel and channel by channel into a new map set.
void network_to_maps_scalar(benchmark::State& s) {
  const auto u = decoder_outputs();
  for (auto _ : s) {
    material_maps maps(maps_side, maps_side);
    for (int y = 0; y < maps_side; ++y)
      for (int x = 0; x < maps_side; ++x) {
        const float* p = u.pixel(0, y, x);
        for (int k = 0; k < parameter_count; ++k) maps.at(k, x, y) = float(network_space::from_network(k, p[k]));
      }
    benchmark::DoNotOptimize(maps.plane(0));
  }
  set_texel_counter(s);
}

void add_network_gradient(benchmark::State& s) {
  omp_set_num_threads(int(s.range(0)));
  const auto u = decoder_outputs();
  tensor<parameter_count> grad(1, maps_side, maps_side);
  material_maps grad_maps(maps_side, maps_side);
  nn::random_generator g(4);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < grad_maps.texel_count(); ++i) grad_maps.plane(k)[i] = float(g.symmetric_uniform());
  for (auto _ : s) {
    network_space::add_network_gradient(u, 0, grad_maps, 1.0, grad);
    benchmark::DoNotOptimize(grad.data());
  }
  set_texel_counter(s);
}

}  // namespace

BENCHMARK(leaky_relu_forward_scalar)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(leaky_relu_forward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(leaky_relu_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(instance_norm_forward_scalar)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(instance_norm_forward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(instance_norm_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(instance_norm_8_channels_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(batch_norm_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(max_over_images_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(upsample_forward_backward)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK(network_to_maps_scalar)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(network_to_maps)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(add_network_gradient)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
