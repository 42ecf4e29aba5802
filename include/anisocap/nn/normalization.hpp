#pragma once
/// @file
/// Instance normalisation (per image and channel over height x width: Deschaintre's estimator) and
/// batch normalisation (per channel over batch x height x width: the end of Gao's encoder,
/// MODEL.md 7), both with a learned scale `weight` (gamma) and shift `bias` (beta).
///
/// Both share one kernel: statistics per group (a batch entry, or the whole batch), two passes
/// (mean, then centred variance, for accuracy), vectorised over channels, rows in parallel.
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

namespace detail {

/// Per-group channel mean and biased variance of x; a group is one batch entry
/// (`per_entry`) or the whole batch. mean and variance hold groups x C values.
template <int C, class T>
void channel_statistics(ad::tape& t, const tensor<C, T>& x, bool per_entry, T* mean, T* variance) {
  const int B = x.batch(), H = x.height(), W = x.width();
  const int groups = per_entry ? B : 1, rows_per_group = per_entry ? H : B * H;
  const T inverse = T(1) / T(std::size_t(rows_per_group) * W);
  T* partial = t.memory().allocate_array<T>(std::size_t(B) * H * C);
  row_channel_sums<C>(B, H, W, partial, [&](int b, int r, int i, T* acc) { add_to(acc, x.pixel(b, r, i), C); });
  for (int g = 0; g < groups; ++g) {
    sum_rows<C>(partial, g * rows_per_group, (g + 1) * rows_per_group, mean + std::size_t(g) * C);
    for (int c = 0; c < C; ++c) mean[std::size_t(g) * C + c] *= inverse;
  }
  row_channel_sums<C>(B, H, W, partial, [&](int b, int r, int i, T* acc) {
    const T* m = mean + std::size_t(per_entry ? b : 0) * C;
    transform(C, acc, [](auto a, auto v, auto mu) { return a + (v - mu) * (v - mu); }, acc, x.pixel(b, r, i), m);
  });
  for (int g = 0; g < groups; ++g) {
    sum_rows<C>(partial, g * rows_per_group, (g + 1) * rows_per_group, variance + std::size_t(g) * C);
    for (int c = 0; c < C; ++c) variance[std::size_t(g) * C + c] *= inverse;
  }
}

/// y = (x - mean) * rstd * gamma + beta with per-group mean and rstd (groups x C values, group =
/// batch entry when `per_entry`). `batch_statistics` says whether mean and rstd came from x itself
/// (training: the backward pass differentiates through them) or are constants (running statistics).
template <int C, class T>
ad::variable<C, T> normalize(ad::tape& t, const ad::variable<C, T>& x, basic_parameter<T>& gamma,
                             basic_parameter<T>& beta, bool per_entry, bool batch_statistics, const T* mean,
                             const T* rstd) {
  const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
  const int groups = per_entry ? B : 1;
  auto y = t.make_variable<C, T>(B, H, W, x.requires_grad || gamma.trainable() || beta.trainable());
  // Per-group scale and shift: y = x * scale + shift.
  T* scale = t.memory().allocate_array<T>(std::size_t(groups) * C);
  T* shift = t.memory().allocate_array<T>(std::size_t(groups) * C);
  for (int g = 0; g < groups; ++g)
    for (int c = 0; c < C; ++c) {
      const std::size_t k = std::size_t(g) * C + c;
      scale[k] = gamma.value[c] * rstd[k];
      shift[k] = beta.value[c] - mean[k] * scale[k];
    }
  for_each_row(B, H, x.value.size(), [&](int b, int r) {
    const std::size_t g = std::size_t(per_entry ? b : 0) * C;
    for (int i = 0; i < W; ++i)
      transform(C, y.value.pixel(b, r, i), [](auto v, auto s, auto o) { return xsimd::fma(v, s, o); },
                x.value.pixel(b, r, i), scale + g, shift + g);
  });
  if (!y.requires_grad) return y;
  ad::tape* tp = &t;
  t.record([=, x = x, &gamma, &beta]() mutable {
    const std::size_t gc = std::size_t(groups) * C;
    // S1 = sum gy, S2 = sum gy * xhat per group and channel, xhat = (x - mean) * rstd.
    T* partial = tp->memory().allocate_array<T>(std::size_t(B) * H * 2 * C);
    T* sums = tp->memory().allocate_array<T>(2 * gc);
    row_channel_sums<2 * C>(B, H, W, partial, [&](int b, int r, int i, T* acc) {
      const std::size_t g = std::size_t(per_entry ? b : 0) * C;
      const T* gy = y.grad.pixel(b, r, i);
      add_to(acc, gy, C);
      transform(C, acc + C, [](auto a, auto d, auto v, auto mu, auto s) { return xsimd::fma(d, (v - mu) * s, a); },
                acc + C, gy, x.value.pixel(b, r, i), mean + g, rstd + g);
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
    for_each_row(B, H, x.value.size(), [&](int b, int r) {
      const std::size_t g = std::size_t(per_entry ? b : 0) * C;
      for (int i = 0; i < W; ++i) {
        T* gx = x.grad.pixel(b, r, i);
        transform(
            C, gx,
            [](auto acc, auto gy, auto v, auto mu, auto kk, auto aa, auto dd) {
              return acc + (xsimd::fma(kk, gy, aa * (v - mu)) + dd);
            },
            gx, y.grad.pixel(b, r, i), x.value.pixel(b, r, i), mean + g, k + g, a + g, d + g);
      }
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
    if (x.value.height() * x.value.width() == 0) throw std::invalid_argument("nn::instance_norm: empty image");
    const std::size_t n = std::size_t(x.value.batch()) * C;
    T* mean = t.memory().allocate_array<T>(n);
    T* rstd = t.memory().allocate_array<T>(n);
    detail::channel_statistics(t, x.value, true, mean, rstd);
    for (std::size_t j = 0; j < n; ++j) rstd[j] = T(1) / std::sqrt(rstd[j] + epsilon);
    return detail::normalize(t, x, weight, bias, true, true, mean, rstd);
  }

  /// Visits the trainable weights (weight, then bias).
  template <class F>
  void for_each_parameter(F&& f) {
    f(weight);
    f(bias);
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
      const T unbiased = T(n) / T(n - 1);
      for (int c = 0; c < C; ++c) {
        running_mean.value[c] = (1 - momentum) * running_mean.value[c] + momentum * mean[c];
        running_var.value[c] = (1 - momentum) * running_var.value[c] + momentum * rstd[c] * unbiased;
        rstd[c] = T(1) / std::sqrt(rstd[c] + epsilon);
      }
    } else {
      for (int c = 0; c < C; ++c) {
        mean[c] = running_mean.value[c];
        rstd[c] = T(1) / std::sqrt(running_var.value[c] + epsilon);
      }
    }
    return detail::normalize(t, x, weight, bias, false, training, mean, rstd);
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
