// One training step of each compact network (training/training.hpp) split in two: building the
// step's samples (make_batch: procedural materials, the estimator's 5 inputs, the 4 render-loss
// targets) and the network step (estimator_step, autoencoder_step: forward, losses, backward,
// Adam), run one after the other as train_estimator and train_autoencoder do with prefetching
// off. The samples' share of a step is what prefetching them on a second thread can hide at best. Steps of consecutive training
// seeds (different materials each step); prints the mean over --steps steps after the first, in ms.
//
// usage: anisocap_study_training_step [--steps 50] [--size 128] [--batch 2] [--materials original|training]
#include <omp.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "anisocap/training/training.hpp"

using namespace anisocap;
using clock_type = std::chrono::steady_clock;

namespace {

double ms_between(clock_type::time_point a, clock_type::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

struct split {
  double samples = 0, network = 0;  // ms summed over the timed steps
};

/// Times `steps` steps: build(step) then train(step, samples); the first step is not counted.
template <class Train>
split time_steps(const training::train_options& o, bool with_photos, Train train) {
  split s;
  for (long step = 0; step < o.steps; ++step) {
    const auto a = clock_type::now();
    const std::vector<training::sample> samples = training::make_batch(o, step, with_photos);
    const auto b = clock_type::now();
    train(step, samples);
    const auto c = clock_type::now();
    if (step > 0) {
      s.samples += ms_between(a, b);
      s.network += ms_between(b, c);
    }
  }
  return s;
}

void report(const char* name, const training::train_options& o, const split& s) {
  const double n = double(o.steps - 1);
  std::printf("| %s | %d | %d x %d | %.1f | %.1f | %.1f%% |\n", name, omp_get_max_threads(), o.size, o.batch, s.samples / n,
              s.network / n, 100 * s.samples / (s.samples + s.network));
}

}  // namespace

int main(int argc, char** argv) {
  training::train_options o;
  o.steps = 50;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) {
      std::fprintf(stderr, "usage: anisocap_study_training_step [--steps 50] [--size 128] [--batch 2] [--materials original|training]\n");
      return 1;
    }
    const std::string value = argv[++i];
    if (a == "--steps") o.steps = std::atol(value.c_str());
    else if (a == "--size") o.size = std::atoi(value.c_str());
    else if (a == "--batch") o.batch = std::atoi(value.c_str());
    else if (a == "--materials") o.mix = value == "training" ? material_mix::training : material_mix::original;
    else {
      std::fprintf(stderr, "unknown option %s\n", a.c_str());
      return 1;
    }
  }
  if (o.steps < 2 || o.size <= 0 || o.size % 64 != 0 || o.batch < 1) {
    std::fprintf(stderr, "--steps must be at least 2, --size a positive multiple of 64, --batch positive\n");
    return 1;
  }
  std::printf("| network | threads | size x batch | samples ms/step | network ms/step | samples' share |\n|---|---|---|---|---|---|\n");
  {
    estimation_network<estimator_compact> net(1);
    nn::adam opt(nn::learning_rate_schedule::constant(3e-4));
    opt.add_parameters(net);
    ad::tape t;
    report("estimator, compact", o, time_steps(o, true, [&](long, const std::vector<training::sample>& samples) {
      training::estimator_step(t, net, opt, samples);
    }));
  }
  {
    auto_encoder<autoencoder_compact> net(1);
    nn::adam opt(nn::learning_rate_schedule::constant(1e-3));
    opt.add_parameters(net);
    ad::tape t;
    report("auto-encoder, compact", o, time_steps(o, false, [&](long step, const std::vector<training::sample>& samples) {
      training::autoencoder_step(t, net, opt, samples, o, step);
    }));
  }
}
