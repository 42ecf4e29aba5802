// Per-texel optimisation cost: one refine step against the fused loss + gradient it is built on,
// on a 256 x 256 procedural material with 12 inputs (set alpha), and a refine with texel freezing.
// fused_loss_masks: the same loss with a mask per photograph, as a capture passes them: all ones
// (no pixel clipped: the loss skips them) or one pixel left out of each (the loss reads them).
#include <benchmark/benchmark.h>
#include <omp.h>

#include <algorithm>
#include <vector>

#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;

namespace {
constexpr int size = 256, images = 12;

struct scene {
  material_maps truth = generate_material(7, size, size);
  capture cap = set_alpha(images, 7, size, size);
  loss_targets targets = make_loss_targets(render(truth, cap));
};
const scene& shared_scene() {
  static const scene s;
  return s;
}

void fused_loss(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const scene& s = shared_scene();
  material_maps guess = initial_guess(s.cap, render(s.truth, s.cap));
  material_maps grad(size, size);
  for (auto _ : state) benchmark::DoNotOptimize(loss_and_gradient(guess, s.cap, s.targets, &grad));
  state.counters["evals_per_second"] = benchmark::Counter(double(size) * size * images * double(state.iterations()), benchmark::Counter::kIsRate);
}

void fused_loss_masks(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const scene& s = shared_scene();
  material_maps guess = initial_guess(s.cap, render(s.truth, s.cap));
  material_maps grad(size, size);
  std::vector<image> masks(images, image(size, size, 1));
  for (image& m : masks) {
    std::fill(m.plane(0), m.plane(0) + m.pixel_count(), 1.0f);
    if (state.range(1)) m.at(0, 5, 5) = 0.0f;
  }
  const loss_targets targets = make_loss_targets(render(s.truth, s.cap), masks);
  for (auto _ : state) benchmark::DoNotOptimize(loss_and_gradient(guess, s.cap, targets, &grad));
  state.counters["evals_per_second"] = benchmark::Counter(double(size) * size * images * double(state.iterations()), benchmark::Counter::kIsRate);
}

void refine_step(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const scene& s = shared_scene();
  material_maps guess = initial_guess(s.cap, render(s.truth, s.cap));
  refine_options o;
  o.steps = 10;
  for (auto _ : state) {
    material_maps m = guess;
    benchmark::DoNotOptimize(refine(m, s.cap, s.targets, o));
  }
  // One iteration is 10 steps plus the final loss evaluation.
  state.counters["steps_per_second"] = benchmark::Counter(10.0 * double(state.iterations()), benchmark::Counter::kIsRate);
}

// A refine with texel freezing (refine_options::freeze_tolerance) from maps near convergence (the
// first guess refined for 300 steps, as after the network stages): 300 steps, groups checked every
// 25; the counters give the steps per second and the share of texel-steps evaluated.
void refine_frozen(benchmark::State& state) {
  omp_set_num_threads(int(state.range(0)));
  const scene& s = shared_scene();
  static const material_maps guess = [&] {
    material_maps m = initial_guess(s.cap, render(s.truth, s.cap));
    refine_options o;
    o.steps = 300;
    refine(m, s.cap, s.targets, o);
    return m;
  }();
  refine_options o;
  o.steps = 300;
  o.freeze_tolerance = 0.002;
  double evaluated = 0;
  for (auto _ : state) {
    material_maps m = guess;
    const refine_result r = refine(m, s.cap, s.targets, o);
    evaluated = r.evaluated_fraction;
  }
  state.counters["steps_per_second"] = benchmark::Counter(300.0 * double(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["evaluated_fraction"] = evaluated;
}
}  // namespace

BENCHMARK(fused_loss)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(fused_loss_masks)->ArgNames({"threads", "pixel_left_out"})->ArgsProduct({{1, 2}, {0, 1}})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(refine_step)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(refine_frozen)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
