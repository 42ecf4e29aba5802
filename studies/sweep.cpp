// Run time against error: sweeps the knobs that trade time for accuracy on procedural
// validation materials and writes one CSV row per (material, configuration). studies/sweep_plot.py
// turns the CSV into the plot and the Pareto table of studies/README.md.
//
// Knobs: fine-tune steps (0 ... 5000, the paper's count) and fine-tune early stopping, refine steps,
// refine early stopping, refine texel freezing, specular culling, automatic kernel choice, double
// precision, input count (12 and 8), and the network-free path (first guess + refine).
//
// One fine-tune trajectory per material and input count serves every fine-tune step count: the
// decoder's Adam run does not depend on how many steps are planned, so the maps after k steps are
// the maps a k-step run returns, and its time is the time to reach step k (observer overhead
// excluded). Early stopping is read off the same trajectory with the pipeline's rule.
//
// usage: anisocap_study_sweep [--materials 10] [--size 256] [--max-finetune 5000]
//                             [--finetune-lr 7.5e-4] [--finetune-points 0,200,500,1000,2000,5000]
//                             [--images 12,8] [--networks-only] [--long-refine] [--no-stops]
//                             [--finetune-crop K] [--finetune-warmup W] [--finetune-half-life H]
//                             [--network-precision fp32|bf16] [--models DIR] [--out FILE.csv]
// --long-refine replaces the refine variants tried on the first fine-tune point by longer refines
// (1000, 2000 steps, 2000 with freezing); --plain-refine tries none and 500 refine steps only;
// --no-stops leaves out the fine-tune early-stopping points. --finetune-crop, --finetune-warmup and
// --finetune-half-life set the pipeline options of the same names (crop mini-batches, learning-rate
// warm-up and decay) for the fine-tune trajectory. --network-precision sets the networks'
// convolutions (capture_options::network_precision; written in the network_precision column).
#include <omp.h>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "anisocap/data/image_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/presets.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
namespace fs = std::filesystem;

#ifndef ANISOCAP_SWEEP_MODELS
#define ANISOCAP_SWEEP_MODELS "models"
#endif

namespace {

using clock_type = std::chrono::steady_clock;

/// One refine configuration.
struct refine_variant {
  std::string name;
  int steps = 500;
  double stop = 0;                 // refine early stopping threshold
  double freeze = 0;               // texel freezing threshold
  float cull = 0;                  // specular culling tolerance
  bool double_precision = false;
  double auto_kernel = 0;          // > 0: kernel from analyse_kernel(start maps, tolerance)
};

bool all_finite(const material_maps& m) {
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < m.texel_count(); ++i)
      if (!std::isfinite(m.plane(k)[i])) return false;
  return true;
}

/// The number of updates after which the fine-tune's early stopping (nn/early_stopping.hpp; window
/// means with crops) ends a run with this loss curve.
int stopping_step(const std::vector<double>& losses, double tolerance, bool window_mean, int patience = 200) {
  nn::early_stopping rule(tolerance, patience, window_mean);
  for (int step = 0; step < int(losses.size()); ++step)
    if (rule.stop_after(step, losses[std::size_t(step)])) return step + 1;
  return int(losses.size());
}

struct row_writer {
  std::ostringstream out;
  row_writer() {
    out << "material,seed,truth,images,path,finetune_steps,finetune_stop,finetune_steps_run,refine,refine_steps_run,"
           "evaluated_fraction,kernel,seconds,novel_view_loss,diffuse,specular,normal,lobes,rotation,fresnel,finite,finetune_lr,"
           "finetune_crop,finetune_warmup,finetune_half_life,network_precision\n";
  }
};

}  // namespace

int main(int argc, char** argv) {
  int materials = 10, size = 256, max_finetune = 5000, finetune_crop = 0, finetune_warmup = 0, finetune_half_life = 0;
  float finetune_lr = 7.5e-4f;
  nn::precision network_precision = nn::precision::fp32;
  bool networks_only = false, long_refine = false, no_stops = false, plain_refine = false;
  std::vector<int> finetune_points = {0, 200, 500, 1000, 2000, 5000}, image_counts = {12, 8};
  auto int_list = [](const std::string& text) {
    std::vector<int> v;
    std::stringstream in(text);
    for (std::string item; std::getline(in, item, ',');) v.push_back(std::stoi(item));
    return v;
  };
  fs::path models = ANISOCAP_SWEEP_MODELS, out_file = "sweep.csv";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) { std::fprintf(stderr, "sweep: %s needs a value\n", a.c_str()); std::exit(2); }
      return argv[++i];
    };
    if (a == "--materials") materials = std::stoi(next());
    else if (a == "--size") size = std::stoi(next());
    else if (a == "--max-finetune") max_finetune = std::stoi(next());
    else if (a == "--models") models = next();
    else if (a == "--finetune-lr") finetune_lr = std::stof(next());
    else if (a == "--finetune-crop") finetune_crop = std::stoi(next());
    else if (a == "--finetune-warmup") finetune_warmup = std::stoi(next());
    else if (a == "--finetune-half-life") finetune_half_life = std::stoi(next());
    else if (a == "--finetune-points") finetune_points = int_list(next());
    else if (a == "--images") image_counts = int_list(next());
    else if (a == "--networks-only") networks_only = true;
    else if (a == "--long-refine") long_refine = true;
    else if (a == "--no-stops") no_stops = true;
    else if (a == "--plain-refine") plain_refine = true;
    else if (a == "--out") out_file = next();
    else if (a == "--network-precision") {
      try {
        network_precision = nn::parse_precision(next(), "--network-precision");
        nn::require_available(network_precision, "--network-precision");
      } catch (const std::exception& e) {
        std::fprintf(stderr, "sweep: %s\n", e.what());
        return 2;
      }
    }
    else { std::fprintf(stderr, "sweep: unknown option %s (see the file comment)\n", a.c_str()); return 2; }
  }
  if (materials < 1 || size < 32 || max_finetune < 0) { std::fprintf(stderr, "sweep: bad option values\n"); return 2; }
  // The networks of the presets the weight files name (compact, or an experimental variant).
  const fs::path estimator_file = models / "compact" / "estimator.safetensors", ae_file = models / "compact" / "autoencoder.safetensors";
  auto sweep = [&]<class EstimatorPreset, class AutoEncoderPreset>() -> int {
  estimation_network<EstimatorPreset> estimator;
  auto_encoder<AutoEncoderPreset> autoencoder;
  nn::load_weights(estimator_file, estimator);  // a bad file is reported by the catch around the dispatch below

  std::erase_if(finetune_points, [&](int k) { return k > max_finetune || k % 100 != 0; });  // snapshots every 100 steps
  int rich_point = 0;  // the first non-zero fine-tune point gets every refine variant
  for (int k : finetune_points)
    if (k > 0) { rich_point = k; break; }
  const std::vector<double> finetune_stops = {1e-3, 3e-3, 1e-2};
  const refine_variant none{"none", 0};
  const refine_variant paper{"500", 500};
  // Refine variants tried on the cheaper starting points (the others get none / 500 only).
  std::vector<refine_variant> extra = {
      {"100", 100},
      {"200", 200},
      {"500 freeze 1e-2", 500, 0, 1e-2},
      {"500 freeze 3e-2", 500, 0, 3e-2},
      {"500 stop+freeze", 500, 1e-3, 1e-2},
      {"500 cull 1e-3", 500, 0, 0, 1e-3f},
      {"500 auto kernel 0.1", 500, 0, 0, 0, false, 0.1},
      {"500 double", 500, 0, 0, 0, true},
  };
  if (long_refine) extra = {{"1000", 1000}, {"2000", 2000}, {"2000 freeze 1e-2", 2000, 0, 1e-2}};
  if (plain_refine) extra.clear();
  row_writer rows;
  std::fprintf(stderr, "sweep: %d materials, %dx%d, %d threads, fine-tune up to %d steps at learning rate %g, %s networks\n", materials,
               size, size, omp_get_max_threads(), max_finetune, double(finetune_lr), nn::to_string(network_precision));
  for (int m = 0; m < materials; ++m) {
    const std::uint64_t seed = 920000 + std::uint64_t(m);  // disjoint from training (< 2^62 hashes) and eval (900000+)
    material_maps truth = generate_material(seed, size, size);
    // Every fourth material is made isotropic with flat normals (sy = sx, alpha = 0, n = z): the
    // scenes the kernel analysis is for.
    const bool isotropic = m % 4 == 3;
    if (isotropic) restrict_to_features(truth, brdf_features{false, true, false});
    const std::string truth_name = std::string(material_kind_name(kind_for_seed(seed))) + (isotropic ? " (isotropic, flat)" : "");
    const capture novel = novel_view_set(seed, size, size);
    for (int n : image_counts) {
      capture cap = set_alpha(n, seed, size, size);
      std::vector<image> photos = render(truth, cap);
      apply_exposure(cap, photos, exposure_scale(cap));
      const loss_targets targets = make_loss_targets(photos);
      auto emit = [&](const std::string& path, int ft_planned, double ft_stop, int ft_run, const std::string& refine_name, int refine_run,
                      double evaluated, const brdf_features& f, double seconds, const material_maps& maps) {
        const parameter_errors e = compare_maps(maps, truth);
        const double nv = novel_view_error(maps, truth, novel);
        rows.out << m << ',' << seed << ",\"" << truth_name << "\"," << n << ',' << path << ',' << ft_planned << ',' << ft_stop << ','
                 << ft_run << ",\"" << refine_name << "\"," << refine_run << ',' << evaluated << ",\""
                 << kernel_analysis{f, 0, 0, 0}.describe() << "\"," << seconds << ',' << nv << ',' << e.diffuse << ',' << e.specular << ','
                 << e.normal << ',' << e.lobes << ',' << e.rotation << ',' << e.fresnel << ',' << (all_finite(maps) ? 1 : 0) << ','
                 << finetune_lr << ',' << finetune_crop << ',' << finetune_warmup << ',' << finetune_half_life << ','
                 << nn::to_string(network_precision) << '\n';
      };
      auto run_refine = [&](const material_maps& start, const refine_variant& v, float lr, brdf_features& used, refine_result& rr) {
        material_maps maps = start;
        used = all_features;
        if (v.steps == 0) return maps;
        refine_options ro;
        ro.steps = v.steps;
        ro.learning_rate = lr;
        ro.min_relative_improvement = v.stop;
        ro.freeze_tolerance = v.freeze;
        ro.render.cull_tolerance = v.cull;
        ro.render.double_precision = v.double_precision;
        const auto t0 = clock_type::now();
        if (v.auto_kernel > 0) used = analyse_kernel(maps, cap, v.auto_kernel).features;
        rr = with_features(used, [&]<brdf_features F>() { return refine<F>(maps, cap, targets, ro); });
        rr.seconds = seconds_since(t0);  // includes the analysis
        return maps;
      };

      // Network path: estimate + encode, then one fine-tune trajectory observed at every step.
      nn::load_weights(ae_file, autoencoder);  // fresh decoder weights for every trajectory
      const int ft_max = n == 12 ? max_finetune : std::min(max_finetune, 1000);
      capture_options po;
      po.kernel = kernel_options::parse("full");
      po.stages = pipeline_stages{true, true, true, false};
      po.finetune.steps = ft_max;
      po.finetune.learning_rate = finetune_lr;
      po.finetune.crop.cells = finetune_crop;
      po.finetune.warmup = finetune_warmup;
      po.finetune.half_life = finetune_half_life;
      po.network_precision = network_precision;
      po.normalise_exposure = false;  // done above, identically for every path
      std::vector<double> losses;
      std::map<int, material_maps> snapshots;
      std::map<int, double> snapshot_seconds;
      double observer_seconds = 0;
      auto ft_start = clock_type::now();
      bool started = false;
      po.finetune.observer = [&](int updates, double loss, const std::function<material_maps()>& maps) {
        const auto t_in = clock_type::now();
        if (!started) { started = true; ft_start = t_in; }
        losses.push_back(loss);
        if (updates % 100 == 0) {
          snapshots[updates] = maps();
          snapshot_seconds[updates] = std::chrono::duration<double>(t_in - ft_start).count() - observer_seconds;
        }
        observer_seconds += seconds_since(t_in);
      };
      const auto t_all = clock_type::now();
      capture_result pr = capture_once(cap, photos, estimator, autoencoder, po);
      const double total = seconds_since(t_all);
      double pre_seconds = 0, ft_seconds = 0;
      for (const auto& st : pr.stages) {
        if (st.name == "estimate" || st.name == "encode") pre_seconds += st.seconds;
        if (st.name == "finetune") ft_seconds = st.seconds - observer_seconds;
      }
      snapshots[ft_max] = *pr.after_finetune;
      snapshot_seconds[ft_max] = ft_seconds;
      int restarts = 0;
      for (const auto& st : pr.stages) restarts += st.restarts;
      std::fprintf(stderr, "sweep: material %d/%d (%s) N=%d: estimate+encode %.1f s, fine-tune %d steps %.1f s (run %.1f s), guard restarts %d\n", m + 1,
                   materials, truth_name.c_str(), n, pre_seconds, ft_max, ft_seconds, total, restarts);
      struct start_point { int planned; double stop; int run; };
      std::vector<start_point> starts;
      for (int k : finetune_points)
        if (k <= ft_max) starts.push_back({k, 0, k});
      if (!no_stops)
        for (double tol : finetune_stops) starts.push_back({ft_max, tol, stopping_step(losses, tol, finetune_crop > 0)});
      for (const auto& sp : starts) {
        const material_maps& start = snapshots.at(sp.run);
        const double t_start = pre_seconds + snapshot_seconds.at(sp.run);
        std::vector<refine_variant> variants = {none, paper};
        const bool rich = n == 12 && ((sp.planned == rich_point && sp.stop == 0) || sp.stop == 3e-3);
        if (rich) variants.insert(variants.end(), extra.begin(), extra.end());
        for (const auto& v : variants) {
          brdf_features used;
          refine_result rr;
          const material_maps maps = run_refine(start, v, 0.003f, used, rr);
          emit("networks", sp.planned, sp.stop, sp.run, v.name, v.steps ? rr.steps : 0, v.steps ? rr.evaluated_fraction : 1.0, used,
               t_start + (v.steps ? rr.seconds : 0.0), maps);
        }
      }
      // Network-free path: first guess from the photographs + refine (lr 0.03, the program's default alone).
      if (!networks_only) {
        const auto t0 = clock_type::now();
        const material_maps guess = initial_guess(cap, photos);
        const double guess_seconds = seconds_since(t0);
        for (const refine_variant& v : {refine_variant{"1000", 1000}, refine_variant{"1000 stop+freeze", 1000, 1e-3, 1e-2}}) {
          if (n != 12 && v.freeze > 0) continue;
          brdf_features used;
          refine_result rr;
          const material_maps maps = run_refine(guess, v, 0.03f, used, rr);
          emit("refine-only", 0, 0, 0, v.name, rr.steps, rr.evaluated_fraction, used, guess_seconds + rr.seconds, maps);
        }
      }
      // Rewritten after every material, atomically: a partial sweep is usable, never half a file.
      write_file_atomically(out_file, rows.out.str());
    }
  }
  std::fprintf(stderr, "sweep: wrote %s\n", out_file.c_str());
  return 0;
  };
  try {
    return with_compact_estimator_preset(estimator_file, [&]<class EstimatorPreset>() {
      return with_compact_autoencoder_preset(ae_file, [&]<class AutoEncoderPreset>() { return sweep.template operator()<EstimatorPreset, AutoEncoderPreset>(); });
    });
  } catch (const std::exception& e) {
    std::fprintf(stderr, "sweep: %s\n", e.what());
    return 1;
  }
}
