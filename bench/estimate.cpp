// The estimate stage's memory behaviour: a sliding-window estimate (256 x 256 windows, stride 64)
// of a 384 x 384 sample from 8 photographs with the shipped estimator, steady state. Reports the
// page faults per estimate (getrusage: minor + major) next to the time. The estimator keeps its
// inference tape across windows and calls (estimation_network::estimate), so after the first
// call an estimate should fault in (almost) nothing. keep_tape:0 frees that tape before every
// window (estimation_network::release_scratch), as a fresh tape per window did.
// bf16:1 runs the estimator's convolutions in bf16 (nn/precision.hpp).
#include <benchmark/benchmark.h>
#include <omp.h>
#include <sys/resource.h>

#include <cmath>
#include <filesystem>

#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/presets.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/networks.hpp"

using namespace anisocap;

namespace {
constexpr int size = 384, images = 8;
using estimator = estimation_network<estimator_compact_orientation_doubled_angle>;

long page_faults() {
  rusage r{};
  getrusage(RUSAGE_SELF, &r);
  return r.ru_minflt + r.ru_majflt;
}

std::vector<image> photographs() {
  std::vector<image> photos;
  for (int k = 0; k < images; ++k) {
    image im(size, size, 3);
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) im.at(c, x, y) = 0.2f + 0.1f * std::sin(0.05f * float(x * (k + 1)) + 0.07f * float(y) + float(c));
    photos.push_back(im);
  }
  return photos;
}

/// range(0): threads; range(1): 1 = keep the tape between windows, 0 = free it before each window;
/// range(2): 1 = the convolutions in bf16 (nn/precision.hpp), 0 = FP32.
void sliding_window_estimate(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const bool keep = state.range(1) != 0;
  if (state.range(2) != 0 && !nn::bf16_available()) {
    state.SkipWithError("this build has no AVX-512 BF16");
    return;
  }
  nn::precision_scope precision(state.range(2) != 0 ? nn::precision::bf16 : nn::precision::fp32);
  static const std::vector<image> photos = photographs();
  estimator net;
  nn::load_weights(find_models_folder() / "compact" / "estimator.safetensors", net);
  auto window = [&](const std::vector<image>& crops) {
    if (!keep) net.release_scratch();
    return net.estimate(crops);
  };
  (void)estimate_by_windows(photos, 256, 64, window);  // warm-up: the tape and the allocator reach their sizes
  long faults = 0;
  for (auto _ : state) {
    const long before = page_faults();
    benchmark::DoNotOptimize(estimate_by_windows(photos, 256, 64, window));
    faults += page_faults() - before;
  }
  state.counters["page_faults_per_estimate"] = double(faults) / double(state.iterations());
  state.counters["windows"] = double(window_starts(size, 256, 64).size() * window_starts(size, 256, 64).size());
}
}  // namespace

BENCHMARK(sliding_window_estimate)->ArgsProduct({{1, 2}, {1, 0}, {0, 1}})->ArgNames({"threads", "keep_tape", "bf16"})->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_MAIN();
