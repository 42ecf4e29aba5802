#pragma once
/// @file
/// Instance normalisation (per image and channel over height x width: Deschaintre's estimator) and
/// batch normalisation (per channel over batch x height x width: the end of Gao's encoder,
/// docs/method.md section 7), both with a learned scale `weight` (gamma) and shift `bias` (beta).
///
/// Both share one kernel: statistics per group (a batch entry, or the whole batch), two passes
/// (mean, then centred variance, for accuracy), vectorised over channels, rows in parallel.
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

namespace detail {

/// Per-group channel patterns (groups x pattern_length values) of per-group channel values.
template <int C, class T>
T* expand_groups(ad::tape& t, const T* values, int groups) {
  constexpr std::size_t P = pattern_length<C, T>;
  T* p = t.memory().allocate_array<T>(std::size_t(groups) * P);
  for (int g = 0; g < groups; ++g) expand_pattern<C>(values + std::size_t(g) * C, p + std::size_t(g) * P);
  return p;
}

/// Per-group channel mean and biased variance of x; a group is one batch entry
/// (`per_entry`) or the whole batch. mean and variance hold groups x C values.
template <int C, class T>
void channel_statistics(ad::tape& t, const tensor<C, T>& x, bool per_entry, T* mean, T* variance) {
  constexpr std::size_t P = pattern_length<C, T>;
  const int B = x.batch(), H = x.height(), W = x.width();
  const int groups = per_entry ? B : 1, rows_per_group = per_entry ? H : B * H;
  const T inverse = T(1) / T(std::size_t(rows_per_group) * W);
  T* partial = t.memory().allocate_array<T>(std::size_t(B) * H * C);
  row_channel_sums<C>(B, H, W, partial, [&](int b, int r, std::size_t s, std::size_t n, T* acc) {
    add_to(acc, x.pixel(b, r, 0) + s, n);
  });
  for (int g = 0; g < groups; ++g) {
    sum_rows<C>(partial, g * rows_per_group, (g + 1) * rows_per_group, mean + std::size_t(g) * C);
    for (int c = 0; c < C; ++c) mean[std::size_t(g) * C + c] *= inverse;
  }
  const T* mean_pattern = expand_groups<C>(t, mean, groups);
  row_channel_sums<C>(B, H, W, partial, [&](int b, int r, std::size_t s, std::size_t n, T* acc) {
    const T* m = mean_pattern + std::size_t(per_entry ? b : 0) * P;
    transform(n, acc, [](auto a, auto v, auto mu) { return a + (v - mu) * (v - mu); }, acc, x.pixel(b, r, 0) + s, m);
  });
  for (int g = 0; g < groups; ++g) {
    sum_rows<C>(partial, g * rows_per_group, (g + 1) * rows_per_group, variance + std::size_t(g) * C);
    for (int c = 0; c < C; ++c) variance[std::size_t(g) * C + c] *= inverse;
  }
}

/// The per-group scale and shift of a normalisation, y = x * scale + shift with scale = gamma rstd
/// and shift = beta - mean scale (mean and rstd: groups x C values), as channel patterns (groups
/// x pattern_length values each, in the tape's arena).
template <int C, class T>
std::pair<const T*, const T*> scale_and_shift_patterns(ad::tape& t, const basic_parameter<T>& gamma, const basic_parameter<T>& beta,
                                                       int groups, const T* mean, const T* rstd) {
  const std::size_t gc = std::size_t(groups) * C;
  T* scale = t.memory().allocate_array<T>(2 * gc);
  T* shift = scale + gc;
  for (int g = 0; g < groups; ++g)
    for (int c = 0; c < C; ++c) {
      const std::size_t k = std::size_t(g) * C + c;
      scale[k] = gamma.value[c] * rstd[k];
      shift[k] = beta.value[c] - mean[k] * scale[k];
    }
  return {expand_groups<C>(t, scale, groups), expand_groups<C>(t, shift, groups)};
}

/// y = (x - mean) * rstd * gamma + beta with per-group mean and rstd (groups x C values, group =
/// batch entry when `per_entry`). `batch_statistics` says whether mean and rstd came from x itself
/// (training: the backward pass differentiates through them) or are constants (running statistics).
/// Rows are processed as flat arrays against channel patterns (see pattern_length).
template <int C, class T>
ad::variable<C, T> normalize(ad::tape& t, const ad::variable<C, T>& x, basic_parameter<T>& gamma,
                             basic_parameter<T>& beta, bool per_entry, bool batch_statistics, const T* mean,
                             const T* rstd) {
  constexpr std::size_t P = pattern_length<C, T>;
  const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
  const int groups = per_entry ? B : 1;
  const std::size_t gc = std::size_t(groups) * C, n = std::size_t(W) * C;
  auto y = t.make_variable<C, T>(B, H, W, x.requires_grad || gamma.trainable() || beta.trainable());
  const auto patterns = scale_and_shift_patterns<C>(t, gamma, beta, groups, mean, rstd);
  const T* scale_pattern = patterns.first;
  const T* shift_pattern = patterns.second;
  for_each_row(B, H, x.value.size(), [&](int b, int r) {
    const std::size_t g = std::size_t(per_entry ? b : 0) * P;
    const T* in = x.value.pixel(b, r, 0);
    T* out = y.value.pixel(b, r, 0);
    for_each_chunk<C, T>(n, [&](std::size_t s, std::size_t len) {
      transform(len, out + s, [](auto v, auto sc, auto o) { return xsimd::fma(v, sc, o); }, in + s, scale_pattern + g,
                shift_pattern + g);
    });
  });
  if (!y.requires_grad) return y;
  const T* mean_pattern = expand_groups<C>(t, mean, groups);
  const T* rstd_pattern = expand_groups<C>(t, rstd, groups);
  ad::tape* tp = &t;
  t.record([=, x = x, &gamma, &beta]() mutable {
    // S1 = sum gy, S2 = sum gy * xhat per group and channel, xhat = (x - mean) * rstd.
    T* partial = tp->memory().allocate_array<T>(std::size_t(B) * H * 2 * C);
    T* sums = tp->memory().allocate_array<T>(2 * gc);
    row_channel_sums<C, 2>(B, H, W, partial, [&](int b, int r, std::size_t s, std::size_t len, T* acc) {
      const std::size_t g = std::size_t(per_entry ? b : 0) * P;
      const T* gy = y.grad.pixel(b, r, 0) + s;
      add_to(acc, gy, len);
      transform(len, acc + P, [](auto a, auto d, auto v, auto mu, auto rs) { return xsimd::fma(d, (v - mu) * rs, a); },
                acc + P, gy, x.value.pixel(b, r, 0) + s, mean_pattern + g, rstd_pattern + g);
    });
    const int rows_per_group = per_entry ? H : B * H;
    for (int g = 0; g < groups; ++g) {
      alignas(simd::alignment) T both[2 * C];
      sum_rows<2 * C>(partial, g * rows_per_group, (g + 1) * rows_per_group, both);
      std::copy_n(both, C, sums + std::size_t(g) * C);
      std::copy_n(both + C, C, sums + gc + std::size_t(g) * C);
    }
    for (int g = 0; g < groups; ++g)
      for (int c = 0; c < C; ++c) {
        if (gamma.trainable()) gamma.grad[c] += sums[gc + std::size_t(g) * C + c];
        if (beta.trainable()) beta.grad[c] += sums[std::size_t(g) * C + c];
      }
    if (!x.requires_grad) return;
    // Training: gx = gamma rstd (gy - S1/N - xhat S2/N); with constant statistics: gx = gamma rstd gy.
    // Stored as per-group coefficients: gx += k * gy + a * (x - mean) + d.
    const T inverse_n = T(1) / T(std::size_t(rows_per_group) * W);
    T* k = tp->memory().allocate_array<T>(3 * gc);
    T* a = k + gc;
    T* d = k + 2 * gc;
    for (std::size_t j = 0; j < gc; ++j) {
      k[j] = gamma.value[j % C] * rstd[j];
      a[j] = batch_statistics ? -k[j] * rstd[j] * sums[gc + j] * inverse_n : T(0);
      d[j] = batch_statistics ? -k[j] * sums[j] * inverse_n : T(0);
    }
    const T* k_pattern = expand_groups<C>(*tp, k, groups);
    const T* a_pattern = expand_groups<C>(*tp, a, groups);
    const T* d_pattern = expand_groups<C>(*tp, d, groups);
    for_each_row(B, H, x.value.size(), [&](int b, int r) {
      const std::size_t g = std::size_t(per_entry ? b : 0) * P;
      T* gx = x.grad.pixel(b, r, 0);
      const T* gy = y.grad.pixel(b, r, 0);
      const T* v = x.value.pixel(b, r, 0);
      for_each_chunk<C, T>(n, [&](std::size_t s, std::size_t len) {
        transform(
            len, gx + s,
            [](auto acc, auto dy, auto xv, auto mu, auto kk, auto aa, auto dd) {
              return acc + (xsimd::fma(kk, dy, aa * (xv - mu)) + dd);
            },
            gx + s, gy + s, v + s, mean_pattern + g, k_pattern + g, a_pattern + g, d_pattern + g);
      });
    });
  });
  return y;
}

}  // namespace detail

/// Instance normalisation: each image's channels normalised over height x width, then scaled and
/// shifted by the learned per-channel `weight` and `bias` (initially 1 and 0).
template <int C, class T = float>
class instance_norm {
 public:
  basic_parameter<T> weight;  ///< C scales (gamma)
  basic_parameter<T> bias;    ///< C shifts (beta)
  T epsilon = T(1e-5);        ///< added to the variance (PyTorch's default)

  explicit instance_norm(const std::string& name = "instance_norm")
      : weight(name + ".weight", {C}), bias(name + ".bias", {C}) {
    constant_init(weight, T(1));
  }

  /// Normalises x (batch x H x W x C) per batch entry and channel.
  ad::variable<C, T> operator()(ad::tape& t, const ad::variable<C, T>& x) {
    const auto [mean, rstd] = statistics(t, x.value);
    return detail::normalize(t, x, weight, bias, true, true, mean, rstd);
  }

  /// act(norm(x) + v), v broadcast over pixels: the values of add_channel_bias(t, (*this)(t, x), v,
  /// act) (nn/combine.hpp), bit for bit. x is consumed (nothing, the caller or a recorded backward,
  /// may read its tensor afterwards): where no gradient flows (x needs none, and the tape is not
  /// recording or neither v nor the weights need one) its tensor is normalised, biased and
  /// activated in place in one pass and returned, so an inference keeps one tensor where the two
  /// layers keep three and touches a third of the memory; otherwise the two layers run and are
  /// recorded as usual.
  template <class Act = identity_activation>
  ad::variable<C, T> with_channel_bias(ad::tape& t, ad::variable<C, T>&& x, const ad::variable<C, T>& v, const Act& act = {}) {
    if (x.requires_grad || (t.recording() && (v.requires_grad || weight.trainable() || bias.trainable())))
      return add_channel_bias(t, (*this)(t, x), v, act);
    const T* bias_pattern = detail::channel_bias_patterns(t, x.value, v.value, "nn::add_channel_bias");
    detail::require_in_place_activation(act, "nn::add_channel_bias");
    constexpr std::size_t P = detail::pattern_length<C, T>;
    const int B = x.value.batch();
    const std::size_t n = std::size_t(x.value.width()) * C;
    // detail::normalize's fma, then add_channel_bias's sum, per value.
    const auto [mean, rstd] = statistics(t, x.value);
    const auto patterns = detail::scale_and_shift_patterns<C>(t, weight, bias, B, mean, rstd);
    const T* scale_pattern = patterns.first;
    const T* shift_pattern = patterns.second;
    detail::for_each_row(B, x.value.height(), x.value.size(), [&](int b, int r) {
      T* row = x.value.pixel(b, r, 0);
      const std::size_t g = std::size_t(b) * P;
      detail::for_each_chunk<C, T>(n, [&](std::size_t s, std::size_t len) {
        detail::transform(
            len, row + s,
            [&](auto u, auto sc, auto sh, auto q) {
              if constexpr (std::is_same_v<Act, identity_activation>) return xsimd::fma(u, sc, sh) + q;
              else return act(xsimd::fma(u, sc, sh) + q);
            },
            row + s, scale_pattern + g, shift_pattern + g, bias_pattern + g);
      });
    });
    return std::move(x);
  }

  /// Visits the trainable weights (weight, then bias).
  template <class F>
  void for_each_parameter(F&& f) {
    f(weight);
    f(bias);
  }

 private:
  /// Each entry's channel means and 1 / sqrt(variance + epsilon) (batch x C values each, in the
  /// tape's arena).
  std::pair<const T*, const T*> statistics(ad::tape& t, const tensor<C, T>& x) const {
    if (x.height() * x.width() == 0) throw std::invalid_argument("nn::instance_norm: empty image");
    const std::size_t n = std::size_t(x.batch()) * C;
    T* mean = t.memory().allocate_array<T>(n);
    T* rstd = t.memory().allocate_array<T>(n);
    detail::channel_statistics(t, x, true, mean, rstd);
    for (std::size_t j = 0; j < n; ++j) rstd[j] = T(1) / std::sqrt(rstd[j] + epsilon);
    return {mean, rstd};
  }
};

/// Batch normalisation. Training mode normalises with the batch's statistics (over batch x H x W)
/// and updates the running statistics as PyTorch does (momentum 0.1, unbiased running variance);
/// evaluation mode (`training = false`) normalises with the running statistics.
template <int C, class T = float>
class batch_norm {
 public:
  basic_parameter<T> weight;        ///< C scales (gamma)
  basic_parameter<T> bias;          ///< C shifts (beta)
  basic_parameter<T> running_mean;  ///< C values; a buffer, not trained (frozen)
  basic_parameter<T> running_var;   ///< C values; a buffer, not trained (frozen)
  T epsilon = T(1e-5);              ///< added to the variance
  T momentum = T(0.1);              ///< running = (1 - momentum) running + momentum batch
  bool training = true;             ///< batch statistics (true) or running statistics (false)

  explicit batch_norm(const std::string& name = "batch_norm")
      : weight(name + ".weight", {C}), bias(name + ".bias", {C}), running_mean(name + ".running_mean", {C}),
        running_var(name + ".running_var", {C}) {
    constant_init(weight, T(1));
    constant_init(running_var, T(1));
    running_mean.frozen = running_var.frozen = true;
  }

  /// Normalises x per channel over the whole batch (training) or with the running statistics.
  ad::variable<C, T> operator()(ad::tape& t, const ad::variable<C, T>& x) {
    T* mean = t.memory().allocate_array<T>(C);
    T* rstd = t.memory().allocate_array<T>(C);
    if (training) {
      const std::size_t n = x.value.size() / C;
      if (n < 2) throw std::invalid_argument("nn::batch_norm: training needs more than one value per channel");
      detail::channel_statistics(t, x.value, false, mean, rstd);
      track(mean, rstd, n);  // rstd holds the variance here
      for (int c = 0; c < C; ++c) rstd[c] = T(1) / std::sqrt(rstd[c] + epsilon);
    } else {
      for (int c = 0; c < C; ++c) {
        mean[c] = running_mean.value[c];
        rstd[c] = T(1) / std::sqrt(running_var.value[c] + epsilon);
      }
    }
    return detail::normalize(t, x, weight, bias, false, training, mean, rstd);
  }

  /// Moves the running statistics towards a batch's per-channel `mean` and biased `variance` over
  /// `n` values per channel (momentum; the variance made unbiased), as training mode does.
  /// Exposed for a batch whose statistics are summed over several passes
  /// (training::autoencoder_gradient_parts).
  void track(const T* mean, const T* variance, std::size_t n) {
    const T unbiased = T(n) / T(n - 1);
    for (int c = 0; c < C; ++c) {
      running_mean.value[c] = (1 - momentum) * running_mean.value[c] + momentum * mean[c];
      running_var.value[c] = (1 - momentum) * running_var.value[c] + momentum * variance[c] * unbiased;
    }
  }

  /// Visits the trainable weights (weight, then bias).
  template <class F>
  void for_each_parameter(F&& f) {
    f(weight);
    f(bias);
  }

  /// Visits the state that is saved but not trained (running_mean, running_var).
  template <class F>
  void for_each_buffer(F&& f) {
    f(running_mean);
    f(running_var);
  }
};

}  // namespace anisocap::nn
