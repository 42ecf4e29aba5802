// How much of the maps a linear code of the auto-encoder's size keeps: the best linear code for the
// squared error (principal components, Karhunen-Loeve) of B x B blocks of the 12 network-space
// channels, K components per block, fitted on training materials. A code of K components per
// 16 x 16 block holds as many values as a latent of (H/16) x (W/16) x K: K = 256 is
// compact-fine-wide's (and the paper's) compression, 12 map values per latent value; 128
// compact-fine's (24); 32 compact's (96, whose latent cells are 32 x 32 x 128).
//
// The validation materials, their sizes and the errors are eval-networks' (the same seeds, kinds,
// compare_maps in the original ranges), so the rows compare with its tables; with --autoencoder and
// --estimator the study also measures those networks on the same materials (their rows reproduce
// eval-networks' numbers). The code's output is clamped to the decoder's tanh range [-1, 1].
// Reading: an auto-encoder above the linear code of its own size has room to learn; one below it by
// a wide margin is near what its compression allows. models/README.md ("Run 28") has the command
// and the result.
//
// usage: anisocap_study_linear_codes [--fit 300] [--count 30] [--size 256] [--block 16]
//            [--keep 32,64,128,256,512] [--autoencoder FILE] [--estimator FILE] [--markdown FILE]
#include <CLI/CLI.hpp>

#include <Eigen/Dense>
#include <cstdio>
#include <string>
#include <vector>

#include "anisocap/anisocap.hpp"
#include "anisocap/training/training.hpp"

namespace {

using namespace anisocap;

struct study_options {
  int fit = 300;     // training materials the code is fitted on
  int count = 30;    // validation materials (eval-networks' --count)
  int size = 256;    // side of every material
  int block = 16;    // side of a code block (16: an auto-encoder latent cell of 4 levels)
  std::vector<int> keep{32, 64, 128, 256, 512};
  std::string autoencoder, estimator, markdown;
  std::uint64_t fit_seed = 28;  // run seed of the fitting materials (training_seed(fit_seed, i, 0))
};

/// Block b of `t` (1 x size x size x 12, NHWC) as a column: texels in row order, 12 channels each.
void gather(const tensor<parameter_count>& t, int size, int block, int b, double* out) {
  const int per_row = size / block, by = b / per_row, bx = b % per_row;
  for (int y = 0; y < block; ++y) {
    const float* row = t.data() + (std::size_t(by * block + y) * size + std::size_t(bx) * block) * parameter_count;
    for (int i = 0; i < block * parameter_count; ++i) *out++ = row[i];
  }
}

void scatter(tensor<parameter_count>& t, int size, int block, int b, const double* in) {
  const int per_row = size / block, by = b / per_row, bx = b % per_row;
  for (int y = 0; y < block; ++y) {
    float* row = t.data() + (std::size_t(by * block + y) * size + std::size_t(bx) * block) * parameter_count;
    for (int i = 0; i < block * parameter_count; ++i) row[i] = float(std::clamp(*in++, -1.0, 1.0));
  }
}

std::string row(const std::string& name, const parameter_errors& e) {
  char line[320];
  std::snprintf(line, sizeof line, "| %s | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g |\n", name.c_str(), e.diffuse, e.specular,
                e.normal, e.lobes, e.rotation, e.rotation_anisotropic, e.fresnel);
  return line;
}

int run(const study_options& o) {
  if (o.size % o.block != 0) throw std::invalid_argument("--size must be a multiple of --block");
  const int d = o.block * o.block * parameter_count, blocks = (o.size / o.block) * (o.size / o.block);
  for (int k : o.keep)
    if (k < 1 || k > d) throw std::invalid_argument("--keep: " + std::to_string(k) + " is not in 1.." + std::to_string(d));

  // The code: the mean block and the covariance's leading eigenvectors, over the fitting materials'
  // blocks (the training mix, as the auto-encoder's training materials).
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(d);
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(d, d), x(d, blocks);
  const procedural_options fit_options = training::training_material_options(material_mix::training);
  for (int i = 0; i < o.fit; ++i) {
    const training::sample s = training::make_sample(training::training_seed(o.fit_seed, i, 0), o.size, false, fit_options);
    for (int b = 0; b < blocks; ++b) gather(s.truth_net, o.size, o.block, b, x.col(b).data());
    mean += x.rowwise().sum();
    covariance.selfadjointView<Eigen::Lower>().rankUpdate(x);
    if ((i + 1) % 50 == 0) std::fprintf(stderr, "fitted %d of %d materials\n", i + 1, o.fit);
  }
  const double n = double(o.fit) * blocks;
  mean /= n;
  covariance = covariance.selfadjointView<Eigen::Lower>();
  covariance = covariance / n - mean * mean.transpose();
  std::fprintf(stderr, "eigen-decomposition of %d x %d\n", d, d);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(covariance);
  if (solver.info() != Eigen::Success) throw std::runtime_error("the covariance's eigen-decomposition did not converge");
  const Eigen::VectorXd variance = solver.eigenvalues().reverse();  // descending
  const Eigen::MatrixXd basis = solver.eigenvectors().rowwise().reverse();

  // The validation materials of eval-networks (original mix).
  std::vector<training::sample> samples;
  std::vector<material_kind> kinds;
  for (int i = 0; i < o.count; ++i) {
    const std::uint64_t seed = training::validation_seed(i);
    procedural_options options;
    options.kind = evaluation_kind(i, seed, {}, material_mix::original);
    kinds.push_back(*options.kind);
    samples.push_back(training::make_sample(seed, o.size, !o.estimator.empty(), options));
  }

  std::string md = "Validation materials: " + std::to_string(o.count) + " (eval-networks' seeds, original mix), " + std::to_string(o.size) +
                   " x " + std::to_string(o.size) + "; linear codes of " + std::to_string(o.block) + " x " + std::to_string(o.block) +
                   " blocks of the 12 network-space channels (" + std::to_string(d) + " values), fitted on " + std::to_string(o.fit) +
                   " training materials (training mix); MSE in the original ranges (compare_maps)\n\n";
  md += "| model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n|---|---|---|---|---|---|---|---|\n";
  std::vector<std::pair<std::string, std::vector<family_errors>>> by_family;  // each row's per-family means
  // One row: the mean errors of output(sample) (network space) over the validation materials.
  const auto measure = [&](const std::string& name, auto output) {
    std::vector<material_errors> all;
    for (std::size_t i = 0; i < samples.size(); ++i)
      all.push_back({kinds[i], compare_maps(network_space::network_to_maps(output(samples[i]), 0), samples[i].truth)});
    md += row(name, average_errors(all).mean);
    by_family.emplace_back(name, errors_by_family(all));
  };
  if (!o.estimator.empty())
    with_compact_estimator_preset(o.estimator, [&]<class P>() {
      estimation_network<P> net;
      nn::load_weights(o.estimator, net);
      measure("estimator (" + std::string(P::name) + ")", [&](const training::sample& s) { return training::estimator_output(net, s); });
    });
  if (!o.autoencoder.empty())
    with_compact_autoencoder_preset(o.autoencoder, [&]<class A>() {
      auto_encoder<A> net;
      nn::load_weights(o.autoencoder, net);
      measure("auto-encoder reconstruction (" + std::string(A::name) + ")",
              [&](const training::sample& s) { return training::autoencoder_output(net, s); });
    });
  const double total = variance.sum();
  for (int k : o.keep) {
    const Eigen::MatrixXd p = basis.leftCols(k);
    char name[160];
    std::snprintf(name, sizeof name, "linear code, %d per %d x %d block (%.3g map values per value; %.2f%% of the variance left)", k,
                  o.block, o.block, double(d) / k, 100.0 * (total - variance.head(k).sum()) / total);
    measure(name, [&](const training::sample& s) {
      for (int b = 0; b < blocks; ++b) gather(s.truth_net, o.size, o.block, b, x.col(b).data());
      const Eigen::MatrixXd centred = x.colwise() - mean;
      const Eigen::MatrixXd r = (p * (p.transpose() * centred)).colwise() + mean;
      tensor<parameter_count> t(1, o.size, o.size);
      for (int b = 0; b < blocks; ++b) scatter(t, o.size, o.block, b, r.col(b).data());
      return t;
    });
  }
  md += "\nPer family\n\n| family | materials | model | a_d | a'_s | n_s | sigma | alpha (mod pi) | alpha, anisotropic | F0 |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n";
  for (std::size_t f = 0; f < by_family.front().second.size(); ++f)
    for (const auto& [name, rows] : by_family)
      md += row(std::string(material_kind_name(rows[f].kind)) + " | " + std::to_string(rows[f].count) + " | " + name, rows[f].mean);
  std::printf("%s", md.c_str());
  if (!o.markdown.empty()) write_file_atomically(o.markdown, md);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  study_options o;
  CLI::App app{"errors of the best linear codes of map blocks, beside the auto-encoder's (models/README.md, Run 28)"};
  app.add_option("--fit", o.fit, "training materials the code is fitted on")->check(CLI::Range(1, 100000));
  app.add_option("--count", o.count, "validation materials")->check(CLI::Range(1, 100000));
  app.add_option("--size", o.size, "side of every material, texels")->check(CLI::Range(16, 4096));
  app.add_option("--block", o.block, "side of a code block, texels")->check(CLI::Range(1, 64));
  app.add_option("--keep", o.keep, "components kept per block, one row each")->delimiter(',');
  app.add_option("--autoencoder", o.autoencoder, "also measure this compact auto-encoder's reconstruction")->check(CLI::ExistingFile);
  app.add_option("--estimator", o.estimator, "also measure this compact estimator")->check(CLI::ExistingFile);
  app.add_option("--markdown", o.markdown, "also write the table to this file");
  CLI11_PARSE(app, argc, argv);
  try {
    return run(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "anisocap_study_linear_codes: %s\n", e.what());
    return 1;
  }
}
