// Per-texel optimisation cost: one refine step against the fused loss + gradient it is built on,
// on a 256 x 256 procedural material with 12 inputs (set alpha), and a refine with texel freezing.
// fused_loss_masks: the same loss with a mask per photograph, as a capture passes them: all ones
// (no pixel clipped: the loss skips them), one pixel left out of each (the loss reads the masks in
// one texel group), or a clipped highlight left out of each, a disc of radius 24 texels at a
// different place in each photograph (the loss reads them in the groups the disc touches); with
// flags:0 the targets' all-ones flags are cleared, so that every mask is read everywhere.
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
  for (std::size_t k = 0; k < masks.size(); ++k) {
    image& m = masks[k];
    std::fill(m.plane(0), m.plane(0) + m.pixel_count(), 1.0f);
    if (state.range(1) == 1) m.at(0, 5, 5) = 0.0f;
    if (state.range(1) == 2) {
      const int cx = 32 + int(k) * 16, cy = 224 - int(k) * 16, r = 24;
      for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x)
          if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= r * r) m.at(0, x, y) = 0.0f;
    }
  }
  loss_targets targets = make_loss_targets(render(s.truth, s.cap), masks);
  if (!state.range(2)) targets.mask_all_ones.clear();  // every mask read everywhere
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
BENCHMARK(fused_loss_masks)->ArgNames({"threads", "left_out", "flags"})->ArgsProduct({{1, 2}, {0, 1, 2}, {1, 0}})->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(refine_step)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK(refine_frozen)->Arg(1)->Arg(2)->UseRealTime()->Unit(benchmark::kMillisecond);
BENCHMARK_MAIN();
