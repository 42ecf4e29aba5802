// Fused render + loss + gradient throughput: texel-image evaluations per second, SIMD against the
// scalar build of the same template, specialised kernels against the full one, 1 and 2 threads.
#include <benchmark/benchmark.h>
#include <omp.h>

#include <random>

#include "anisocap/render/renderer.hpp"

using namespace anisocap;

namespace {

material_maps bench_maps(int w, int h, std::uint64_t seed, bool isotropic_flat) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  material_maps m(w, h);
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    for (int c = 0; c < 6; ++c) m.plane(c)[i] = 0.05f + 0.9f * u(gen);
    m.plane(lobe_x)[i] = 0.05f + 0.4f * u(gen);
    m.plane(lobe_y)[i] = isotropic_flat ? m.plane(lobe_x)[i] : 0.05f + 0.4f * u(gen);
    m.plane(fresnel_f0)[i] = isotropic_flat ? 1.0f : 0.05f + 0.9f * u(gen);
    m.plane(normal_x)[i] = isotropic_flat ? 0.0f : 0.3f * (u(gen) - 0.5f);
    m.plane(normal_y)[i] = isotropic_flat ? 0.0f : 0.3f * (u(gen) - 0.5f);
    m.plane(rotation)[i] = isotropic_flat ? 0.0f : 3.0f * (u(gen) - 0.5f);
  }
  return m;
}

capture bench_capture(int n, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  capture c;
  for (int i = 0; i < n; ++i) {
    capture_image im;
    im.camera = {u(gen), u(gen), 1.5f + u(gen)};
    im.light = {-im.camera[0] + 0.2f * u(gen), -im.camera[1] + 0.2f * u(gen), 1.5f + u(gen)};
    im.intensity = {3, 3, 3};
    c.images.push_back(im);
  }
  return c;
}

constexpr int size = 256, images = 12;
constexpr brdf_features specialised{false, false, false};

template <brdf_features F, class V>
void fused(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const bool simple = F == specialised;
  const material_maps maps = bench_maps(size, size, 1, simple);
  const capture cap = bench_capture(images, 2);
  const loss_targets targets = make_loss_targets(render<F>(bench_maps(size, size, 3, simple), cap));
  material_maps grad(size, size);
  render_options options;
  options.cull_tolerance = float(state.range(1)) * 1e-4f;
  options.flush_denormals = state.range(2) != 0;
  for (auto _ : state) benchmark::DoNotOptimize(loss_and_gradient<F, V>(maps, cap, targets, &grad, {}, options));
  state.counters["evals_per_second"] =
      benchmark::Counter(double(size) * size * images * double(state.iterations()), benchmark::Counter::kIsRate);
  state.SetLabel(simd::lanes_v<V> == 1 ? "scalar" : simd::arch_name());
}

template <brdf_features F, class V>
void render_only(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const material_maps maps = bench_maps(size, size, 1, F == specialised);
  const capture cap = bench_capture(images, 2);
  for (auto _ : state) benchmark::DoNotOptimize(render<F, V>(maps, cap));
  state.counters["evals_per_second"] =
      benchmark::Counter(double(size) * size * images * double(state.iterations()), benchmark::Counter::kIsRate);
}

// The FMA peak of one core, for the renderer's roofline: 16 independent chains of fused
// multiply-adds on full registers (enough to hide the FMA latency on current x86 cores).
void fma_peak(benchmark::State& state) {
  using V = simd::batch<float>;
  constexpr int chains = 16, steps = 1024;
  V acc[chains];
  for (int c = 0; c < chains; ++c) acc[c] = V(1.0f + 0.001f * float(c));
  const V a(0.999999f), b(1e-7f);
  for (auto _ : state) {
    for (int s = 0; s < steps; ++s)
      for (int c = 0; c < chains; ++c) acc[c] = simd::fma(acc[c], a, b);
    for (int c = 0; c < chains; ++c) benchmark::DoNotOptimize(acc[c]);
  }
  const double flops = 2.0 * double(simd::lanes_v<V>) * chains * steps;
  state.counters["gflops"] = benchmark::Counter(flops * double(state.iterations()) * 1e-9, benchmark::Counter::kIsRate);
  state.SetLabel(simd::arch_name());
}

}  // namespace

BENCHMARK(fma_peak)->Name("roofline/fma_peak/1_thread");

using simd_v = simd::batch<float>;
// Args: threads, culling tolerance in units of 1e-4 (0: off), flush denormals (1) or not (0).
BENCHMARK(fused<all_features, simd_v>)->Name("fused/full/simd")->ArgNames({"threads", "cull", "ftz"})
    ->Args({1, 0, 1})->Args({2, 0, 1})->Args({2, 0, 0})->Args({2, 10, 1})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(fused<all_features, float>)->Name("fused/full/scalar")->ArgNames({"threads", "cull", "ftz"})
    ->Args({1, 0, 1})->Args({2, 0, 1})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(fused<specialised, simd_v>)->Name("fused/isotropic_nofresnel_flat/simd")->ArgNames({"threads", "cull", "ftz"})
    ->Args({1, 0, 1})->Args({2, 0, 1})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(fused<brdf_features{false, true, true}, simd_v>)->Name("fused/isotropic/simd")->ArgNames({"threads", "cull", "ftz"})
    ->Args({2, 0, 1})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(render_only<all_features, simd_v>)->Name("render/full/simd")->Args({2})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
