#pragma once
/// @file
/// Operations that join tensors: element-wise sum, concatenation along channels (U-Net skip
/// connections, docs/method.md section 7) and the per-channel bias broadcast that adds the estimator's global
/// feature vector to every pixel of the next layer (Deschaintre 2018's global-feature track).
#include <algorithm>
#include <cstddef>
#include <stdexcept>
#include <string>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/kernels.hpp"

namespace anisocap::nn {

/// a + b, element by element (same shape).
template <int C, class T>
ad::variable<C, T> add(ad::tape& t, const ad::variable<C, T>& a, const ad::variable<C, T>& b) {
  detail::require_same_shape(a.value, b.value, "nn::add");
  auto y = t.make_variable<C, T>(a.value.batch(), a.value.height(), a.value.width(), a.requires_grad || b.requires_grad);
  const std::size_t n = std::size_t(a.value.width()) * C;
  detail::for_each_row(a.value.batch(), a.value.height(), a.value.size(), [&](int bi, int r) {
    detail::transform(n, y.value.pixel(bi, r, 0), [](auto u, auto v) { return u + v; }, a.value.pixel(bi, r, 0),
                      b.value.pixel(bi, r, 0));
  });
  if (y.requires_grad) {
    t.record([a = a, b = b, y, n]() mutable {
      detail::for_each_row(y.value.batch(), y.value.height(), y.value.size(), [&](int bi, int r) {
        if (a.requires_grad) detail::add_to(a.grad.pixel(bi, r, 0), y.grad.pixel(bi, r, 0), n);
        if (b.requires_grad) detail::add_to(b.grad.pixel(bi, r, 0), y.grad.pixel(bi, r, 0), n);
      });
    });
  }
  return y;
}

/// Concatenation along channels: the first C1 channels of the result are a's, the next C2 are b's.
template <int C1, int C2, class T>
ad::variable<C1 + C2, T> concat(ad::tape& t, const ad::variable<C1, T>& a, const ad::variable<C2, T>& b) {
  detail::require_same_shape(a.value, b.value, "nn::concat");
  constexpr int C = C1 + C2;
  auto y = t.make_variable<C, T>(a.value.batch(), a.value.height(), a.value.width(), a.requires_grad || b.requires_grad);
  const int w = a.value.width();
  detail::for_each_row(a.value.batch(), a.value.height(), y.value.size(), [&](int bi, int r) {
    for (int x = 0; x < w; ++x) {
      T* out = y.value.pixel(bi, r, x);
      std::copy_n(a.value.pixel(bi, r, x), C1, out);
      std::copy_n(b.value.pixel(bi, r, x), C2, out + C1);
    }
  });
  if (y.requires_grad) {
    t.record([a = a, b = b, y, w]() mutable {
      detail::for_each_row(y.value.batch(), y.value.height(), y.value.size(), [&](int bi, int r) {
        for (int x = 0; x < w; ++x) {
          const T* g = y.grad.pixel(bi, r, x);
          if (a.requires_grad) detail::add_channels<C1>(a.grad.pixel(bi, r, x), g);
          if (b.requires_grad) detail::add_channels<C2>(b.grad.pixel(bi, r, x), g + C1);
        }
      });
    });
  }
  return y;
}

namespace detail {

/// A channel bias v for x (batch x 1 x 1 x C, one C-vector per entry of x) checked, and each
/// entry's bias expanded to a channel pattern (batch x pattern_length values, in the tape's arena),
/// so that rows are added as flat arrays. Throws std::invalid_argument naming `op` for another shape.
template <int C, class T>
const T* channel_bias_patterns(ad::tape& t, const tensor<C, T>& x, const tensor<C, T>& v, const char* op) {
  if (v.batch() != x.batch() || v.height() != 1 || v.width() != 1)
    throw std::invalid_argument(std::string(op) + ": the bias must be batch x 1 x 1 x C with the input's batch");
  constexpr std::size_t P = pattern_length<C, T>;
  T* pattern = t.memory().allocate_array<T>(std::size_t(x.batch()) * P);
  for (int b = 0; b < x.batch(); ++b) expand_pattern<C>(v.pixel(b, 0, 0), pattern + std::size_t(b) * P);
  return pattern;
}

}  // namespace detail

/// act(x + v), v broadcast over pixels: v holds one C-vector per batch entry (batch x 1 x 1 x C),
/// added to every pixel of that entry. This is how the global-feature track feeds a layer
/// (docs/method.md section 7). `act` (nn/activation.hpp, none by default) is applied in the same
/// pass, as the layers apply theirs: the same values and gradients as act(t, add_channel_bias(t, x, v)).
template <int C, class T, class Act = identity_activation>
ad::variable<C, T> add_channel_bias(ad::tape& t, const ad::variable<C, T>& x, const ad::variable<C, T>& v, const Act& act = {}) {
  const T* pattern = detail::channel_bias_patterns(t, x.value, v.value, "nn::add_channel_bias");
  detail::require_in_place_activation(act, "nn::add_channel_bias");
  auto y = t.make_variable<C, T>(x.value.batch(), x.value.height(), x.value.width(), x.requires_grad || v.requires_grad);
  constexpr std::size_t P = detail::pattern_length<C, T>;
  const int w = x.value.width();
  const std::size_t n = std::size_t(w) * C;
  detail::for_each_row(x.value.batch(), x.value.height(), x.value.size(), [&](int b, int r) {
    const T* in = x.value.pixel(b, r, 0);
    T* out = y.value.pixel(b, r, 0);
    detail::for_each_chunk<C, T>(n, [&](std::size_t s, std::size_t len) {
      if constexpr (std::is_same_v<Act, identity_activation>)
        detail::transform(len, out + s, [](auto p, auto q) { return p + q; }, in + s, pattern + std::size_t(b) * P);
      else
        detail::transform(len, out + s, [&](auto p, auto q) { return act(p + q); }, in + s, pattern + std::size_t(b) * P);
    });
  });
  if (y.requires_grad) {
    ad::tape* tp = &t;
    t.record([x = x, v = v, y, g = detail::pre_activation_gradient<Act>(t, y), act, w, n, tp]() mutable {
      const int B = y.value.batch(), H = y.value.height();
      detail::activation_gradient(act, y.value, y.grad, g);  // g: the gradient of x + v
      if (x.requires_grad)
        detail::for_each_row(B, H, y.value.size(), [&](int b, int r) {
          detail::add_to(x.grad.pixel(b, r, 0), g.pixel(b, r, 0), n);
        });
      if (v.requires_grad) {
        T* partial = tp->memory().allocate_array<T>(std::size_t(B) * H * C);
        detail::row_channel_sums<C>(B, H, w, partial, [&](int b, int r, std::size_t s, std::size_t len, T* acc) {
          detail::add_to(acc, g.pixel(b, r, 0) + s, len);
        });
        alignas(simd::alignment) T sums[C];
        for (int b = 0; b < B; ++b) {
          detail::sum_rows<C>(partial, b * H, (b + 1) * H, sums);
          detail::add_to(v.grad.pixel(b, 0, 0), sums, C);
        }
      }
    });
  }
  return y;
}

}  // namespace anisocap::nn
