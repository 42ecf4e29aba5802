// Can the compact estimator learn the rotation alpha at all? Trains it (training::estimator_step,
// the trainers' loss: L1 in network space + render_weight x render loss) on a fixed set of
// procedural materials of one family, cycling through them, and prints every --report steps the
// rotation error of the anisotropic texels (compare_maps' rotation_anisotropic, alpha modulo pi
// and the swapped lobe form) on those training materials and on as many held-out ones of the same
// family. Reading: an error that falls on the training materials says the network can fit the
// rotation of what it has seen; one that falls on the held-out ones says it reads rotation from
// the photographs. pi^2 / 48 = 0.206 is the error of a guess that knows nothing (a difference
// uniform over a quarter turn).
//
// With --preset compact-orientation the estimator also sees each photo's structure-tensor
// orientation channels (network_space::orientation_channels); --init then loads every tensor of
// the file that matches in shape (all but the first encoder layer's weights of a compact file).
//
// usage: anisocap_study_rotation_fit [--preset compact|compact-orientation] [--kind brushed]
//            [--materials 16] [--steps 3000] [--report 250] [--size 128] [--batch 2] [--lr 3e-4]
//            [--render-weight 1] [--init FILE|none]
#include <omp.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "anisocap/render/evaluate.hpp"
#include "anisocap/training/training.hpp"

#ifndef ANISOCAP_SWEEP_MODELS
#define ANISOCAP_SWEEP_MODELS "models"
#endif

using namespace anisocap;

namespace {

/// Mean rotation error over the anisotropic texels of `set`, and the mean |alpha| the network
/// outputs there (near 0 when it has learnt a constant).
template <class Net>
std::pair<double, double> rotation_error(Net& net, const std::vector<training::sample>& set) {
  double error = 0, spread = 0;
  for (const auto& s : set) {
    const auto u = training::estimator_output(net, s);
    const material_maps m = network_space::network_to_maps(u, 0);
    error += compare_maps(m, s.truth).rotation_anisotropic / double(set.size());
    double a = 0;
    for (int y = 0; y < m.height(); ++y)
      for (int x = 0; x < m.width(); ++x) a += std::abs(m.at(rotation, x, y));
    spread += a / (double(m.width()) * m.height()) / double(set.size());
  }
  return {error, spread};
}

struct settings {
  std::string kind_name = "brushed", preset = "compact", init = std::string(ANISOCAP_SWEEP_MODELS) + "/compact/estimator.safetensors";
  int count = 16, size = 128, batch = 2;
  long steps = 3000, every = 250;
  double lr = 3e-4, render_weight = 1;
};

template <class Preset>
int run(const settings& a, const procedural_options& options) {
  // Training and held-out materials from two disjoint seed streams, all of the one kind.
  std::vector<training::sample> train, held_out;
  for (int i = 0; i < a.count; ++i) {
    train.push_back(training::make_sample(hash64(1, i, 0), a.size, true, options));
    held_out.push_back(training::make_sample(hash64(2, i, 0), a.size, true, options));
  }
  estimation_network<Preset> net(1);
  std::string fresh;
  if (a.init != "none")
    for (const auto& name : nn::load_matching_weights(a.init, net)) fresh += (fresh.empty() ? "" : ", ") + name;
  nn::adam opt(nn::learning_rate_schedule::constant(a.lr));
  opt.add_parameters(net);
  ad::tape t;
  std::printf("# %s, preset %s, %d training and %d held-out materials, %d x %d, batch %d, lr %g, render weight %g, init %s%s%s, %d threads\n",
              a.kind_name.c_str(), Preset::name, a.count, a.count, a.size, a.size, a.batch, a.lr, a.render_weight, a.init.c_str(),
              fresh.empty() ? "" : " (initialised afresh: ", fresh.empty() ? "" : (fresh + ")").c_str(), omp_get_max_threads());
  std::printf("step,materials_seen,train_rotation_anisotropic,held_out_rotation_anisotropic,train_mean_abs_alpha,held_out_mean_abs_alpha\n");
  auto report = [&](long step) {
    const auto [te, ts] = rotation_error(net, train);
    const auto [he, hs] = rotation_error(net, held_out);
    std::printf("%ld,%ld,%.4f,%.4f,%.3f,%.3f\n", step, step * a.batch, te, he, ts, hs);
    std::fflush(stdout);
  };
  report(0);
  for (long step = 1; step <= a.steps; ++step) {
    std::vector<training::sample> samples;
    for (int b = 0; b < a.batch; ++b) samples.push_back(train[std::size_t((step * a.batch + b) % a.count)]);
    training::estimator_step(t, net, opt, samples, {.render = a.render_weight});
    if (step % a.every == 0) report(step);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  settings a;
  for (int i = 1; i < argc; ++i) {
    const std::string o = argv[i];
    if (i + 1 >= argc) {
      std::fprintf(stderr, "%s: a value is missing (see the usage at the top of studies/rotation_fit.cpp)\n", o.c_str());
      return 1;
    }
    const std::string v = argv[++i];
    if (o == "--kind") a.kind_name = v;
    else if (o == "--preset") a.preset = v;
    else if (o == "--materials") a.count = std::atoi(v.c_str());
    else if (o == "--steps") a.steps = std::atol(v.c_str());
    else if (o == "--report") a.every = std::atol(v.c_str());
    else if (o == "--size") a.size = std::atoi(v.c_str());
    else if (o == "--batch") a.batch = std::atoi(v.c_str());
    else if (o == "--lr") a.lr = std::atof(v.c_str());
    else if (o == "--render-weight") a.render_weight = std::atof(v.c_str());
    else if (o == "--init") a.init = v;
    else {
      std::fprintf(stderr, "unknown option %s\n", o.c_str());
      return 1;
    }
  }
  procedural_options options;
  options.kind = material_kind_from_name(a.kind_name);
  if (!options.kind || a.count < 1 || a.steps < 1 || a.every < 1 || a.size <= 0 || a.size % 64 != 0 || a.batch < 1 ||
      !(a.lr > 0) || !(a.render_weight >= 0) || (a.preset != "compact" && a.preset != "compact-orientation")) {
    std::fprintf(stderr, "rotation_fit: impossible options (a known --kind and --preset; positive counts; --size a multiple of 64)\n");
    return 1;
  }
  return a.preset == "compact" ? run<estimator_compact>(a, options) : run<estimator_compact_orientation>(a, options);
}
