#pragma once
/// @file
/// Fully connected layer, applied to every pixel's channel vector. On the batch x 1 x 1 x C output
/// of `spatial_mean` it is the dense layer of the estimator's global-feature track (docs/method.md section 7).
#include <cstddef>
#include <cstdint>
#include <string>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/kernels.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

namespace detail {

/// Dot product of N values on SIMD batches. N is a compile-time length (a layer's channel count),
/// so the scalar tail exists only when N is not a whole number of registers.
template <std::size_t N, class T>
inline T dot(const T* a, const T* b) {
  using B = simd::batch<T>;
  constexpr std::size_t W = B::size;
  constexpr std::size_t whole = N - N % W;
  B acc(T(0));
  for (std::size_t i = 0; i < whole; i += W) acc = xsimd::fma(B::load_unaligned(a + i), B::load_unaligned(b + i), acc);
  // Lanes summed through memory (xsimd's AVX-512 hadd trips a GCC 12 false -Wmaybe-uninitialized).
  alignas(simd::alignment) T lanes[W];
  acc.store_aligned(lanes);
  T s = T(0);
  for (std::size_t l = 0; l < W; ++l) s += lanes[l];
  if constexpr (whole < N)
    for (std::size_t i = whole; i < N; ++i) s += a[i] * b[i];
  return s;
}

/// y[i] += alpha * x[i] for i < n.
template <class T>
inline void axpy(T alpha, const T* x, T* y, std::size_t n) {
  transform(n, y, [alpha](auto yv, auto xv) { return xsimd::fma(decltype(xv)(alpha), xv, yv); }, y, x);
}

}  // namespace detail

/// y = W x + b at every pixel. `weight` is Cout x Cin (row o holds output o's weights, the layout of
/// PyTorch's nn.Linear, so weight files exchange without transposes); `bias` has Cout values.
template <int Cin, int Cout, class T = float>
class linear {
 public:
  basic_parameter<T> weight;  ///< Cout x Cin
  basic_parameter<T> bias;    ///< Cout

  /// Parameters are named `name.weight` and `name.bias`; weights start He-uniform (seeded,
  /// identical on every machine), biases at zero.
  explicit linear(const std::string& name = "linear", std::uint64_t seed = 0)
      : weight(name + ".weight", {Cout, Cin}), bias(name + ".bias", {Cout}) {
    he_uniform(weight, Cin, seed);
  }

  /// Applies the layer; records weight gradients only for parameters that are not frozen and the
  /// input gradient only when x requires it.
  ad::variable<Cout, T> operator()(ad::tape& t, const ad::variable<Cin, T>& x) {
    const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
    auto y = t.make_variable<Cout, T>(B, H, W, x.requires_grad || weight.trainable() || bias.trainable());
    const T* w = weight.value.data();
    const T* b = bias.value.data();
    detail::for_each_row(B, H, std::size_t(B) * H * W * Cin * Cout / 8, [&](int bi, int r) {
      for (int i = 0; i < W; ++i) {
        const T* in = x.value.pixel(bi, r, i);
        T* out = y.value.pixel(bi, r, i);
        for (int o = 0; o < Cout; ++o) out[o] = b[o] + detail::dot<std::size_t(Cin)>(w + std::size_t(o) * Cin, in);
      }
    });
    if (y.requires_grad) {
      t.record([this, x = x, y]() mutable { backward(x, y); });
    }
    return y;
  }

  /// Visits the trainable weights (weight, then bias).
  template <class F>
  void for_each_parameter(F&& f) {
    f(weight);
    f(bias);
  }

 private:
  void backward(ad::variable<Cin, T>& x, const ad::variable<Cout, T>& y) {
    const int B = x.value.batch(), H = x.value.height(), W = x.value.width();
    const std::size_t work = std::size_t(B) * H * W * Cin * Cout / 8;
    if (x.requires_grad) {
      const T* w = weight.value.data();
      detail::for_each_row(B, H, work, [&](int bi, int r) {
        for (int i = 0; i < W; ++i) {
          const T* g = y.grad.pixel(bi, r, i);
          T* gx = x.grad.pixel(bi, r, i);
          for (int o = 0; o < Cout; ++o) detail::axpy(g[o], w + std::size_t(o) * Cin, gx, Cin);
        }
      });
    }
    if (weight.trainable()) {
      // Each output row of the weight gradient belongs to one thread: no races, fixed sum order.
      T* gw = weight.grad.data();
#pragma omp parallel for schedule(static) if (work >= detail::parallel_threshold)
      for (int o = 0; o < Cout; ++o)
        for (int bi = 0; bi < B; ++bi)
          for (int r = 0; r < H; ++r)
            for (int i = 0; i < W; ++i)
              detail::axpy(y.grad.pixel(bi, r, i)[o], x.value.pixel(bi, r, i), gw + std::size_t(o) * Cin, Cin);
    }
    if (bias.trainable()) {
      T* gb = bias.grad.data();
      for (int bi = 0; bi < B; ++bi)
        for (int r = 0; r < H; ++r)
          for (int i = 0; i < W; ++i) detail::add_to(gb, y.grad.pixel(bi, r, i), Cout);
    }
  }
};

}  // namespace anisocap::nn
