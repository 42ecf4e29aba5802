// How well a capture separates a'_s from F0 on metals, against the number and the height of its
// grazing (Fresnel) configurations: procedural metals are rendered under set alpha with 0, 2, 4, ...
// Fresnel configurations in a camera-height band, refined per texel from the photographs' first
// guess (pipeline/refine.hpp; --stages refine) or from the compact estimator's estimate (--stages
// estimate,refine: the pipeline without the decoder fine-tune), and compared with the truth
// (compare_maps) and on three novel views.
// One CSV row per material and configuration, and a Markdown table of the means on stdout.
// studies/README.md, "Grazing configurations on metals", has the command and the result.
#include <CLI/CLI.hpp>
#include <omp.h>

#include <chrono>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "anisocap/anisocap.hpp"

namespace {

using namespace anisocap;

struct band {
  double low, high;
  std::string name() const {
    char s[32];
    std::snprintf(s, sizeof s, "%.2f-%.2f", low, high);
    return s;
  }
};

struct study_options {
  int size = 96;
  int materials = 4;
  std::vector<int> images{8, 12};
  std::vector<int> fresnel{0, 2, 4};
  std::vector<std::string> heights{"0.1:0.2", "0.2:0.3", "0.3:0.4"};
  std::string kinds = "brushed,spun";
  int captures = 1;
  int steps = 400;
  double learning_rate = 0.03;
  int threads = 1;
  std::uint64_t first_seed = 700000;
  std::string csv = "metals_fresnel.csv";
  std::string stages = "refine";
  std::string models = "models/compact";
};

band parse_band(const std::string& text) {
  const auto colon = text.find(':');
  if (colon == std::string::npos) throw std::invalid_argument("--heights: expected LOW:HIGH, got '" + text + "'");
  const band b{std::stod(text.substr(0, colon)), std::stod(text.substr(colon + 1))};
  if (!(b.low > 0) || !(b.high >= b.low)) throw std::invalid_argument("--heights: need 0 < LOW <= HIGH, got '" + text + "'");
  return b;
}

struct sums {
  double specular = 0, fresnel = 0, novel = 0, lobes = 0, normal = 0, diffuse = 0, seconds = 0;
  int n = 0;
};

/// The study with an estimator of preset EstimatorPreset (used with --stages estimate,refine).
template <class EstimatorPreset>
int run_with(const study_options& o) {
  omp_set_num_threads(o.threads);
  const std::vector<material_kind> kinds = material_kinds_from_names(o.kinds);
  if (kinds.empty()) throw std::invalid_argument("--kinds: give at least one family");
  const pipeline_stages stages = pipeline_stages::parse(o.stages);
  if (stages.encode || stages.finetune) throw std::invalid_argument("--stages: this study runs refine or estimate,refine");
  std::unique_ptr<estimation_network<EstimatorPreset>> estimator;
  std::unique_ptr<auto_encoder<autoencoder_compact>> autoencoder;
  if (stages.estimate) {
    if (o.size % 64 != 0) throw std::invalid_argument("--stages estimate needs --size a multiple of 64");
    estimator = std::make_unique<estimation_network<EstimatorPreset>>();
    autoencoder = std::make_unique<auto_encoder<autoencoder_compact>>();
    nn::load_weights(o.models + "/estimator.safetensors", *estimator);
  }
  std::vector<band> bands;
  for (const auto& h : o.heights) bands.push_back(parse_band(h));
  std::ostringstream csv;
  csv << "material,seed,kind,capture,images,fresnel,heights,diffuse,specular,normal,lobes,rotation,fresnel_f0,novel_view_loss,"
         "seconds\n";
  std::map<std::string, sums> table;
  std::vector<std::string> order;
  const int w = o.size, h = o.size;
  for (int m = 0; m < o.materials; ++m) {
    const std::uint64_t seed = o.first_seed + std::uint64_t(m);
    procedural_options po;
    po.kind = kinds[std::size_t(m) % kinds.size()];
    po.mix = material_mix::extended;
    const procedural_parameters parameters = draw_procedural_parameters(seed, po);
    const material_maps truth = generate_material(parameters, w, h);
    const capture novel = novel_view_set(seed, w, h);
    std::fprintf(stderr, "material %d/%d: %s\n", m + 1, o.materials, describe(parameters).c_str());
    for (int c = 0; c < o.captures; ++c) {
      const std::uint64_t capture_seed = hash64(seed, c, 0x6d6574616cLL);
      for (int n : o.images) {
        for (int f : o.fresnel) {
          std::vector<band> runs = f == 0 ? std::vector<band>{band{fresnel_min_height, fresnel_max_height}} : bands;
          for (const band& b : runs) {
            if (n < f + 2) continue;
            const capture cap = set_alpha(n, capture_seed, w, h, fresnel_options{f, b.low, b.high});
            const std::vector<image> photos = render(truth, cap);
            const auto start = std::chrono::steady_clock::now();
            material_maps maps;
            if (estimator) {
              capture_options pipeline;
              pipeline.stages = stages;
              pipeline.estimate.window = std::min(256, w);
              pipeline.estimate.stride = std::max(32, pipeline.estimate.window / 4);
              pipeline.kernel = kernel_options::parse("full");  // the kernel the refine-only runs use
              pipeline.refine.steps = o.steps;
              pipeline.refine.learning_rate = float(o.learning_rate);
              maps = capture_once(cap, photos, *estimator, *autoencoder, pipeline).maps;
            } else {
              maps = initial_guess(cap, photos);
              refine_options ro;
              ro.steps = o.steps;
              ro.learning_rate = float(o.learning_rate);
              refine<all_features>(maps, cap, make_loss_targets(photos), ro);
            }
            const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            const parameter_errors e = compare_maps(maps, truth);
            const double nv = novel_view_error(maps, truth, novel);
            const std::string heights = f == 0 ? "-" : b.name();
            csv << m << ',' << seed << ',' << material_kind_name(*po.kind) << ',' << c << ',' << n << ',' << f << ',' << heights << ','
                << e.diffuse << ',' << e.specular << ',' << e.normal << ',' << e.lobes << ',' << e.rotation << ',' << e.fresnel << ','
                << nv << ',' << seconds << '\n';
            char key[64];
            std::snprintf(key, sizeof key, "%d|%d|%s", n, f, heights.c_str());
            if (!table.count(key)) order.push_back(key);
            sums& s = table[key];
            s.specular += e.specular;
            s.fresnel += e.fresnel;
            s.novel += nv;
            s.lobes += e.lobes;
            s.normal += e.normal;
            s.diffuse += e.diffuse;
            s.seconds += seconds;
            ++s.n;
            std::fprintf(stderr, "  N=%d Fresnel %d heights %s: a'_s %.4f F0 %.4f novel %.4f (%.1f s)\n", n, f, heights.c_str(),
                         e.specular, e.fresnel, nv, seconds);
          }
        }
      }
    }
  }
  {
    const std::string text = csv.str();
    write_file_atomically(o.csv, text);
  }
  std::printf("| N | Fresnel | camera height (n) | a'_s | F0 | novel-view loss | sigma | n_s | a_d | s / run |\n"
              "|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& key : order) {
    const sums& s = table[key];
    const auto p1 = key.find('|'), p2 = key.rfind('|');
    const double k = s.n;
    std::printf("| %s | %s | %s | %.4f | %.4f | %.4f | %.4f | %.4f | %.5f | %.1f |\n", key.substr(0, p1).c_str(),
                key.substr(p1 + 1, p2 - p1 - 1).c_str(), key.substr(p2 + 1).c_str(), s.specular / k, s.fresnel / k, s.novel / k,
                s.lobes / k, s.normal / k, s.diffuse / k, s.seconds / k);
  }
  std::printf("\n(%d materials of %s, %d x %d, %d capture seed(s) each, stages %s, refine %d steps at rate %g; rows in %s)\n",
              o.materials, o.kinds.c_str(), o.size, o.size, o.captures, o.stages.c_str(), o.steps, o.learning_rate, o.csv.c_str());
  return 0;
}

}  // namespace

/// run_with the preset that --models' estimator file names (compact, or an experimental variant).
int run(const study_options& o) {
  if (!pipeline_stages::parse(o.stages).estimate) return run_with<estimator_compact>(o);
  return with_compact_estimator_preset(o.models + "/estimator.safetensors", [&]<class P>() { return run_with<P>(o); });
}

int main(int argc, char** argv) {
  CLI::App app{"metals: per-parameter and novel-view error against the number and height of Fresnel configurations"};
  study_options o;
  app.add_option("--size", o.size, "material side in texels")->check(CLI::Range(16, 1024))->capture_default_str();
  app.add_option("--materials", o.materials, "materials (kinds in turn)")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--kinds", o.kinds, "families, comma-separated (brushed, spun, foil, ...)")->capture_default_str();
  app.add_option("--images", o.images, "input counts N")->delimiter(',')->capture_default_str();
  app.add_option("--fresnel", o.fresnel, "Fresnel configurations per set")->delimiter(',')->capture_default_str();
  app.add_option("--heights", o.heights, "camera height bands LOW:HIGH in units of n")->delimiter(',')->capture_default_str();
  app.add_option("--captures", o.captures, "capture seeds per material")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--steps", o.steps, "refine steps")->check(CLI::NonNegativeNumber)->capture_default_str();
  app.add_option("--lr", o.learning_rate, "refine learning rate")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--threads", o.threads, "OpenMP threads")->check(CLI::PositiveNumber)->capture_default_str();
  app.add_option("--first-seed", o.first_seed, "seed of the first material")->capture_default_str();
  app.add_option("--csv", o.csv, "per-run rows")->capture_default_str();
  app.add_option("--stages", o.stages, "refine (from the first guess) or estimate,refine (compact estimator first)")
      ->capture_default_str();
  app.add_option("--models", o.models, "folder of the compact estimator's weights (its preset is read from the file)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  for (int f : o.fresnel)
    if (f < 0) {
      std::fprintf(stderr, "metals_fresnel: --fresnel values must be >= 0\n");
      return 1;
    }
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "metals_fresnel: %s\n", e.what());
    return 1;
  }
}
