// The training commands' runs (commands/training_runs.hpp): train-estimator, train-autoencoder and
// eval-networks, compiled in the program's networks unit with the networks they train.
#include <cstdio>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/training/training.hpp"
#include "commands/field_flags.hpp"
#include "commands/ranks.hpp"
#include "commands/training_runs.hpp"

namespace anisocap::commands::train_detail {

namespace {

/// Runs `train(options, net)` on a Net<P> built from the run seed, P the preset s.preset names:
/// Paper ("paper") or one of the list Compact (networks/presets.hpp), while holding the output
/// folder's lock; a run refused before writing anything leaves no folder behind. Under an MPI
/// launcher every rank trains a share of each batch (train_options::data_parallel) and rank 0
/// alone locks and writes the folder.
template <template <class...> class Net, class Paper, class Compact, class Train>
void train_in_locked_folder(const train_settings& settings, Train train) {
  train_settings s = settings;
  training::train_options& o = s.options;
  const communicator& ranks = program_ranks();
  if (mpi_job()) o.data_parallel = true;
  std::optional<output_lock> lock;
  if (ranks.root()) lock.emplace(o.out_dir);  // one run per output folder
  auto run = [&]<class P>() {
    auto net = std::make_unique<Net<P>>(o.seed);
    train(o, *net, ranks);
  };
  naming_options(train_field_flags, [&] {  // the library names train_options fields: name the flags
    if constexpr (program_has_paper_preset)
      if (s.preset == Paper::name) return run.template operator()<Paper>();
    Compact::call(s.preset, run, [&] { return "--preset " + s.preset + ": not one of " + join_names(preset_choices<Paper, Compact>(), ", "); });
  });
}

/// One row of eval-networks' Markdown table: the mean errors of one network on one group of materials.
std::string row(const char* name, const parameter_errors& e) {
  char line[256];
  std::snprintf(line, sizeof line, "| %s | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g |\n", name, e.diffuse, e.specular,
                e.normal, e.lobes, e.rotation, e.rotation_anisotropic, e.fresnel);
  return line;
}

/// eval-networks' validation materials (their kinds in `kinds`), with the settings' sensor noise on
/// their photographs.
std::vector<training::sample> network_eval_samples(const network_eval_settings& s, const std::vector<material_kind>& families,
                                                          std::vector<material_kind>& kinds) {
  std::vector<training::sample> samples;
  for (int i = 0; i < s.count; ++i) {
    const std::uint64_t seed = training::validation_seed(i);
    procedural_options options;
    options.mix = s.mix;
    options.kind = evaluation_kind(i, seed, families, s.mix);
    kinds.push_back(*options.kind);
    samples.push_back(training::make_sample(seed, s.size, true, options));
    add_sensor_noise(samples.back().photos, s.noise, hash64(seed ^ 0x6e6574776f726b73ULL));
  }
  return samples;
}

/// The per-texel mean of the samples' true maps (size x size): eval-networks' baseline.
material_maps mean_of_truths(const std::vector<training::sample>& samples, int size) {
  material_maps mean(size, size);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t j = 0; j < mean.texel_count(); ++j) {
      double sum = 0;
      for (const auto& x : samples) sum += x.truth.plane(k)[j];
      mean.plane(k)[j] = float(sum / double(samples.size()));
    }
  return mean;
}

/// Each validation material's errors for eval-networks' four rows.
struct network_eval_errors {
  std::vector<material_errors> estimator, baseline, autoencoder, start;
};

/// eval-networks' report (Markdown): the settings, the four rows' mean errors, then per family.
std::string network_eval_report(const network_eval_settings& s, const std::vector<material_kind>& families, const char* estimator_name,
                                       const char* autoencoder_name, const network_eval_errors& errors) {
  const parameter_errors est = average_errors(errors.estimator).mean, base = average_errors(errors.baseline).mean,
                         ae = average_errors(errors.autoencoder).mean, start = average_errors(errors.start).mean;
  const auto number = [](double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", v);
    return std::string(text);
  };
  std::string md = "Validation materials: " + std::to_string(s.count) + " (seeds 2^62 + 0 ... ; " +
                   (families.empty() ? std::string(material_mix_name(s.mix)) + " mix" : "families " + s.families) + "), " +
                   std::to_string(s.size) + " x " + std::to_string(s.size) +
                   (s.window > 0 ? ", the estimator over " + std::to_string(s.window) + " x " + std::to_string(s.window) + " windows (stride " +
                                       std::to_string(s.windows().stride) + ", as the pipeline's estimate)"
                                 : std::string()) +
                   ", 5 inputs (training set)" +
                   (s.noise.enabled() ? " with sensor noise (shot " + number(s.noise.shot) + ", read " + number(s.noise.read) + ")"
                                      : std::string()) +
                   "; MSE in the original ranges (compare_maps; alpha modulo pi over all texels, "
                   "and over the anisotropic texels of the materials that have them)\n\n";
  md += "| model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|\n";
  md += row(("estimator (" + std::string(estimator_name) + ")").c_str(), est);
  md += row("mean-map baseline", base);
  md += row(("auto-encoder reconstruction (" + std::string(autoencoder_name) + ")").c_str(), ae);
  md += row("estimate through the auto-encoder (the fine-tune's start)", start);
  md += "\nPer family (held out of training: leather, printed; the baseline is the mean map of all materials above)\n\n";
  md += "| family | materials | model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|---|---|\n";
  const auto est_rows = errors_by_family(errors.estimator), base_rows = errors_by_family(errors.baseline),
             ae_rows = errors_by_family(errors.autoencoder), start_rows = errors_by_family(errors.start);
  for (std::size_t k = 0; k < est_rows.size(); ++k) {
    const std::string prefix = std::string(material_kind_name(est_rows[k].kind)) + (is_held_out(est_rows[k].kind) ? " (held out)" : "") +
                               " | " + std::to_string(est_rows[k].count);
    md += row((prefix + " | estimator").c_str(), est_rows[k].mean);
    md += row((prefix + " | baseline").c_str(), base_rows[k].mean);
    md += row((prefix + " | auto-encoder").c_str(), ae_rows[k].mean);
    md += row((prefix + " | estimate through the auto-encoder").c_str(), start_rows[k].mean);
  }
  return md;
}

/// eval-networks with an estimator and an auto-encoder of the given presets.
template <class EstimatorPreset, class AutoEncoderPreset>
void evaluate_networks_with(const network_eval_settings& s) {
  const std::vector<material_kind> families = material_kinds_from_names(s.families);
  estimation_network<EstimatorPreset> estimator;
  auto_encoder<AutoEncoderPreset> autoencoder;
  nn::load_weights(s.estimator, estimator);
  nn::load_weights(s.autoencoder, autoencoder);
  std::vector<material_kind> kinds;
  const std::vector<training::sample> samples = network_eval_samples(s, families, kinds);
  const material_maps mean = mean_of_truths(samples, s.size);
  network_eval_errors errors;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const auto& x = samples[i];
    tensor<parameter_count> u;
    if (s.window > 0) {
      const material_maps m = estimate(x.photos, estimator, s.windows());
      u = tensor<parameter_count>(1, s.size, s.size);
      network_space::maps_to_network(m, u, 0);
    } else {
      u = training::estimator_output(estimator, x);
    }
    errors.estimator.push_back({kinds[i], compare_maps(network_space::network_to_maps(u, 0), x.truth)});
    errors.baseline.push_back({kinds[i], compare_maps(mean, x.truth)});
    const auto r = training::autoencoder_output(autoencoder, x);
    errors.autoencoder.push_back({kinds[i], compare_maps(network_space::network_to_maps(r, 0), x.truth)});
    // The fine-tune's start: the decoder's maps of the estimate's latent code (docs/method.md section 8.2).
    const auto d = training::autoencoder_output(autoencoder, x, &u);
    errors.start.push_back({kinds[i], compare_maps(network_space::network_to_maps(d, 0), x.truth)});
  }
  const std::string md = network_eval_report(s, families, EstimatorPreset::name, AutoEncoderPreset::name, errors);
  std::printf("%s", md.c_str());
  if (!s.markdown.empty()) write_file_atomically(s.markdown, md);
}

}  // namespace

void evaluate_networks(const network_eval_settings& s) {
  if (s.window % 64 != 0)
    throw std::invalid_argument("eval-networks: --window " + std::to_string(s.window) + " is not a multiple of 64 (the estimator's)");
  if (s.window > 0) naming_options(eval_networks_field_flags, [&] { s.windows().validate(); });
  with_estimator_preset<program_estimator_presets>(s.estimator, [&]<class P>() {
    with_autoencoder_preset<program_autoencoder_presets>(s.autoencoder, [&]<class A>() { evaluate_networks_with<P, A>(s); });
  });
}

void run_train_estimator(const train_settings& s) {
  train_in_locked_folder<estimation_network, estimator_paper, program_estimator_presets>(
      s, [](const training::train_options& o, auto& net, const communicator& ranks) { training::train_estimator(o, net, ranks); });
}

void run_train_autoencoder(const train_settings& s) {
  train_in_locked_folder<auto_encoder, autoencoder_paper, program_autoencoder_presets>(
      s, [&s](const training::train_options& o, auto& net, const communicator& ranks) {
        if (s.inputs == "truth") return training::train_autoencoder(o, net, ranks);
        with_estimator_preset<program_estimator_presets>(s.input_estimator, [&]<class P>() {
          auto estimator = std::make_unique<estimation_network<P>>();
          nn::load_weights(s.input_estimator, *estimator);
          training::train_autoencoder(o, net, *estimator, ranks);
        });
      });
}

}  // namespace anisocap::commands::train_detail
