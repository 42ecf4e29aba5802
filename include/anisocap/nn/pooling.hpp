#pragma once
/// @file
/// Reductions over pixels and over images: the spatial mean that starts the estimator's
/// global-feature track, and the max over the images of a set that fuses the per-image tracks of
/// the multi-image estimator (docs/method.md section 7, after Deschaintre 2019).
#include <cstddef>
#include <stdexcept>
#include <string>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/kernels.hpp"

namespace anisocap::nn {

/// Mean of every channel over height x width: the result is batch x 1 x 1 x C.
template <int C, class T>
ad::variable<C, T> spatial_mean(ad::tape& t, const ad::variable<C, T>& x) {
  const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
  if (H == 0 || W == 0) throw std::invalid_argument("nn::spatial_mean: empty image");
  auto y = t.make_variable<C, T>(B, 1, 1, x.requires_grad);
  T* partial = t.memory().allocate_array<T>(std::size_t(B) * H * C);
  detail::row_channel_sums<C>(B, H, W, partial, [&](int b, int r, std::size_t s, std::size_t n, T* acc) {
    detail::add_to(acc, x.value.pixel(b, r, 0) + s, n);
  });
  const T inverse = T(1) / T(std::size_t(H) * W);
  for (int b = 0; b < B; ++b) {
    T* out = y.value.pixel(b, 0, 0);
    detail::sum_rows<C>(partial, b * H, (b + 1) * H, out);
    for (int c = 0; c < C; ++c) out[c] *= inverse;
  }
  if (y.requires_grad) {
    ad::tape* tp = &t;
    t.record([x = x, y, inverse, tp]() mutable {
      // gx += gy / (H W): the output gradient, scaled and expanded to a channel pattern per entry.
      constexpr std::size_t P = detail::pattern_length<C, T>;
      const int B = x.value.batch();
      T* pattern = tp->memory().allocate_array<T>(std::size_t(B) * P);
      for (int b = 0; b < B; ++b) {
        alignas(simd::alignment) T scaled[C];
        for (int c = 0; c < C; ++c) scaled[c] = y.grad(b, 0, 0, c) * inverse;
        detail::expand_pattern<C>(scaled, pattern + std::size_t(b) * P);
      }
      const std::size_t n = std::size_t(x.value.width()) * C;
      detail::for_each_row(B, x.value.height(), x.value.size(), [&](int b, int r) {
        T* g = x.grad.pixel(b, r, 0);
        detail::for_each_chunk<C, T>(n, [&](std::size_t s, std::size_t len) {
          detail::add_to(g + s, pattern + std::size_t(b) * P, len);
        });
      });
    });
  }
  return y;
}

/// Max over the images of each set: the batch holds batch / images_per_set sets of
/// `images_per_set` consecutive entries; out[s] = max over k of x[s * images_per_set + k],
/// element by element. The gradient goes to the (first) argmax only.
template <int C, class T>
ad::variable<C, T> max_over_images(ad::tape& t, const ad::variable<C, T>& x, int images_per_set) {
  const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
  if (images_per_set <= 0 || B % images_per_set != 0)
    throw std::invalid_argument("nn::max_over_images: batch " + std::to_string(B) +
                                " is not a multiple of the set size " + std::to_string(images_per_set));
  const int sets = B / images_per_set;
  auto y = t.make_variable<C, T>(sets, H, W, x.requires_grad);
  // The argmax, stored as T (exact for small integers) so the SIMD selects stay in one type.
  tensor<C, T> argmax;
  if (y.requires_grad) argmax = t.make_tensor<C, T>(sets, H, W);
  const std::size_t n = std::size_t(W) * C;
  detail::for_each_row(sets, H, x.value.size(), [&](int s, int r) {
    T* out = y.value.pixel(s, r, 0);
    std::copy_n(x.value.pixel(s * images_per_set, r, 0), n, out);
    if (y.requires_grad) std::fill_n(argmax.pixel(s, r, 0), n, T(0));
    for (int k = 1; k < images_per_set; ++k) {
      const T* v = x.value.pixel(s * images_per_set + k, r, 0);
      if (y.requires_grad) {
        T* index = argmax.pixel(s, r, 0);
        const T kk = T(k);
        detail::transform(n, index, [kk](auto idx, auto m, auto c) { return xsimd::select(c > m, decltype(idx)(kk), idx); },
                          index, out, v);
      }
      detail::transform(n, out, [](auto m, auto c) { return xsimd::select(c > m, c, m); }, out, v);
    }
  });
  if (y.requires_grad) {
    t.record([x = x, y, argmax, images_per_set, n]() mutable {
      detail::for_each_row(y.value.batch(), y.value.height(), x.value.size(), [&](int s, int r) {
        const T* index = argmax.pixel(s, r, 0);
        for (int k = 0; k < images_per_set; ++k) {
          T* g = x.grad.pixel(s * images_per_set + k, r, 0);
          const T kk = T(k);
          detail::transform(n, g, [kk](auto a, auto gy, auto idx) { return a + xsimd::select(idx == kk, gy, decltype(gy)(0)); },
                            g, y.grad.pixel(s, r, 0), index);
        }
      });
    });
  }
  return y;
}

}  // namespace anisocap::nn
