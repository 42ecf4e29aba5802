#pragma once
/// @file
/// Nearest-neighbour upsampling by two: each pixel becomes a 2 x 2 block. Decoders that prefer
/// "upsample, then convolve" to a transposed convolution (no checkerboard artefacts) use it.
#include <algorithm>
#include <cstddef>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/kernels.hpp"

namespace anisocap::nn {

/// y(b, 2i + di, 2j + dj, c) = x(b, i, j, c) for di, dj in {0, 1}; the backward pass sums each
/// 2 x 2 block of the output gradient.
template <int C, class T>
ad::variable<C, T> upsample_nearest2x(ad::tape& t, const ad::variable<C, T>& x) {
  const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
  auto y = t.make_variable<C, T>(B, 2 * H, 2 * W, x.requires_grad);
  detail::for_each_row(B, H, y.value.size(), [&](int b, int i) {
    T* row = y.value.pixel(b, 2 * i, 0);
    for (int j = 0; j < W; ++j) {
      const T* p = x.value.pixel(b, i, j);
      std::copy_n(p, C, row + std::size_t(2 * j) * C);
      std::copy_n(p, C, row + std::size_t(2 * j + 1) * C);
    }
    std::copy_n(row, std::size_t(2 * W) * C, y.value.pixel(b, 2 * i + 1, 0));
  });
  if (y.requires_grad) {
    t.record([x = x, y, B, H, W]() mutable {
      detail::for_each_row(B, H, y.value.size(), [&](int b, int i) {
        for (int j = 0; j < W; ++j) {
          T* g = x.grad.pixel(b, i, j);
          const T *p = y.grad.pixel(b, 2 * i, 2 * j), *q = p + C, *r = y.grad.pixel(b, 2 * i + 1, 2 * j), *s = r + C;
          if constexpr (C % simd::width<T> == 0) {
            detail::transform(C, g, [](auto a, auto p0, auto q0, auto r0, auto s0) { return a + ((p0 + q0) + (r0 + s0)); },
                              g, p, q, r, s);
          } else {
            // Fewer channels than a register (or a ragged multiple): a plain loop of compile-time
            // length, same summation order.
            for (int c = 0; c < C; ++c) g[c] += (p[c] + q[c]) + (r[c] + s[c]);
          }
        }
      });
    });
  }
  return y;
}

}  // namespace anisocap::nn
