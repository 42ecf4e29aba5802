// Per-texel optimisation cost: one refine step against the fused loss + gradient it is built on,
// on a 256 x 256 procedural material with 12 inputs (set alpha), and a refine with texel freezing.
#include <benchmark/benchmark.h>
#include <omp.h>

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
BENCHMARK(refine_step)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(refine_frozen)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
