#pragma once
// The capture options the pipeline tests' bounds were measured with: the paper's fine-tune
// schedule (7.5e-4, no warm-up; each test sets its own step count), refine_options' own defaults
// (1000 steps at 0.03), no neighbourhood restarts and the full kernel.
#include "anisocap/pipeline/capture.hpp"

namespace anisocap::testing {

inline capture_options measured_capture_options() {
  capture_options o;
  o.finetune = finetune_options::paper();
  o.refine = refine_options{};
  o.neighbour_restarts.clear();
  o.kernel = kernel_options::parse("full");
  return o;
}

}  // namespace anisocap::testing
