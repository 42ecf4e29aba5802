#pragma once
/// @file
/// Element-wise activations of the estimator and the auto-encoder (docs/method.md section 7): leaky ReLU
/// (Deschaintre's encoder), SELU, tanh (the output layers map to the [-1, 1] network space of
/// docs/method.md section 1). Each is eager on whole tensors and records one backward closure.
#include <cstddef>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/kernels.hpp"

namespace anisocap::nn {

namespace detail {

/// Applies a batch op `forward(x)` to every value of x into a new variable and records
/// `gx += backward(gy, x, y)` (for activations whose derivative reads x or y).
template <int C, class T, class Forward, class Backward>
ad::variable<C, T> elementwise_activation(ad::tape& t, const ad::variable<C, T>& x, Forward forward, Backward backward) {
  auto y = t.make_variable<C, T>(x.value.batch(), x.value.height(), x.value.width(), x.requires_grad);
  const std::size_t n = std::size_t(x.value.width()) * C;
  for_each_row(x.value.batch(), x.value.height(), x.value.size(), [&](int b, int r) {
    transform(n, y.value.pixel(b, r, 0), forward, x.value.pixel(b, r, 0));
  });
  if (y.requires_grad) {
    t.record([x = x, y, backward, n]() mutable {
      for_each_row(x.value.batch(), x.value.height(), x.value.size(), [&](int b, int r) {
        T* gx = x.grad.pixel(b, r, 0);
        transform(n, gx, [&](auto g, auto gy, auto xv, auto yv) { return g + backward(gy, xv, yv); }, gx,
                  y.grad.pixel(b, r, 0), x.value.pixel(b, r, 0), y.value.pixel(b, r, 0));
      });
    });
  }
  return y;
}

}  // namespace detail

/// Leaky ReLU: x for x > 0, slope * x otherwise (the derivative at 0 is taken as `slope`, as PyTorch does).
template <int C, class T>
ad::variable<C, T> leaky_relu(ad::tape& t, const ad::variable<C, T>& x, T slope) {
  return detail::elementwise_activation(
      t, x, [slope](auto v) { return xsimd::select(v > T(0), v, v * slope); },
      [slope](auto gy, auto xv, auto) { return xsimd::select(xv > T(0), gy, gy * slope); });
}

/// SELU constants (Klambauer et al. 2017), the same as PyTorch's.
template <class T>
struct selu_constants {
  static constexpr T alpha = T(1.6732632423543772848170429916717);  ///< negative-side saturation
  static constexpr T scale = T(1.0507009873554804934193349852946);  ///< keeps unit variance through the layer
};

/// SELU: scale * x for x > 0, scale * alpha * (exp(x) - 1) otherwise.
template <int C, class T>
ad::variable<C, T> selu(ad::tape& t, const ad::variable<C, T>& x) {
  constexpr T alpha = selu_constants<T>::alpha, scale = selu_constants<T>::scale;
  return detail::elementwise_activation(
      t, x, [](auto v) { return xsimd::select(v > T(0), v * scale, (xsimd::exp(v) - T(1)) * (scale * alpha)); },
      // For x <= 0 the derivative scale * alpha * exp(x) equals y + scale * alpha: no exp in backward.
      [](auto gy, auto xv, auto yv) { return xsimd::select(xv > T(0), gy * scale, gy * (yv + scale * alpha)); });
}

/// Hyperbolic tangent; the derivative 1 - y^2 reads the output.
template <int C, class T>
ad::variable<C, T> tanh(ad::tape& t, const ad::variable<C, T>& x) {
  return detail::elementwise_activation(
      t, x, [](auto v) { return xsimd::tanh(v); },
      [](auto gy, auto, auto yv) { return gy * (T(1) - yv * yv); });
}

}  // namespace anisocap::nn
