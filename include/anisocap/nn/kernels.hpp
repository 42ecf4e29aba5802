#pragma once
/// @file
/// The loops every non-convolution layer shares: element-wise SIMD transforms over a row's
/// contiguous values (xsimd, full registers, one padded register for the tail) and OpenMP over the
/// rows of large tensors. Reductions over pixels go through per-row partial sums in the tape's
/// arena, then a serial sum over rows, so results do not depend on the number of threads.
#include <algorithm>
#include <cstddef>
#include <numeric>
#include <stdexcept>
#include <string>

#include "anisocap/core/simd.hpp"
#include "anisocap/core/tensor.hpp"

namespace anisocap::nn::detail {

/// Tensors with fewer elements than this run on one thread: a parallel region costs a few
/// microseconds, more than the work it would split.
inline constexpr std::size_t parallel_threshold = std::size_t(1) << 15;

/// out[i] = op(in_0[i], in_1[i], ...) for i < n, on SIMD batches of T. `out` may alias an input
/// (loads of a chunk happen before its store), which is how gradients accumulate.
template <class T, class Op, class... In>
inline void transform(std::size_t n, T* out, Op&& op, const In*... in) {
  using B = simd::batch<T>;
  constexpr std::size_t W = B::size;
  std::size_t i = 0;
  for (; i + W <= n; i += W) op(B::load_unaligned(in + i)...).store_unaligned(out + i);
  if (i < n) {
    // The tail runs through the same batch code on zero-padded copies, so it rounds identically.
    const std::size_t r = n - i;
    auto load_tail = [&](const T* p) {
      alignas(simd::alignment) T buffer[W] = {};
      std::copy(p + i, p + n, buffer);
      return B::load_aligned(buffer);
    };
    alignas(simd::alignment) T result[W];
    op(load_tail(in)...).store_aligned(result);
    std::copy(result, result + r, out + i);
  }
}

/// acc[i] += x[i] for i < n.
template <class T>
inline void add_to(T* acc, const T* x, std::size_t n) {
  transform(n, acc, [](auto a, auto b) { return a + b; }, acc, x);
}

/// acc[c] += x[c] for the C channels of one pixel: SIMD when C is a whole number of registers, a
/// plain loop of compile-time length otherwise (the padded-register tail would cost more).
template <int C, class T>
inline void add_channels(T* acc, const T* x) {
  if constexpr (C % simd::width<T> == 0) add_to(acc, x, C);
  else for (int c = 0; c < C; ++c) acc[c] += x[c];
}

/// Calls f(b, y) for every row of a batch x height image stack, on all threads when `elements`
/// (the work's size) is large. f must only write memory that belongs to its row.
template <class F>
inline void for_each_row(int batch, int height, std::size_t elements, F&& f) {
  const int rows = batch * height;
#pragma omp parallel for schedule(static) if (elements >= parallel_threshold)
  for (int r = 0; r < rows; ++r) f(r / height, r % height);
}

/// The exception require_same_shape throws; out of line and not a template, so that each op's
/// check stays a comparison and a call.
[[noreturn, gnu::cold, gnu::noinline]] inline void throw_shapes_differ(const char* op, int b1, int h1, int w1, int b2, int h2, int w2) {
  throw std::invalid_argument(std::string(op) + ": shape mismatch (" + std::to_string(b1) + "x" + std::to_string(h1) + "x" +
                              std::to_string(w1) + " vs " + std::to_string(b2) + "x" + std::to_string(h2) + "x" +
                              std::to_string(w2) + ")");
}

/// Throws std::invalid_argument naming `op` when two tensors differ in batch, height or width.
template <int C1, int C2, class T>
inline void require_same_shape(const tensor<C1, T>& a, const tensor<C2, T>& b, const char* op) {
  if (!a.same_spatial_shape(b)) throw_shapes_differ(op, a.batch(), a.height(), a.width(), b.batch(), b.height(), b.width());
}

/// Length of a channel pattern: a whole number of pixels (a multiple of C) and of SIMD registers,
/// and at least about 512 values. Per-channel coefficients expanded to this length let a row's
/// values be processed as one flat array with full registers even when C is not a multiple of the
/// register width (C = 3, 8, 12 in the networks' outer layers).
template <int C, class T>
inline constexpr std::size_t pattern_length = [] {
  const std::size_t l = std::lcm(std::size_t(C), simd::width<T>);
  return l * std::max<std::size_t>(1, 512 / l);
}();

/// pattern[j] = per_channel[j % C] for j < pattern_length<C, T>.
template <int C, class T>
inline void expand_pattern(const T* per_channel, T* pattern) {
  for (std::size_t j = 0; j < pattern_length<C, T>; j += C) std::copy_n(per_channel, C, pattern + j);
}

/// Per-row channel sums over flat chunks of a row's width * C values. Chunks start at multiples of
/// P = pattern_length<C, T> (so value j of a chunk is channel j % C) and hold at most P values;
/// `f(b, y, offset, length, acc)` adds the chunk's values to acc[0, length) (and with Sums = 2 a
/// second quantity to acc[P, P + length)). Then partial[((b * height + y) * Sums + s) * C + c] is the
/// sum of quantity s over the row's pixels. Rows run in parallel when large.
template <int C, int Sums = 1, class T, class F>
inline void row_channel_sums(int batch, int height, int width, T* partial, F&& f) {
  constexpr std::size_t P = pattern_length<C, T>;
  const std::size_t n = std::size_t(width) * C;
  for_each_row(batch, height, std::size_t(batch) * height * n, [&](int b, int y) {
    alignas(simd::alignment) T acc[Sums * P];
    std::fill_n(acc, Sums * P, T(0));
    for (std::size_t s = 0; s < n; s += P) f(b, y, s, std::min(P, n - s), acc);
    T* out = partial + (std::size_t(b) * height + y) * Sums * C;
    const std::size_t used = std::min(P, n);  // a short row leaves the rest of acc at zero
    for (int k = 0; k < Sums; ++k) {
      T* o = out + std::size_t(k) * C;
      std::copy_n(acc + k * P, C, o);
      for (std::size_t j = C; j < used; j += C)
        for (int c = 0; c < C; ++c) o[c] += acc[k * P + j + c];
    }
  });
}

/// Calls f(offset, length) for the chunks of a row of n values that row_channel_sums uses.
template <int C, class T, class F>
inline void for_each_chunk(std::size_t n, F&& f) {
  constexpr std::size_t P = pattern_length<C, T>;
  for (std::size_t s = 0; s < n; s += P) f(s, std::min(P, n - s));
}

/// sums[c] = sum over rows [r0, r1) of partial[r * C + c] (serial: deterministic).
template <int C, class T>
inline void sum_rows(const T* partial, int r0, int r1, T* sums) {
  std::fill(sums, sums + C, T(0));
  for (int r = r0; r < r1; ++r) add_to(sums, partial + std::size_t(r) * C, C);
}

}  // namespace anisocap::nn::detail
