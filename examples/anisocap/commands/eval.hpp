#pragma once
// `anisocap eval`: the paper's Table 1 on procedural validation materials.
#include <chrono>
#include <map>
#include <memory>
#include <sstream>

#include "common.hpp"

namespace anisocap::commands {

/// What eval runs.
struct eval_settings {
  fs::path out = "anisocap-eval";
  int count = 20, min_size = 256, max_size = 640;
  std::vector<int> image_counts{8, 10, 12};
  std::vector<std::string> sets{"alpha", "beta"};
  std::uint64_t first_seed = 900000;  // validation seeds: disjoint from training (training draws below 2^32 from its own salts)
  sensor_noise noise;  // simulated sensor noise on the inputs (the novel views stay exact)
  material_mix mix = material_mix::original;  // the mix the materials' kinds are drawn from (data/procedural.hpp)
  std::string families;     // non-empty: these families only, material m gets the (m mod n)-th
  fresnel_options fresnel;  // set alpha's grazing configurations (default: the paper's 2)
  std::string stages = "all";  // the pipeline stages each capture runs (pipeline_stages::parse)
};

/// eval's tables: per (N, stage, set) key the errors summed over the materials, per key the
/// materials' errors for the per-family table, and one CSV row per material and stage; written
/// (atomically) as table.md and table.csv.
class eval_tables {
 public:
  /// One material's capture of one key: where it came from and what it gave.
  struct entry {
    int material = 0;
    std::uint64_t seed = 0;
    int width = 0, height = 0, images = 0;
    std::string set;
    material_kind kind{};
    double seconds = 0;
  };

  eval_tables() {
    csv_ << "material,seed,width,height,images,set,stage,diffuse,specular,normal,lobes,rotation,rotation_anisotropic,fresnel,"
            "novel_view_loss,seconds,family,photo_loss,estimate_photo_loss,encode_photo_loss\n";
  }

  /// Records the maps of `stage` (whose image loss the capture reports as `report`) of entry x.
  void record(const entry& x, const char* stage, const char* report, const material_maps& maps, const material_maps& truth,
              const capture& novel, const capture_result& pr) {
    const parameter_errors pe = compare_maps(maps, truth);
    const double nv = novel_view_error(maps, truth, novel);
    const std::string key = std::to_string(x.images) + "|" + stage + "|" + x.set;
    if (!rows_.count(key)) order_.push_back(key);
    row_sum& r = rows_[key];
    r.e.diffuse += pe.diffuse; r.e.specular += pe.specular; r.e.normal += pe.normal; r.e.lobes += pe.lobes;
    r.e.rotation += pe.rotation; r.e.fresnel += pe.fresnel; r.novel += nv; r.seconds += x.seconds; ++r.n;
    family_rows_[key].push_back({x.kind, pe, nv});
    csv_ << x.material << ',' << x.seed << ',' << x.width << ',' << x.height << ',' << x.images << ',' << x.set << ',' << stage << ','
         << pe.diffuse << ',' << pe.specular << ',' << pe.normal << ',' << pe.lobes << ',' << pe.rotation << ',' << pe.rotation_anisotropic
         << ',' << pe.fresnel << ',' << nv << ',' << x.seconds << ',' << material_kind_name(x.kind) << ',' << pr.stage_loss(report) << ','
         << pr.stage_loss("estimate") << ',' << pr.stage_loss("encode") << '\n';
  }

  /// table.md's text: the means per key, then per key and family.
  std::string markdown() const {
    std::ostringstream md;
    md << "| N | stage | set | a_d | a_s | n_s | sigma | alpha | F0 | novel-view loss | s / material |\n|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& key : order_) {
      const row_sum& r = rows_.at(key);
      const double k = r.n;
      const auto p1 = key.find('|'), p2 = key.rfind('|');
      char line[400];
      std::snprintf(line, sizeof line, "| %s | %s | %s | %.4f | %.4f | %.4f | %.4f | %.3f | %.4f | %.4f | %.1f |\n", key.substr(0, p1).c_str(),
                    key.substr(p1 + 1, p2 - p1 - 1).c_str(), key.substr(p2 + 1).c_str(), r.e.diffuse / k, r.e.specular / k,
                    r.e.normal / k, r.e.lobes / k, r.e.rotation / k, r.e.fresnel / k, r.novel / k, r.seconds / k);
      md << line;
    }
    md << "\nPer family (held out of training: leather, printed)\n\n| N | stage | set | family | materials | a_d | a_s | n_s | sigma | alpha | F0 | novel-view loss |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
    for (const auto& key : order_) {
      const auto p1 = key.find('|'), p2 = key.rfind('|');
      for (const family_errors& f : errors_by_family(family_rows_.at(key))) {
        char line[400];
        std::snprintf(line, sizeof line, "| %s | %s | %s | %s%s | %d | %.4f | %.4f | %.4f | %.4f | %.3f | %.4f | %.4f |\n",
                      key.substr(0, p1).c_str(), key.substr(p1 + 1, p2 - p1 - 1).c_str(), key.substr(p2 + 1).c_str(),
                      material_kind_name(f.kind), is_held_out(f.kind) ? " (held out)" : "", f.count, f.mean.diffuse,
                      f.mean.specular, f.mean.normal, f.mean.lobes, f.mean.rotation, f.mean.fresnel, f.novel_view_loss);
        md << line;
      }
    }
    return md.str();
  }

  /// Writes table.md and table.csv into `out` together; returns table.md's text.
  std::string write(const fs::path& out) const {
    fs::create_directories(out);
    file_transaction files_out;
    const std::string table = markdown(), rows_csv = csv_.str();
    files_out.stage(out / "table.md", table.data(), table.size());
    files_out.stage(out / "table.csv", rows_csv.data(), rows_csv.size());
    files_out.commit();
    return table;
  }

 private:
  struct row_sum { parameter_errors e{}; double novel = 0, seconds = 0; int n = 0; };
  std::map<std::string, row_sum> rows_;
  std::map<std::string, std::vector<material_errors>> family_rows_;  // same keys: per-material errors for the per-family table
  std::vector<std::string> order_;
  std::ostringstream csv_;
};

/// eval's work once its options are checked and e.out is locked: captures each material (of
/// `families`, e.families read), writing table.md and table.csv into e.out (atomically) after
/// every material, so that a long run that is stopped keeps its rows so far.
inline void evaluate_materials(const eval_settings& e, const std::vector<material_kind>& families, const networks& nets,
                               const capture_options& options) {
  eval_tables tables;
  for (int m = 0; m < e.count; ++m) {
    const std::uint64_t seed = e.first_seed + std::uint64_t(m);
    random_generator rng(hash64(seed ^ 0x6576616cULL));
    const int w = e.min_size + int(rng.uniform_int(std::uint64_t(e.max_size - e.min_size + 1)));
    const int h = e.min_size + int(rng.uniform_int(std::uint64_t(e.max_size - e.min_size + 1)));
    procedural_options material_options;
    material_options.mix = e.mix;
    material_options.kind = evaluation_kind(m, seed, families, e.mix);
    const material_maps truth = generate_material(seed, w, h, material_options);
    const capture novel = novel_view_set(seed, w, h);
    for (int n : e.image_counts)
      for (const auto& set : e.sets) {
        const capture cap = set == "alpha" ? set_alpha(n, seed, w, h, e.fresnel) : set_beta(n, seed, w, h);
        auto photos = render(truth, cap);
        add_sensor_noise(photos, e.noise, seed ^ hash64(std::uint64_t(n) * 2 + (set == "beta")));
        const auto t0 = std::chrono::steady_clock::now();
        const capture_result pr = capture_material(cap, photos, nets, options);
        const eval_tables::entry x{m, seed, w, h, n, set, *material_options.kind, seconds_since(t0)};
        std::fprintf(stderr, "eval: material %d/%d (seed %llu, %dx%d, %s) N=%d set %s: %.1f s\n", m + 1, e.count,
                     static_cast<unsigned long long>(seed), w, h, material_kind_name(x.kind), n, set.c_str(), x.seconds);
        // Each row's photo_loss is the stage's image loss against the input photographs: what a
        // capture of real photographs can measure, beside the errors that need the truth. Every row
        // also carries the (kept run's) estimate's and its auto-encoder projection's losses, the
        // starts the fine-tune can take (docs/method.md section 8.3).
        if (pr.after_finetune) tables.record(x, "fine-tuned", "finetune", *pr.after_finetune, truth, novel, pr);
        tables.record(x, "refined", "refine", pr.maps, truth, novel, pr);
      }
    tables.write(e.out);
    std::fprintf(stderr, "eval: %d/%d materials done, tables in %s\n", m + 1, e.count, e.out.c_str());
  }
  const std::string table = tables.write(e.out);
  std::printf("%s\n(%d materials, %d to %d texels a side; per-material rows in %s)\n", table.c_str(), e.count, e.min_size, e.max_size,
              (e.out / "table.csv").c_str());
}

/// The paper's Table 1 on procedural validation materials (docs/method.md section 9): per N, set and
/// stage the mean over materials of each per-parameter MSE, the novel-view image loss and seconds
/// per material.
inline void eval_command(const eval_settings& e, const model_choice& models, const capture_options& options, bool also_models_given) {
  if (e.count < 1 || e.min_size < 1 || e.max_size < e.min_size) throw std::invalid_argument("eval: need --count >= 1 and 1 <= --min-size <= --max-size");
  for (const auto& set : e.sets)
    if (set != "alpha" && set != "beta") throw std::invalid_argument("eval: --sets takes alpha and beta, got '" + set + "'");
  for (int n : e.image_counts)
    if (n < 4 || n < e.fresnel.count + 2)
      throw std::invalid_argument("eval: --images values must be >= 4 and >= --fresnel + 2");
  e.noise.validate();
  const std::vector<material_kind> families = material_kinds_from_names(e.families);
  options.validate();  // reject impossible options before any work
  if (also_models_given && !options.stages.networks())
    throw std::invalid_argument("--also-models chooses between the network stages' results, and these stages do not run (--stages)");
  const networks nets = options.stages.networks() ? load_program_networks(models) : networks{};
  output_lock lock(e.out);  // one run per output folder; its tables are rewritten after every material
  capture_options without_uncertainty = options;  // the tables do not use it
  without_uncertainty.uncertainty.reset();
  evaluate_materials(e, families, nets, without_uncertainty);
}

/// Registers `anisocap eval`.
inline void add_eval_command(CLI::App& app) {
  auto e = std::make_shared<eval_settings>();
  auto models = std::make_shared<model_choice>();
  auto options = std::make_shared<capture_options>();
  auto* c = app.add_subcommand("eval", "the paper's Table 1 on procedural validation materials (per N, set, stage)");
  c->add_option("-o,--out", e->out, "output folder for table.md and table.csv");
  c->add_option("--count", e->count, "validation materials");
  c->add_option("--first-seed", e->first_seed,
                "seed of the first material (material m has seed first-seed + m; with --families its kind stays the (m mod n)-th, so "
                "--first-seed 900008 --count 1 --families brushed redoes material 8 of an 8-family run)");
  c->add_option("--min-size", e->min_size, "smallest side in texels");
  c->add_option("--max-size", e->max_size, "largest side in texels");
  c->add_option("--images", e->image_counts, "input counts N")->delimiter(',');
  c->add_option("--sets", e->sets, "configuration sets")->delimiter(',');
  add_noise_options(c, e->noise);
  c->add_option("--fresnel", e->fresnel.count, "grazing (Fresnel) configurations in set alpha")->check(CLI::NonNegativeNumber);
  add_mix_option(c, e->mix, {material_mix::original, material_mix::extended, material_mix::training},
                 "families the materials are drawn from: original, extended or training");
  c->add_option("--families", e->families,
                "evaluate these families only, comma-separated (e.g. leather,printed or brushed,spun,foil); material m gets the (m mod n)-th")
      ->check(family_list_check());
  c->add_option(capture_flag("pipeline_stages"), e->stages,
                "stages each capture runs: all, or a list of estimate,encode,finetune,refine (e.g. estimate,refine leaves the "
                "auto-encoder out; refine alone starts from the first guess with the refine's own schedule, as capture does)");
  add_model_options(c, *models);
  add_optimiser_options(c, *options);
  c->callback([e, models, options, c] {
    naming_options(capture_field_flags, [&] {
      capture_options o = *options;
      o.stages = pipeline_stages::parse(e->stages);
      eval_command(*e, *models, o, c->count("--also-models") > 0);
    });
  });
}

}  // namespace anisocap::commands
