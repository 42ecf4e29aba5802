// The decoder fine-tune step (docs/method.md section 8.3), taken apart: decode forward, maps from the network
// outputs, fused image loss + gradient, the chain rule back to the network outputs, backward
// through the decoder, Adam. For the compact preset (shipped weights) and the paper preset
// (seeded initial weights: the step's cost does not depend on the weights' values), on a
// 256 x 256 procedural tile with 12 inputs (set alpha), whole-tile steps and crop steps
// (finetune_crop_options). Prints medians of --repeats steps after --warmup steps, in ms,
// and the ratios that matter: a crop step against a whole step, the paper preset against compact.
//
// usage: anisocap_study_finetune_step [--size 256] [--repeats 40] [--warmup 8] [--crop 4] [--models DIR]
//                                     [--precision fp32|bf16] [--presets compact,paper]
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "anisocap/data/procedural.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
using clock_type = std::chrono::steady_clock;

#ifndef ANISOCAP_SWEEP_MODELS
#define ANISOCAP_SWEEP_MODELS "models"
#endif

namespace {

double ms_between(clock_type::time_point a, clock_type::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

struct step_times {
  std::vector<double> decode, to_maps, loss, chain, backward, adam, total, crop;
};

template <class P>
step_times time_steps(auto_encoder<P>& ae, int size, int repeats, int warmup, int crop) {
  const std::uint64_t seed = 920000;
  const material_maps truth = generate_material(seed, size, size);
  capture cap = set_alpha(12, seed, size, size);
  std::vector<image> photos = render(truth, cap);
  apply_exposure(cap, photos, exposure_scale(cap));
  const loss_targets targets = make_loss_targets(photos);
  const auto z = encode(ae, truth);
  ae.freeze_encoder(true);
  nn::adam adam(nn::learning_rate_schedule::constant(1e-5));  // small: the weights barely move while timing
  ae.for_each_decoder_parameter([&](nn::parameter& p) { adam.add(p); });
  material_maps grad(size, size);
  material_maps m;  // one map set for every step, as the pipeline's fine-tune keeps
  step_times st;
  ad::tape t;
  for (int s = 0; s < warmup + repeats; ++s) {
    const auto t0 = clock_type::now();
    t.clear();
    auto y = ae.decode(t, t.leaf(z));
    const auto t1 = clock_type::now();
    const auto u_view = y.value.tile(0, 0, size, size);
    network_space::network_to_maps(u_view, 0, m);
    const auto t2 = clock_type::now();
    loss_and_gradient(m, cap, targets, &grad);
    const auto t3 = clock_type::now();
    auto g_view = y.grad.tile(0, 0, size, size);
    network_space::add_network_gradient(u_view, 0, grad, 1.0, g_view);
    const auto t4 = clock_type::now();
    t.backward();
    const auto t5 = clock_type::now();
    adam.step();
    const auto t6 = clock_type::now();
    if (s >= warmup) {
      st.decode.push_back(ms_between(t0, t1));
      st.to_maps.push_back(ms_between(t1, t2));
      st.loss.push_back(ms_between(t2, t3));
      st.chain.push_back(ms_between(t3, t4));
      st.backward.push_back(ms_between(t4, t5));
      st.adam.push_back(ms_between(t5, t6));
      st.total.push_back(ms_between(t0, t6));
    }
  }
  // Crop steps, windows as the pipeline draws them.
  const int cells = z.width(), k = std::min(crop, cells);  // a square tile: z.height() too
  finetune_crops::scratch scratch;
  for (int s = 0; s < warmup + repeats; ++s) {
    const auto t0 = clock_type::now();
    t.clear();
    const auto win = finetune_crops::random_window(cells, cells, k, k, 1, s);
    finetune_crops::crop_step<all_features>(t, ae, z, win, k, k, size, size, cap, targets, {}, scratch);
    adam.step();
    if (s >= warmup) st.crop.push_back(ms_between(t0, clock_type::now()));
  }
  return st;
}

void print(const char* name, const step_times& s, int crop) {
  std::printf("| %s | %.2f | %.2f | %.2f | %.2f | %.2f | %.2f | **%.2f** | %.2f (k = %d) | %.2f |\n", name, median(s.decode), median(s.to_maps),
              median(s.loss), median(s.chain), median(s.backward), median(s.adam), median(s.total), median(s.crop), crop,
              median(s.crop) / median(s.total));
}

}  // namespace

int main(int argc, char** argv) {
  int size = 256, repeats = 40, warmup = 8, crop = 4;
  std::filesystem::path models = ANISOCAP_SWEEP_MODELS;
  std::string precision = "fp32", presets = "compact,paper";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) { std::fprintf(stderr, "finetune_step: %s needs a value\n", a.c_str()); return 2; }
    if (a == "--size") size = std::stoi(argv[++i]);
    else if (a == "--repeats") repeats = std::stoi(argv[++i]);
    else if (a == "--warmup") warmup = std::stoi(argv[++i]);
    else if (a == "--crop") crop = std::stoi(argv[++i]);
    else if (a == "--models") models = argv[++i];
    else if (a == "--precision") precision = argv[++i];
    else if (a == "--presets") presets = argv[++i];
    else { std::fprintf(stderr, "finetune_step: unknown option %s (see the file comment)\n", a.c_str()); return 2; }
  }
  if (size < 32 || repeats < 1 || warmup < 0 || crop < 1) { std::fprintf(stderr, "finetune_step: bad option values\n"); return 2; }
  const bool run_compact = presets.find("compact") != std::string::npos, run_paper = presets.find("paper") != std::string::npos;
  if (!run_compact && !run_paper) { std::fprintf(stderr, "finetune_step: --presets names neither compact nor paper\n"); return 2; }
  try {
    nn::set_convolution_precision(nn::parse_precision(precision, "--precision"));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "finetune_step: %s\n", e.what());
    return 2;
  }
  std::printf("fine-tune step, %d x %d, 12 inputs, %s convolutions, %d threads, medians of %d steps (ms)\n\n", size, size,
              precision.c_str(), omp_get_max_threads(), repeats);
  std::printf("| preset | decode | to maps | loss + gradient | chain rule | backward | Adam | whole step | crop step | crop / whole |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
  step_times c, p;
  if (run_compact) {
    auto_encoder<autoencoder_compact> compact;
    try {
      nn::load_weights(models / "compact" / "autoencoder.safetensors", compact);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "finetune_step: %s\n", e.what());
      return 1;
    }
    c = time_steps(compact, size, repeats, warmup, crop);
    print("compact", c, crop);
  }
  if (run_paper) {
    auto paper = std::make_unique<auto_encoder<autoencoder_paper>>(1);
    p = time_steps(*paper, size, repeats, warmup, crop);
    print("paper", p, crop);
  }
  if (run_compact && run_paper) std::printf("\npaper / compact whole step: %.2fx\n", median(p.total) / median(c.total));
  if (run_compact) std::printf("5000 steps: compact %.0f s whole, %.0f s crop\n", 5 * median(c.total), 5 * median(c.crop));
  if (run_paper) std::printf("5000 steps: paper %.0f s whole, %.0f s crop\n", 5 * median(p.total), 5 * median(p.crop));
  return 0;
}
