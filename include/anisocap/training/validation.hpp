#pragma once
/// @file
/// Validation of either network on a run's validation materials, and the networks' outputs for one
/// sample without gradients.
#include <vector>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/data/family_errors.hpp"
#include "anisocap/training/options.hpp"

namespace anisocap::training {

/// Validation summary: mean losses and per-parameter errors (compare_maps, original ranges;
/// rotation_anisotropic is the mean over the materials that have anisotropic texels).
struct validation_result {
  loss_terms loss;          ///< mean over the validation materials
  parameter_errors errors;  ///< mean over the validation materials
};

/// The estimator's network-space maps for one sample (no gradients). The inference tape is kept
/// per thread across calls (training and validation samples share one size), so that every call
/// after the first reuses its memory instead of faulting in fresh pages.
template <class Net>
tensor<parameter_count> estimator_output(Net& net, const sample& s) {
  static thread_local ad::retained_tape scratch;
  ad::tape& t = scratch.fresh();
  ad::tape::no_grad_guard guard(t);
  const int H = s.truth.height(), W = s.truth.width();
  auto x = t.make_variable<Net::inputs>(int(s.photos.size()), H, W, false);
  for (std::size_t i = 0; i < s.photos.size(); ++i) network_space::photo_to_network(s.photos[i], x.value, int(i));
  auto y = net.forward(t, x, int(s.photos.size()));
  tensor<parameter_count> out(1, H, W);
  std::copy_n(y.value.data(), out.size(), out.data());
  return out;
}

/// The auto-encoder's reconstruction of one sample (running batch-norm statistics, no gradients):
/// D(E(m)) of the true maps, or of `input` (network space, the sample's size) when given.
/// Its inference tape is kept per thread across calls, as estimator_output's.
template <class Net>
tensor<parameter_count> autoencoder_output(Net& net, const sample& s, const tensor<parameter_count>* input = nullptr) {
  static thread_local ad::retained_tape scratch;
  ad::tape& t = scratch.fresh();
  ad::tape::no_grad_guard guard(t);
  net.set_training(false);
  auto x = t.leaf(input ? *input : s.truth_net);
  auto y = net.decode(t, net.encode(t, x));
  net.set_training(true);
  tensor<parameter_count> out(1, s.truth.height(), s.truth.width());
  std::copy_n(y.value.data(), out.size(), out.data());
  return out;
}

/// Validation of either network on a run's o.validation_count validation materials of
/// o.size x o.size, drawn as its training materials are (material_options_for_seed).
template <class Net, class Output>
validation_result validate(Net& net, const train_options& o, bool with_photos, Output output) {
  const int count = o.validation_count;
  validation_result r;
  std::vector<material_errors> errors;
  for (int i = 0; i < count; ++i) {
    std::vector<sample> one;
    const std::uint64_t seed = validation_seed(i);
    one.push_back(make_sample(seed, o.size, with_photos, material_options_for_seed(o, seed)));
    const auto u = output(net, one[0]);
    const loss_terms l = map_losses(u, one, nullptr);
    r.loss.total += l.total / count;
    r.loss.l1 += l.l1 / count;
    r.loss.render += l.render / count;
    material_errors m;
    m.errors = compare_maps(network_space::network_to_maps(u, 0), one[0].truth);
    errors.push_back(m);
  }
  r.errors = average_errors(errors).mean;
  return r;
}

}  // namespace anisocap::training
