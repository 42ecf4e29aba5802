#pragma once
/// @file
/// One optimiser step of either network: the gradient of a batch (the whole batch in one pass, or
/// data-parallel, material by material, summed over ranks in a fixed order) and the Adam step.
#include <algorithm>
#include <cmath>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "anisocap/core/distributed.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/nn/part_gradients.hpp"
#include "anisocap/training/options.hpp"

namespace anisocap::training {

namespace detail {

/// The latent smoothness term's |D(z) - D(z + delta)| (`y`, `y2`): adds +-step to the gradients
/// `gy` and -+step to `gy2` per value and returns the sum of the absolute differences.
inline double add_smoothness(const tensor<parameter_count>& y, const tensor<parameter_count>& y2, tensor<parameter_count>& gy,
                             tensor<parameter_count>& gy2, float step) {
  double s = 0;
  for (std::size_t i = 0; i < y.size(); ++i) {
    const float d = y.data()[i] - y2.data()[i];
    s += std::abs(d);
    const float sg = d > 0 ? step : (d < 0 ? -step : 0.0f);
    gy.data()[i] += sg;
    gy2.data()[i] -= sg;
  }
  return s;
}

/// The smoothness term's deltas of training step `step`: `count` values ~ N(0, o.latent_noise^2)
/// from (o.seed, step), the whole batch's latent in order (a data-parallel part takes its slice).
inline void draw_smoothness_deltas(const train_options& o, long step, float* out, std::size_t count) {
  nn::random_generator rng(hash64(o.seed ^ 0x736d6f6f7468ULL, step, 0));
  for (std::size_t i = 0; i < count; ++i) out[i] = float(o.latent_noise * rng.normal());
}

/// Per-channel sums over a data-parallel batch of `batch` materials, `count` of them on this rank
/// (`cell` values of Z channels each): each local material's, and the batch's added over the ranks
/// in ordered_sum's tree.
template <int Z, class PerValue>
std::pair<std::vector<double>, std::vector<double>> batch_channel_sums(const communicator& comm, int batch, int count, std::size_t cell,
                                                                       PerValue per_value) {
  std::vector<double> local_sums(std::size_t(count) * Z, 0.0), total(Z);
  for (int k = 0; k < count; ++k)
    for (std::size_t i = 0; i < cell; ++i)
      for (int c = 0; c < Z; ++c) local_sums[std::size_t(k) * Z + std::size_t(c)] += per_value(k, i, c);
  ordered_sum<double>(comm, batch, Z, local_sums, total);
  return std::pair{local_sums, total};
}

/// A batch norm synchronised over a data-parallel batch (autoencoder_gradient_parts): the batch's
/// statistics of this rank's `features` (its mean, then its centred variance, each summed in
/// ordered_sum's tree), the normalised values, and the backward pass.
template <int Z>
struct synced_norm {
  std::vector<float> mean, variance, rstd;  ///< per channel
  double n = 0;                             ///< values per channel over the batch
  int batch = 0;
  std::size_t cell = 0;                     ///< latent cells of one material

  synced_norm(const std::vector<ad::variable<Z>>& features, int batch_size, std::size_t cells, float epsilon, const communicator& comm)
      : mean(Z), variance(Z), rstd(Z), n(double(batch_size) * double(cells)), batch(batch_size), cell(cells) {
    if (n < 2) throw std::invalid_argument("nn::batch_norm: training needs more than one value per channel");
    const int count = int(features.size());
    const auto [unused_mean_parts, sum] = batch_channel_sums<Z>(
        comm, batch, count, cell, [&](int k, std::size_t i, int c) { return double(features[std::size_t(k)].value.data()[i * Z + c]); });
    (void)unused_mean_parts;
    std::vector<double> mean_d(Z);
    for (int c = 0; c < Z; ++c) mean_d[std::size_t(c)] = sum[std::size_t(c)] / n;
    const auto [unused_variance_parts, squares] = batch_channel_sums<Z>(comm, batch, count, cell, [&](int k, std::size_t i, int c) {
      const double d = double(features[std::size_t(k)].value.data()[i * Z + c]) - mean_d[std::size_t(c)];
      return d * d;
    });
    (void)unused_variance_parts;
    for (int c = 0; c < Z; ++c) {
      const double v = squares[std::size_t(c)] / n;
      mean[std::size_t(c)] = float(mean_d[std::size_t(c)]);
      variance[std::size_t(c)] = float(v);
      rstd[std::size_t(c)] = float(1 / std::sqrt(v + double(epsilon)));
    }
  }

  /// Material k's normalised value at cell i, channel c.
  float z_hat(const std::vector<ad::variable<Z>>& features, int k, std::size_t i, int c) const {
    return (features[std::size_t(k)].value.data()[i * Z + c] - mean[std::size_t(c)]) * rstd[std::size_t(c)];
  }

  /// The backward pass from dL/dz (`dz`, per material): the scale's and shift's gradients of each
  /// material into `norm`, dL/d(features) from the sums over the batch, each material's encoder
  /// backward on its own tape, and its gradient taken into part first + k.
  void backward(nn::batch_norm<Z>& norm, std::vector<ad::variable<Z>>& features, std::vector<std::unique_ptr<ad::tape>>& tapes,
                const std::vector<std::vector<float>>& dz, const communicator& comm, nn::part_gradients<loss_terms>& parts, int first) const {
    const int count = int(features.size());
    const auto [scale_parts, scale_sum] = batch_channel_sums<Z>(
        comm, batch, count, cell, [&](int k, std::size_t i, int c) { return double(dz[std::size_t(k)][i * Z + c]) * z_hat(features, k, i, c); });
    const auto [shift_parts, shift_sum] =
        batch_channel_sums<Z>(comm, batch, count, cell, [&](int k, std::size_t i, int c) { return double(dz[std::size_t(k)][i * Z + c]); });
    for (int k = 0; k < count; ++k) {
      if (norm.weight.trainable())
        for (int c = 0; c < Z; ++c) norm.weight.grad[c] += float(scale_parts[std::size_t(k) * Z + std::size_t(c)]);
      if (norm.bias.trainable())
        for (int c = 0; c < Z; ++c) norm.bias.grad[c] += float(shift_parts[std::size_t(k) * Z + std::size_t(c)]);
      auto& f = features[std::size_t(k)];
      if (f.requires_grad) {
        for (std::size_t i = 0; i < cell; ++i)
          for (int c = 0; c < Z; ++c) {
            const double g = dz[std::size_t(k)][i * Z + c] - shift_sum[std::size_t(c)] / n - z_hat(features, k, i, c) * scale_sum[std::size_t(c)] / n;
            f.grad.data()[i * Z + c] = float(double(norm.weight.value[c]) * rstd[std::size_t(c)] * g);
          }
        tapes[std::size_t(k)]->backward();
      }
      parts.take(first + k);
    }
  }
};

}  // namespace detail

/// The estimator's gradient on a batch (make_batch with photos; docs/method.md section 7): the
/// samples' 5 inputs in network space, the forward pass, map_losses with weights `w` (L1 +
/// w.render x render loss by default) and its gradient, backward. The gradients are added to the
/// parameters' (zero them first). `t` is cleared first (reuse it across steps to keep its memory).
/// `batch_size`: as map_losses's (a data-parallel part's share of a larger batch). Returns the
/// batch's loss terms.
template <class Preset>
loss_terms estimator_gradient(ad::tape& t, estimation_network<Preset>& net, std::span<const sample> samples, const loss_weights& w = {},
                              int batch_size = 0) {
  const int B = int(samples.size()), N = int(samples[0].photos.size());
  const int H = samples[0].truth.height(), W = samples[0].truth.width();
  t.clear();
  auto x = t.make_variable<estimation_network<Preset>::inputs>(B * N, H, W, false);
  for (int b = 0; b < B; ++b)
    for (int i = 0; i < N; ++i) network_space::photo_to_network(samples[std::size_t(b)].photos[i], x.value, b * N + i);
  auto y = net.forward(t, x, N);
  const loss_terms l = map_losses(y.value, samples, &y.grad, w, batch_size);
  t.backward();
  return l;
}

/// One optimiser step of the estimator on a batch: estimator_gradient, then one Adam step.
/// Returns the batch's loss terms before the step.
template <class Preset>
loss_terms estimator_step(ad::tape& t, estimation_network<Preset>& net, nn::adam& opt, const std::vector<sample>& samples,
                          const loss_weights& w = {}) {
  const loss_terms l = estimator_gradient(t, net, samples, w);
  opt.step();
  return l;
}

/// The auto-encoder's gradient on a batch (make_batch without photos; docs/method.md section 7):
/// D(E(m)) of the samples' true maps in training mode, map_losses with o.loss()'s weights, and with
/// o.smoothness_weight > 0 the latent smoothness term o.smoothness_weight * mean |D(z) - D(z +
/// delta)|, delta ~ N(0, o.latent_noise^2) per latent value drawn from (o.seed, step); backward.
/// The gradients are added to the parameters'. `t` is cleared first. Returns the batch's loss
/// terms. With `inputs` (one network-space map set per sample, e.g. the estimator's estimates) the
/// encoder reads those instead of the true maps; the loss still compares with the truth.
template <class Preset>
loss_terms autoencoder_gradient(ad::tape& t, auto_encoder<Preset>& net, const std::vector<sample>& samples, const train_options& o,
                                long step, const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  constexpr int Z = auto_encoder<Preset>::latent_channels;
  const int B = int(samples.size()), H = samples[0].truth_net.height(), W = samples[0].truth_net.width();
  if (inputs && int(inputs->size()) != B) throw std::invalid_argument("autoencoder_step: one input per sample");
  t.clear();
  auto x = t.make_variable<parameter_count>(B, H, W, false);
  for (int b = 0; b < B; ++b) {
    const tensor<parameter_count>& in = inputs ? (*inputs)[std::size_t(b)] : samples[b].truth_net;
    if (in.height() != H || in.width() != W) throw std::invalid_argument("autoencoder_step: an input's size differs from its sample's");
    std::copy_n(in.data(), in.size(), x.value.pixel(b, 0, 0));
  }
  net.set_training(true);
  auto z = net.encode(t, x);
  auto y = net.decode(t, z);
  loss_terms l = map_losses(y.value, samples, &y.grad, o.loss());
  if (o.smoothness_weight > 0) {
    auto delta = t.make_variable<Z>(z.value.batch(), z.value.height(), z.value.width(), false);
    detail::draw_smoothness_deltas(o, step, delta.value.data(), delta.value.size());
    auto y2 = net.decode(t, nn::add(t, z, delta));
    const double values = double(y.value.size());
    l.smoothness = detail::add_smoothness(y.value, y2.value, y.grad, y2.grad, float(o.smoothness_weight / values)) / values;
    l.total += o.smoothness_weight * l.smoothness;
  }
  t.backward();
  return l;
}

/// One optimiser step of the auto-encoder on a batch: autoencoder_gradient, then one Adam step.
/// Returns the batch's loss terms before the step.
template <class Preset>
loss_terms autoencoder_step(ad::tape& t, auto_encoder<Preset>& net, nn::adam& opt, const std::vector<sample>& samples,
                            const train_options& o, long step, const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  const loss_terms l = autoencoder_gradient(t, net, samples, o, step, inputs);
  opt.step();
  return l;
}

/// The parts of a data-parallel step (train_options::data_parallel) of `net`: one per material of
/// a batch of `batch`, started.
template <class Net>
nn::part_gradients<loss_terms> batch_parts(Net& net, const communicator& comm, int batch) {
  nn::part_gradients<loss_terms> parts(nn::trainable_parameters([&](auto&& f) { net.for_each_parameter(f); }), comm);
  parts.start(batch);
  return parts;
}

/// The sum of the parts' gradients in the parameters' gradients, on every rank; returns the
/// batch's loss terms.
inline loss_terms finish_parts(nn::part_gradients<loss_terms>& parts) {
  const loss_terms total = parts.sum();
  parts.apply();
  return total;
}

/// The estimator's gradient on a batch of `batch` materials, data-parallel
/// (train_options::data_parallel): `local` holds this rank's materials (part_range's share), each
/// one's gradient is computed alone (estimator_gradient with the batch's normalisation) and the
/// parts are summed over the ranks in ordered_sum's tree. Every rank calls it; on return every
/// rank's parameters hold the batch's gradient. Returns the batch's loss terms.
template <class Preset>
loss_terms estimator_gradient_parts(ad::tape& t, estimation_network<Preset>& net, std::span<const sample> local, int batch,
                                    const loss_weights& w, const communicator& comm) {
  nn::part_gradients<loss_terms> parts = batch_parts(net, comm, batch);
  if (int(local.size()) != parts.last() - parts.first())
    throw std::invalid_argument("estimator_gradient_parts: this rank's materials are not its share of the batch");
  for (int k = parts.first(); k < parts.last(); ++k) {
    parts.loss(k) = estimator_gradient(t, net, local.subspan(std::size_t(k - parts.first()), 1), w, batch);
    parts.take(k);
  }
  return finish_parts(parts);
}

/// The auto-encoder's gradient on a batch of `batch` materials, data-parallel: `local` (and
/// `inputs`, when given) hold this rank's materials. Each material's encoder, decoder and loss
/// (smoothness included, its delta the whole batch's slice) run alone; the batch norm that ends
/// the encoder normalises with the statistics of the whole batch, summed over the materials in
/// ordered_sum's tree (a synchronised batch norm: its mean, then its centred variance, and in the
/// backward pass the sums of dL/dz and dL/dz * z_hat), and updates the running statistics as
/// batch_norm does. The result equals autoencoder_gradient's up to rounding, on any rank count the
/// same bits. Every rank calls it. Returns the batch's loss terms.
template <class Preset>
loss_terms autoencoder_gradient_parts(ad::tape& t, auto_encoder<Preset>& net, std::span<const sample> local, int batch,
                                      const train_options& o, long step, const communicator& comm,
                                      const std::vector<tensor<parameter_count>>* inputs = nullptr) {
  constexpr int Z = auto_encoder<Preset>::latent_channels;
  nn::part_gradients<loss_terms> parts = batch_parts(net, comm, batch);
  const int first = parts.first(), count = parts.last() - parts.first();
  if (int(local.size()) != count || (inputs && int(inputs->size()) != count))
    throw std::invalid_argument("autoencoder_gradient_parts: this rank's materials are not its share of the batch");
  net.set_training(true);
  nn::batch_norm<Z>& norm = net.latent_norm;
  // Every material is o.size x o.size (make_batch), its latent h x w on every rank, also on a rank
  // that holds none.
  const int h = o.size / auto_encoder<Preset>::size_multiple, w = h;
  // The encoders, each on a tape of its own (kept for the backward pass after the statistics).
  std::vector<std::unique_ptr<ad::tape>> tapes;
  std::vector<ad::variable<Z>> features;
  for (int k = 0; k < count; ++k) {
    const tensor<parameter_count>& in = inputs ? (*inputs)[std::size_t(k)] : local[std::size_t(k)].truth_net;
    if (in.height() != o.size || in.width() != o.size)
      throw std::invalid_argument("autoencoder_gradient_parts: a material is not o.size x o.size");
    tapes.push_back(std::make_unique<ad::tape>());
    auto x = tapes.back()->make_variable<parameter_count>(1, in.height(), in.width(), false);
    std::copy_n(in.data(), in.size(), x.value.data());
    features.push_back(net.encode_features(*tapes.back(), x));
  }
  const std::size_t cell = std::size_t(h) * w;
  const detail::synced_norm<Z> stats(features, batch, cell, norm.epsilon, comm);
  norm.track(stats.mean.data(), stats.variance.data(), std::size_t(stats.n));
  // The batch's smoothness deltas, drawn as autoencoder_gradient draws them; material k's slice.
  std::vector<float> deltas;
  if (o.smoothness_weight > 0) {
    deltas.resize(std::size_t(batch) * cell * Z);
    detail::draw_smoothness_deltas(o, step, deltas.data(), deltas.size());
  }
  // Each material's decoder, loss and backward pass to z; dL/dz kept for the encoder's.
  std::vector<std::vector<float>> dz(static_cast<std::size_t>(count));
  for (int k = 0; k < count; ++k) {
    t.clear();
    auto z = t.make_variable<Z>(1, h, w, true);
    for (std::size_t i = 0; i < cell; ++i)
      for (int c = 0; c < Z; ++c) z.value.data()[i * Z + c] = stats.z_hat(features, k, i, c) * norm.weight.value[c] + norm.bias.value[c];
    auto y = net.decode(t, z);
    loss_terms l = map_losses(y.value, local.subspan(std::size_t(k), 1), &y.grad, o.loss(), batch);
    if (o.smoothness_weight > 0) {
      auto delta = t.make_variable<Z>(1, h, w, false);
      std::copy_n(deltas.data() + std::size_t(first + k) * cell * Z, cell * Z, delta.value.data());
      auto y2 = net.decode(t, nn::add(t, z, delta));
      const double values = double(y.value.size()) * batch;  // the batch's
      l.smoothness = detail::add_smoothness(y.value, y2.value, y.grad, y2.grad, float(o.smoothness_weight / values)) / values;
      l.total += o.smoothness_weight * l.smoothness;
    }
    t.backward();
    dz[std::size_t(k)].assign(z.grad.data(), z.grad.data() + z.grad.size());
    parts.loss(first + k) = l;
    parts.take(first + k);  // the decoder's gradient of this material
  }
  stats.backward(norm, features, tapes, dz, comm, parts, first);
  return finish_parts(parts);
}

}  // namespace anisocap::training
