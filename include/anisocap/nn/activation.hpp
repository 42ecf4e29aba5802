#pragma once
/// @file
/// Element-wise activations of the estimator and the auto-encoder (docs/method.md section 7): leaky ReLU
/// (Deschaintre's encoder), SELU, tanh (the output layers map to the [-1, 1] network space of
/// docs/method.md section 1). Each is eager on whole tensors and records one backward closure.
#include <algorithm>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <type_traits>

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

// ---- activations a layer applies to its own output ----------------------------------------------
// A layer called as `layer(t, x, act)` applies `act` in place to its output and, in backward, turns
// the output's gradient into the pre-activation's in a tensor of its own, written rather than
// accumulated: the tape holds one tensor and one zeroed gradient fewer than `act(t, layer(t, x))`,
// with the same values and gradients. This works for activations whose derivative is a function of
// their output; each type below says how.

/// No activation: `layer(t, x)`.
struct identity_activation {};

/// Leaky ReLU as a layer's activation. Its derivative (1 or `slope`) follows from the output's
/// sign, which is the input's for slope >= 0.
template <class T>
struct leaky_relu_activation {
  T slope;  ///< the negative side's slope, >= 0
  /// The activation of a register of values.
  template <class B>
  B operator()(B v) const { return xsimd::select(v > T(0), v, v * slope); }
  /// The pre-activation's gradient from the output's gradient gy and the output y.
  template <class B>
  B gradient(B gy, B y) const { return xsimd::select(y > T(0), gy, gy * slope); }
};

/// The hyperbolic tangent as a layer's activation: its derivative is 1 - y^2.
template <class T>
struct tanh_activation {
  /// The activation of a register of values.
  template <class B>
  B operator()(B v) const { return xsimd::tanh(v); }
  /// The pre-activation's gradient from the output's gradient gy and the output y.
  template <class B>
  B gradient(B gy, B y) const { return gy * (T(1) - y * y); }
};

/// A layer's place in a plain chain, where each layer's output is read by the next layer only (the
/// auto-encoder's decoder). The gradient between two such layers is then written by the later
/// layer's backward, instead of being zeroed when the value is made and added to afterwards: one
/// pass over memory fewer each way. Both sides must agree; the default is no chain.
struct chain_link {
  /// The input is the output of a layer called with `output_to_next`: its gradient holds nothing
  /// until this layer's backward writes it.
  bool input_from_previous = false;
  /// The output goes to the next layer of the chain only (called with `input_from_previous`),
  /// which writes its gradient: it is not zeroed, and nothing may read or add to it before that.
  bool output_to_next = false;
};

namespace detail {

/// A layer's output: y.value = act(y.value) (nothing for identity_activation) and, where y needs a
/// gradient and `zero_gradient`, y.grad = 0, in one parallel pass over the rows: an output made
/// with gradient_init::by_caller has its gradient zeroed in the pass the activation makes anyway,
/// on every thread. Without `zero_gradient` the gradient stays uninitialised for the one layer
/// that writes it (chain_link).
template <int C, class T, class Act>
void activate_output(const Act& act, ad::variable<C, T>& y, bool zero_gradient = true) {
  constexpr bool activate = !std::is_same_v<Act, identity_activation>;
  const bool zero = y.requires_grad && zero_gradient;
  if (!activate && !zero) return;
  const std::size_t n = std::size_t(y.value.width()) * C;
  for_each_row(y.value.batch(), y.value.height(), y.value.size(), [&](int b, int r) {
    if constexpr (activate) {
      T* p = y.value.pixel(b, r, 0);
      transform(n, p, act, p);
    }
    if (zero) std::fill_n(y.grad.pixel(b, r, 0), n, T(0));
  });
}

/// g = act'(pre-activation) * gy, written, from the output y (nothing for identity_activation,
/// whose layer reads gy itself).
template <int C, class T, class Act>
void activation_gradient(const Act& act, const tensor<C, T>& y, const tensor<C, T>& gy, tensor<C, T>& g) {
  if constexpr (!std::is_same_v<Act, identity_activation>) {
    const std::size_t n = std::size_t(y.width()) * C;
    for_each_row(y.batch(), y.height(), y.size(), [&](int b, int r) {
      transform(n, g.pixel(b, r, 0), [&](auto gv, auto yv) { return act.gradient(gv, yv); }, gy.pixel(b, r, 0), y.pixel(b, r, 0));
    });
  }
}

/// Checks an activation a layer is asked to apply in place (a leaky ReLU's slope must be >= 0).
template <class Act>
void require_in_place_activation(const Act& act, const char* op) {
  if constexpr (requires { act.slope; }) {
    if (!(act.slope >= 0))
      throw std::invalid_argument(std::string(op) + ": a leaky ReLU applied in place needs a slope >= 0 (got " +
                                  std::to_string(double(act.slope)) + ")");
  }
}

/// The gradient tensor a layer's backward feeds to its own passes: the output's gradient itself
/// for identity_activation, else a new tensor in the tape that activation_gradient writes.
template <class Act, int C, class T>
tensor<C, T> pre_activation_gradient(ad::tape& t, const ad::variable<C, T>& y) {
  if constexpr (std::is_same_v<Act, identity_activation>) return y.grad;
  else return t.make_tensor<C, T>(y.value.batch(), y.value.height(), y.value.width());
}

}  // namespace detail

/// Leaky ReLU: x for x > 0, slope * x otherwise (the derivative at 0 is taken as `slope`, as PyTorch does).
template <int C, class T>
ad::variable<C, T> leaky_relu(ad::tape& t, const ad::variable<C, T>& x, T slope) {
  return detail::elementwise_activation(
      t, x, leaky_relu_activation<T>{slope},
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
      t, x, tanh_activation<T>{}, [](auto gy, auto, auto yv) { return tanh_activation<T>{}.gradient(gy, yv); });
}

}  // namespace anisocap::nn
