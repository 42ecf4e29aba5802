// Thread scaling of every stage of a capture and of a training step, with the serial time of each
// stage measured directly, so that the figure for many threads can be predicted on few cores.
//
//   anisocap_bench_scaling [--threads 1,2,...] [--repetitions R] [--size S] [--images N] [--only NAME]
//
// For each stage and thread count: the median wall time over R repetitions, the speed-up and
// parallel efficiency against one thread, and the serial time: the stage's wall time minus the
// time spent inside OpenMP parallel regions that ran on more than one thread. That time is taken
// by wrapping libgomp's entry points (GOMP_parallel and the combined parallel-loop calls that
// `#pragma omp parallel [for]` compiles to) in this program: the executable's definitions take
// precedence over libgomp's for every call the library's inlined headers make, so the library
// itself carries no instrumentation. A region whose `if` clause is false (libgomp is asked for
// one thread) counts as serial. Amdahl's law then predicts the time on T threads as
// serial + (one-thread time - serial) / T, with the serial time measured at the largest thread
// count run (a region with num_threads(n) computed from the thread count only becomes parallel
// there). The stages are written against the low-level pieces (renderer, networks' forward and
// backward, nn::adam, network space), as the capture and training programs compose them.
#include <dlfcn.h>
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "anisocap/anisocap.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/pipeline/exposure.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/training/training.hpp"

using namespace anisocap;

// ---- time inside parallel regions ---------------------------------------------------------------

namespace region_clock {
/// Seconds spent inside outermost parallel regions that ran on more than one thread.
double parallel_seconds = 0;
/// Seconds spent inside outermost regions that ran on one thread (if clause false): part of the
/// serial time, the part a lower threshold or finer work items could make parallel.
double one_thread_region_seconds = 0;
/// Number of regions that ran on more than one thread, and on one.
long parallel_regions = 0, serial_regions = 0;

template <class Real, class... Args>
void timed(Real real, unsigned num_threads, Args... args) {
  if (omp_in_parallel()) {  // nested: part of the enclosing region's time
    real(args...);
    return;
  }
  const double t0 = omp_get_wtime();
  real(args...);
  const double dt = omp_get_wtime() - t0;
  if (num_threads == 1) {
    one_thread_region_seconds += dt;
    ++serial_regions;
  } else {
    parallel_seconds += dt;
    ++parallel_regions;
  }
}

template <class F>
F next(const char* name) {
  void* f = dlsym(RTLD_NEXT, name);
  if (!f) {
    std::fprintf(stderr, "anisocap_bench_scaling: libgomp has no %s\n", name);
    std::exit(1);
  }
  return reinterpret_cast<F>(f);
}
}  // namespace region_clock

extern "C" {
using region_fn = void (*)(void*);

void GOMP_parallel(region_fn fn, void* data, unsigned num_threads, unsigned flags) {
  using F = void (*)(region_fn, void*, unsigned, unsigned);
  static const F real = region_clock::next<F>("GOMP_parallel");
  region_clock::timed([&](auto... a) { real(a...); }, num_threads, fn, data, num_threads, flags);
}

#define ANISOCAP_WRAP_PARALLEL_LOOP(name)                                                                      \
  void name(region_fn fn, void* data, unsigned num_threads, long start, long end, long incr, long chunk,     \
            unsigned flags) {                                                                                \
    using F = void (*)(region_fn, void*, unsigned, long, long, long, long, unsigned);                        \
    static const F real = region_clock::next<F>(#name);                                                     \
    region_clock::timed([&](auto... a) { real(a...); }, num_threads, fn, data, num_threads, start, end, incr, \
                        chunk, flags);                                                                       \
  }
ANISOCAP_WRAP_PARALLEL_LOOP(GOMP_parallel_loop_static)
ANISOCAP_WRAP_PARALLEL_LOOP(GOMP_parallel_loop_dynamic)
ANISOCAP_WRAP_PARALLEL_LOOP(GOMP_parallel_loop_guided)
ANISOCAP_WRAP_PARALLEL_LOOP(GOMP_parallel_loop_nonmonotonic_dynamic)
ANISOCAP_WRAP_PARALLEL_LOOP(GOMP_parallel_loop_nonmonotonic_guided)
#undef ANISOCAP_WRAP_PARALLEL_LOOP
}

// ---- stages --------------------------------------------------------------------------------------

namespace {

/// A capture of n random configurations over a size x size tile (cameras and lights above it).
capture random_capture(int n, std::uint64_t seed) {
  std::mt19937_64 gen(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  capture c;
  for (int i = 0; i < n; ++i) {
    capture_image im;
    im.camera = {0.6f * u(gen), 0.6f * u(gen), 1.5f + 0.3f * u(gen)};
    im.light = {-im.camera[0] + 0.2f * u(gen), -im.camera[1] + 0.2f * u(gen), 1.5f + 0.3f * u(gen)};
    im.intensity = {3, 3, 3};
    c.images.push_back(im);
  }
  return c;
}

struct stage {
  std::string name;
  std::function<void()> setup;  ///< untimed, before each repetition
  std::function<void()> run;    ///< timed
};

struct measurement {
  double seconds = 0;         ///< median wall time
  double serial_seconds = 0;  ///< median time outside parallel regions that ran on > 1 thread
  double one_thread_region_seconds = 0;  ///< median part of it inside regions that ran on one thread
};

measurement measure(const stage& s, int threads, int repetitions) {
  omp_set_num_threads(threads);
  if (s.setup) s.setup();
  s.run();  // warm-up: arenas, caches, thread pool
  std::vector<double> wall, serial, one_thread;
  for (int r = 0; r < repetitions; ++r) {
    if (s.setup) s.setup();
    const double before = region_clock::parallel_seconds, before_one = region_clock::one_thread_region_seconds;
    const double t0 = omp_get_wtime();
    s.run();
    const double dt = omp_get_wtime() - t0;
    wall.push_back(dt);
    serial.push_back(std::max(0.0, dt - (region_clock::parallel_seconds - before)));
    one_thread.push_back(region_clock::one_thread_region_seconds - before_one);
  }
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  };
  return {median(wall), median(serial), median(one_thread)};
}

std::vector<int> parse_threads(const std::string& s) {
  std::vector<int> out;
  std::size_t p = 0;
  while (p < s.size()) {
    const std::size_t q = s.find(',', p);
    out.push_back(std::stoi(s.substr(p, q == std::string::npos ? std::string::npos : q - p)));
    if (q == std::string::npos) break;
    p = q + 1;
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> threads;
  for (int t = 1; t <= omp_get_num_procs(); t *= 2) threads.push_back(t);
  if (threads.back() != omp_get_num_procs()) threads.push_back(omp_get_num_procs());
  int repetitions = 5, size = 256, images = 12;
  std::string only;  // run only the stages whose name contains this
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "anisocap_bench_scaling: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--threads") threads = parse_threads(value());
    else if (a == "--repetitions") repetitions = std::stoi(value());
    else if (a == "--size") size = std::stoi(value());
    else if (a == "--images") images = std::stoi(value());
    else if (a == "--only") only = value();
    else {
      std::fprintf(stderr, "usage: anisocap_bench_scaling [--threads 1,2,...] [--repetitions R] [--size S] [--images N] [--only NAME]\n");
      return 2;
    }
  }
  if (threads.empty() || threads.front() != 1 || repetitions < 1 || size < 64 || size % 64 != 0 || images < 1) {
    std::fprintf(stderr, "anisocap_bench_scaling: need a thread list starting at 1, repetitions >= 1, size a multiple of 64, images >= 1\n");
    return 2;
  }

  // The capture: a procedural material photographed under `images` configurations.
  const material_maps truth = generate_material(7, size, size);
  const capture cap = random_capture(images, 11);
  const std::vector<image> photos = render(truth, cap);
  const loss_targets targets = make_loss_targets(photos);

  using estimator_net = estimation_network<estimator_compact>;
  using autoencoder_net = auto_encoder<autoencoder_compact>;
  estimator_net estimator(3);
  autoencoder_net autoencoder(5);
  constexpr int Z = autoencoder_net::latent_channels;

  // Encode: the maps in network space through the encoder, inference mode.
  tensor<parameter_count> truth_net(1, size, size);
  network_space::maps_to_network(truth, truth_net, 0);
  tensor<Z, float> z;
  {
    ad::tape t;
    ad::tape::no_grad_guard guard(t);
    autoencoder.set_training(false);
    z = autoencoder.encode(t, t.leaf(truth_net)).value.clone();
  }

  // Fine-tune step pieces: decoder forward, maps from network space, render loss, gradient back
  // into network space, decoder backward, Adam over the decoder's parameters.
  autoencoder.freeze_encoder(true);
  nn::adam decoder_adam(nn::learning_rate_schedule::constant(1e-4));
  autoencoder.for_each_decoder_parameter([&](nn::parameter& p) { decoder_adam.add(p); });
  ad::tape ft_tape;
  ad::variable<parameter_count, float> decoded;
  material_maps ft_maps(size, size), ft_grad(size, size);
  auto decode = [&] {
    ft_tape.clear();
    decoded = autoencoder.decode(ft_tape, ft_tape.leaf(z));
  };
  auto finetune_step = [&] {
    decode();
    ft_maps = network_space::network_to_maps(decoded.value, 0);
    loss_and_gradient(ft_maps, cap, targets, &ft_grad);
    network_space::add_network_gradient(decoded.value, 0, ft_grad, 1.0, decoded.grad);
    ft_tape.backward();
    decoder_adam.step();
  };

  // Training steps (compact presets, 128 x 128): samples, forward, losses, backward, Adam.
  constexpr int train_size = 128;
  std::vector<training::sample> est_samples, ae_samples;
  for (int b = 0; b < 2; ++b) est_samples.push_back(training::make_sample(training::training_seed(1, 0, b), train_size, true));
  for (int b = 0; b < 4; ++b) ae_samples.push_back(training::make_sample(training::training_seed(2, 0, b), train_size, false));
  estimator_net train_estimator(9);
  autoencoder_net train_autoencoder(10);
  nn::adam est_adam(nn::learning_rate_schedule::constant(5e-5)), ae_adam(nn::learning_rate_schedule::constant(1e-3));
  est_adam.add_parameters(train_estimator);
  ae_adam.add_parameters(train_autoencoder);
  ad::tape train_tape;
  auto estimator_training_step = [&] {
    const int n = int(est_samples[0].photos.size()), B = int(est_samples.size());
    train_tape.clear();
    auto x = train_tape.make_variable<3>(B * n, train_size, train_size, false);
    for (int b = 0; b < B; ++b)
      for (int i = 0; i < n; ++i) network_space::photo_to_network(est_samples[b].photos[i], x.value, b * n + i);
    auto y = train_estimator.forward(train_tape, x, n);
    training::map_losses(y.value, est_samples, &y.grad);
    train_tape.backward();
    est_adam.step();
  };
  auto autoencoder_training_step = [&] {
    const int B = int(ae_samples.size());
    train_tape.clear();
    auto x = train_tape.make_variable<parameter_count>(B, train_size, train_size, false);
    for (int b = 0; b < B; ++b)
      std::copy_n(ae_samples[b].truth_net.data(), ae_samples[b].truth_net.size(), x.value.pixel(b, 0, 0));
    train_autoencoder.set_training(true);
    auto y = train_autoencoder.decode(train_tape, train_autoencoder.encode(train_tape, x));
    training::map_losses(y.value, ae_samples, &y.grad);
    train_tape.backward();
    ae_adam.step();
  };

  material_maps refined;
  capture exposed_cap;
  std::vector<image> exposed_photos;
  const std::vector<stage> stages = {
      {"exposure (scale + apply)", [&] { exposed_cap = cap; exposed_photos = photos; },
       [&] { apply_exposure(exposed_cap, exposed_photos, exposure_scale(exposed_cap)); }},
      {"estimate (one window: estimator forward)", {}, [&] { (void)estimator.estimate(photos); }},
      {"encode (maps to network space + encoder)", {},
       [&] {
         tensor<parameter_count> u(1, size, size);
         network_space::maps_to_network(truth, u, 0);
         ad::tape t;
         ad::tape::no_grad_guard guard(t);
         (void)autoencoder.encode(t, t.leaf(u));
       }},
      {"fine-tune step (whole)", {}, finetune_step},
      {"  decoder forward", {}, decode},
      {"  network space -> maps", decode, [&] { ft_maps = network_space::network_to_maps(decoded.value, 0); }},
      {"  render loss + gradient", {}, [&] { loss_and_gradient(ft_maps, cap, targets, &ft_grad); }},
      {"  gradient -> network space", decode,
       [&] { network_space::add_network_gradient(decoded.value, 0, ft_grad, 1.0, decoded.grad); }},
      {"  decoder backward", [&] { decode(); }, [&] { ft_tape.backward(); }},
      {"  Adam (decoder)", {}, [&] { decoder_adam.step(); }},
      {"refine (10 steps)", [&] { refined = truth; },
       [&] {
         refine_options o;
         o.steps = 10;
         refine(refined, cap, targets, o);
       }},
      {"training step, compact estimator, 128 x 2", {}, estimator_training_step},
      {"  Adam (estimator)", {}, [&] { est_adam.step(); }},
      {"training step, compact auto-encoder, 128 x 4", {}, autoencoder_training_step},
      {"training samples (procedural + renders), 128 x 2", {},
       [&] {
         for (int b = 0; b < 2; ++b) (void)training::make_sample(training::training_seed(3, 0, b), train_size, true);
       }},
  };

  std::printf("anisocap_bench_scaling: %d x %d, %d images, compact presets; %d hardware threads, %s; "
              "median of %d repetitions\n\n", size, size, images, omp_get_num_procs(), simd::arch_name(), repetitions);
  std::printf("| stage | threads | ms | speed-up | efficiency | serial ms | of which in one-thread regions | serial fraction of 1-thread time |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  struct row { std::string name; double t1, serial_max; };
  std::vector<row> summary;
  for (const stage& s : stages) {
    if (!only.empty() && s.name.find(only) == std::string::npos) continue;
    double t1 = 0, serial_max = 0;
    for (int th : threads) {
      const measurement m = measure(s, th, repetitions);
      if (th == 1) t1 = m.seconds;
      serial_max = m.serial_seconds;
      std::printf("| %s | %d | %.2f | %.2fx | %.0f%% | %.2f | %.2f | %.1f%% |\n", s.name.c_str(), th, 1e3 * m.seconds,
                  t1 / m.seconds, 100.0 * t1 / m.seconds / th, 1e3 * m.serial_seconds, 1e3 * m.one_thread_region_seconds,
                  100.0 * m.serial_seconds / t1);
      std::fflush(stdout);
    }
    summary.push_back({s.name, t1, serial_max});
  }
  std::printf("\nAmdahl's law from the serial time at %d threads: predicted time T(n) = serial + (T(1) - serial) / n\n\n",
              threads.back());
  std::printf("| stage | 1 thread ms | serial ms | serial fraction | predicted 16 threads ms | predicted speed-up 16 vs 1 | 16 vs 2 |\n");
  std::printf("|---|---|---|---|---|---|---|\n");
  for (const row& r : summary) {
    auto predicted = [&](int n) { return r.serial_max + (r.t1 - r.serial_max) / n; };
    std::printf("| %s | %.2f | %.2f | %.1f%% | %.2f | %.1fx | %.1fx |\n", r.name.c_str(), 1e3 * r.t1, 1e3 * r.serial_max,
                100.0 * r.serial_max / r.t1, 1e3 * predicted(16), r.t1 / predicted(16), predicted(2) / predicted(16));
  }
  std::printf("\nparallel regions timed: %ld on more than one thread, %ld on one (if clause false)\n",
              region_clock::parallel_regions, region_clock::serial_regions);
  return 0;
}
