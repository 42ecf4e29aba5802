#pragma once
/// @file
/// 4x4 stride-2 padding-1 transposed convolution (output 2H x 2W), the up-sampling layer of the
/// auto-encoder's decoder (docs/method.md section 7, after Gao 2019). Same semantics as PyTorch's
/// ConvTranspose2d(Cin, Cout, 4, stride=2, padding=1): out[2i-1+kh][2j-1+kw] += in[i][j] W[kh][kw].
///
/// Weight layout [4][4][Cin][Cout] (kh, kw, in, out), bias [Cout]. Each output parity is a 2x2
/// convolution over the input, so the forward pass runs through the same register-blocked kernel
/// as a convolution, at the same speed; its input gradient is a 4x4 stride-2 convolution.
#include "anisocap/nn/combine.hpp"
#include "anisocap/nn/conv.hpp"

namespace anisocap::nn {

/// Output height (or width) of a 4x4 stride-2 pad-1 transposed convolution: twice the input.
constexpr int conv_transpose2d_output_size(int n) { return 2 * n; }

/// Forward transposed convolution; out must be batch x 2H x 2W; bias may be null.
template <int Cin, int Cout, class T>
void conv_transpose2d_forward(const tensor<Cin, T>& in, const T* weight, const std::type_identity_t<T>* bias, tensor<Cout, T>& out) {
  namespace dc = detail::conv;
  dc::require_shape(out, in.batch(), 2 * in.height(), 2 * in.width(), "conv_transpose2d_forward", "output");
  if (out.empty()) return;
  const auto [w, b] = dc::forward_weights<16, Cin, Cout>(weight, bias);
  const auto a = dc::padded(in, 1, 1, in.height() + 2, in.width() + 2, Cin, 0);
  dc::transposed_core<Cin, Cout>(a, w, b, out, false);
}

/// conv_transpose2d_forward of the channel concatenation [a, b] (Cin = C1 + C2), which is never
/// formed: a and b are copied straight into the padded buffer the kernel reads. The same values
/// as forming it; a and b must have the same shape.
template <int C1, int C2, int Cout, class T>
void conv_transpose2d_forward_concat(const tensor<C1, T>& a, const tensor<C2, T>& b, const T* weight,
                                     const std::type_identity_t<T>* bias, tensor<Cout, T>& out) {
  namespace dc = detail::conv;
  dc::require_shape(out, a.batch(), 2 * a.height(), 2 * a.width(), "conv_transpose2d_forward", "output");
  dc::require_shape(b, a.batch(), a.height(), a.width(), "conv_transpose2d_forward", "the second input");
  if (out.empty()) return;
  const auto [w, bb] = dc::forward_weights<16, C1 + C2, Cout>(weight, bias);
  const auto p = dc::padded_concat(a, b, 1, 1, a.height() + 2, a.width() + 2, 0);
  dc::transposed_core<C1 + C2, Cout>(p, w, bb, out, false);
}

namespace detail::conv {

/// The input gradient, ACCUMULATED into grad_in (written over it where not `accumulate`), from the
/// output gradient padded by one pixel on each side (`a`, Cout channels a pixel): in[i][j] fed
/// out[2i-1+kh][2j-1+kw], so its gradient is a 4x4 stride-2 pad-1 convolution of the output
/// gradient with the transposed kernel (in <-> out).
template <int Cin, int Cout, class T>
void transposed_input_gradient(const padded_source<T>& a, const T* weight, tensor<Cin, T>& grad_in, bool accumulate) {
  if (prefer_in_cache_transpose<T>(std::size_t(16) * Cin * Cout, grad_in.size() / Cin)) {
    // Few pixels for a large kernel: transpose it block by block inside the work items.
    conv_core<Cout, Cin, 4, 2>(a, in_cache_transposed<Cin, Cout>(weight), nullptr, grad_in, accumulate);
  } else {
    conv_core<Cout, Cin, 4, 2>(a, input_gradient_weights<16, Cin, Cout>(weight, false), nullptr, grad_in, accumulate);
  }
}

/// The weight gradient [4][4][Cin][Cout], ACCUMULATED, from the input and the output gradient
/// padded by one pixel on each side (`g`, ldg channels a pixel):
/// gW[kh][kw] = sum over input pixels (i, j) of in[i][j] (x) grad_out[2i-1+kh][2j-1+kw].
template <int Cin, int Cout, class T>
void transposed_weight_gradient(const tensor<Cin, T>& in, const padded_source<T>& g, int ldg, T* grad_weight) {
  weight_pass<T> ps;
  ps.a = in.data();
  ps.a_batch = in.batch_stride();
  ps.a_row = in.row_stride();
  ps.a_col = Cin;
  ps.g = g.data;
  ps.g_batch = g.batch_stride;
  ps.g_row = 2 * g.row_stride;
  ps.g_col = 2 * ldg;
  ps.batch = in.batch();
  ps.rows = in.height();
  ps.cols = in.width();
  ps.taps = 16;
  for (int kh = 0; kh < 4; ++kh)
    for (int kw = 0; kw < 4; ++kw) ps.g_tap[kh * 4 + kw] = kh * g.row_stride + kw * ldg;
  run_weight_of<Cin, Cout>(ps, grad_weight);
}

/// Whether conv_transpose2d_backward_activated writes the activation's gradient straight into the
/// padded copy its passes read (where the weights need a gradient): an activation, and one padded
/// copy read alike by both passes.
template <class Act, int Cin, int Cout, class T>
inline constexpr bool writes_padded_activation_gradient =
    !std::is_same_v<Act, identity_activation> && weight_gradient_channels<T, Cin, Cout> == Cout;

/// padded(g, 1, 1, 2H + 2, 2W + 2, C, slot) of a layer's pre-activation gradient g = act'(y) * gy
/// (activation_gradient's values, bit for bit), written straight into the padded buffer: g itself
/// is never formed.
template <int C, class T, class Act>
padded_source<T> padded_activation_gradient(const Act& act, const tensor<C, T>& y, const tensor<C, T>& gy, int slot) {
  const int B = y.batch(), Hp = y.height() + 2, Wp = y.width() + 2;
  T* buffer = scratch<T>(slot, std::size_t(B) * Hp * Wp * C);
  pad_rows(B, y.height(), y.width(), 1, 1, Hp, Wp, C, buffer, [&](int b, int r, int x0, int x1, T* d) {
    transform(std::size_t(x1 - x0) * C, d, [&](auto gv, auto yv) { return act.gradient(gv, yv); }, gy.pixel(b, r, x0 - 1),
              y.pixel(b, r, x0 - 1));
  });
  return {buffer, std::ptrdiff_t(Hp) * Wp * C, std::ptrdiff_t(Wp) * C};
}

/// The passes of a transposed convolution's backward from one padded copy `g` of the output
/// gradient (Cout channels a pixel, 2H + 2 x 2W + 2 with a border of one, H x W the input's):
/// the bias's gradient summed from the copy's interior (null: skipped), the input's accumulated
/// into grad_in, or written over it where not `accumulate` (null: skipped), and the weights'.
template <int Cin, int Cout, class T>
void transposed_backward_passes(const tensor<Cin, T>& in, const padded_source<T>& g, const T* weight, tensor<Cin, T>* grad_in,
                                T* grad_weight, T* grad_bias, bool accumulate) {
  const int B = in.batch(), H = in.height(), W = in.width();
  if (grad_bias) bias_gradient(tensor<Cout, T>::wrap(const_cast<T*>(g.data), B, 2 * H + 2, 2 * W + 2).tile(1, 1, 2 * H, 2 * W), grad_bias);
  if (grad_in) transposed_input_gradient<Cin, Cout>(g, weight, *grad_in, accumulate);
  transposed_weight_gradient<Cin, Cout>(in, g, Cout, grad_weight);
}

}  // namespace detail::conv

/// How a backward pass stores an input's gradient: added to what the tensor holds (the tape's rule:
/// each reader of a value adds its share), or written over it (the one reader of a value whose
/// gradient was left uninitialised; chain_link).
enum class input_gradient { accumulated, written };

/// Gradient for the input, ACCUMULATED into grad_in (batch x H x W; grad_out is batch x 2H x 2W),
/// or written over it with input_gradient::written.
template <int Cin, int Cout, class T>
void conv_transpose2d_backward_input(const tensor<Cout, T>& grad_out, const T* weight, tensor<Cin, T>& grad_in,
                                     input_gradient mode = input_gradient::accumulated) {
  namespace dc = detail::conv;
  const int H = grad_in.height(), W = grad_in.width();
  dc::require_shape(grad_out, grad_in.batch(), 2 * H, 2 * W, "conv_transpose2d_backward_input", "output gradient");
  if (grad_in.empty()) return;
  dc::transposed_input_gradient<Cin, Cout>(dc::padded(grad_out, 1, 1, 2 * H + 2, 2 * W + 2, Cout, 0), weight, grad_in,
                                           mode == input_gradient::accumulated);
}

/// Gradients for the weights [4][4][Cin][Cout] and bias [Cout] (null: skipped), ACCUMULATED.
template <int Cin, int Cout, class T>
void conv_transpose2d_backward_weight(const tensor<Cin, T>& in, const tensor<Cout, T>& grad_out,
                                      std::type_identity_t<T>* grad_weight, std::type_identity_t<T>* grad_bias) {
  namespace dc = detail::conv;
  const int H = in.height(), W = in.width();
  dc::require_shape(grad_out, in.batch(), 2 * H, 2 * W, "conv_transpose2d_backward_weight", "output gradient");
  if (in.empty()) return;
  if (grad_bias) dc::bias_gradient(grad_out, grad_bias);
  if (!grad_weight) return;
  constexpr int ldg = dc::weight_gradient_channels<T, Cin, Cout>;
  dc::transposed_weight_gradient<Cin, Cout>(in, dc::padded(grad_out, 1, 1, 2 * H + 2, 2 * W + 2, ldg, 2), ldg, grad_weight);
}

/// Every gradient of a transposed convolution at once, ACCUMULATED: the input's into grad_in (or
/// written over it, `mode`), the weights' and the bias's (each null: skipped). The same values as
/// conv_transpose2d_backward_input and conv_transpose2d_backward_weight; where both passes read
/// the output gradient's padded copy alike (its channels whole registers, or only broadcast by the
/// weight pass), it is made once.
template <int Cin, int Cout, class T>
void conv_transpose2d_backward(const tensor<Cin, T>& in, const tensor<Cout, T>& grad_out, const std::type_identity_t<T>* weight,
                               tensor<Cin, std::type_identity_t<T>>* grad_in,
                               std::type_identity_t<T>* grad_weight, std::type_identity_t<T>* grad_bias,
                               input_gradient mode = input_gradient::accumulated) {
  namespace dc = detail::conv;
  constexpr int ldg = dc::weight_gradient_channels<T, Cin, Cout>;
  if (ldg != Cout || !grad_in || !grad_weight) {
    if (grad_in) conv_transpose2d_backward_input<Cin, Cout>(grad_out, weight, *grad_in, mode);
    conv_transpose2d_backward_weight<Cin, Cout>(in, grad_out, grad_weight, grad_bias);
    return;
  }
  const int H = in.height(), W = in.width();
  dc::require_shape(*grad_in, in.batch(), H, W, "conv_transpose2d_backward", "input gradient");
  dc::require_shape(grad_out, in.batch(), 2 * H, 2 * W, "conv_transpose2d_backward", "output gradient");
  if (in.empty()) return;
  dc::transposed_backward_passes<Cin, Cout>(in, dc::padded(grad_out, 1, 1, 2 * H + 2, 2 * W + 2, Cout, 0), weight, grad_in, grad_weight,
                                            grad_bias, mode == input_gradient::accumulated);
}

/// conv_transpose2d_backward of a layer's pre-activation gradient act'(y) * gy, from its output y and
/// the output's gradient gy: the same values. Where the passes read one padded copy of that
/// gradient (its channels whole registers, or only broadcast by the weight pass) and the weights
/// need a gradient, the activation's gradient is written straight into the copy, and the bias's
/// gradient is summed from it: two passes over memory fewer. Otherwise through `g` (y's shape), as
/// activation_gradient then conv_transpose2d_backward; `g` may be empty where it is not used
/// (detail::conv::writes_padded_activation_gradient and a weight gradient).
template <int Cin, int Cout, class T, class Act>
void conv_transpose2d_backward_activated(const Act& act, const tensor<Cin, T>& in, const tensor<Cout, T>& y,
                                         const tensor<Cout, T>& gy, tensor<Cout, T>& g, const std::type_identity_t<T>* weight,
                                         tensor<Cin, std::type_identity_t<T>>* grad_in, std::type_identity_t<T>* grad_weight,
                                         std::type_identity_t<T>* grad_bias, input_gradient mode = input_gradient::accumulated) {
  namespace dc = detail::conv;
  if constexpr (dc::writes_padded_activation_gradient<Act, Cin, Cout, T>) {
    if (grad_weight) {
      const int B = in.batch(), H = in.height(), W = in.width();
      dc::require_shape(y, B, 2 * H, 2 * W, "conv_transpose2d_backward", "output");
      dc::require_shape(gy, B, 2 * H, 2 * W, "conv_transpose2d_backward", "output gradient");
      if (grad_in) dc::require_shape(*grad_in, B, H, W, "conv_transpose2d_backward", "input gradient");
      if (in.empty()) return;
      // The slots conv_transpose2d_backward and conv_transpose2d_backward_weight pad into.
      dc::transposed_backward_passes<Cin, Cout>(in, dc::padded_activation_gradient(act, y, gy, grad_in ? 0 : 2), weight, grad_in,
                                                grad_weight, grad_bias, mode == input_gradient::accumulated);
      return;
    }
  }
  detail::activation_gradient(act, y, gy, g);
  conv_transpose2d_backward<Cin, Cout>(in, g, weight, grad_in, grad_weight, grad_bias, mode);
}

/// A 4x4 stride-2 transposed convolution layer (weights [4][4][Cin][Cout] named
/// name+".weight", bias name+".bias"), with the gradient rules of conv2d.
template <int Cin, int Cout, class T = float>
class conv_transpose2d {
 public:
  basic_parameter<T> weight;  ///< [4][4][Cin][Cout]
  basic_parameter<T> bias;    ///< [Cout]; empty when built without bias

  /// Zero-initialised parameters (initialisation is the network's job).
  explicit conv_transpose2d(std::string name, bool with_bias = true)
      : weight(name + ".weight", {4, 4, Cin, Cout}), has_bias_(with_bias) {
    if (with_bias) bias = basic_parameter<T>(name + ".bias", {Cout});
  }

  /// True when the layer has a bias.
  bool has_bias() const noexcept { return has_bias_; }

  /// y = act(conv_transpose(x) (+ bias)), recorded on t; `act` (nn/activation.hpp) is applied in
  /// place: the same values and gradients as act(t, layer(t, x)) with less memory. `link`: the
  /// layer's place in a plain chain of layers (chain_link), the same values and gradients.
  template <class Act = identity_activation>
  ad::variable<Cout, T> operator()(ad::tape& t, const ad::variable<Cin, T>& x, const Act& act = {}, chain_link link = {}) {
    detail::require_in_place_activation(act, "conv_transpose2d");
    const bool weight_grad = weight.trainable();
    const bool bias_grad = has_bias_ && bias.trainable();
    ad::variable<Cout, T> y = t.make_variable<Cout, T>(x.value.batch(), 2 * x.value.height(), 2 * x.value.width(),
                                                       x.requires_grad || weight_grad || bias_grad, ad::tape::gradient_init::by_caller);
    conv_transpose2d_forward<Cin, Cout>(x.value, weight.value.data(), has_bias_ ? bias.value.data() : nullptr, y.value);
    nn::detail::activate_output(act, y, !link.output_to_next);
    if (y.requires_grad) {
      const input_gradient mode = link.input_from_previous ? input_gradient::written : input_gradient::accumulated;
      // No pre-activation tensor where the backward writes the activation's gradient into its padded copy.
      const bool padded_only = detail::conv::writes_padded_activation_gradient<Act, Cin, Cout, T> && weight_grad;
      t.record([this, input = x.value, grad_in = x.grad, input_grad = x.requires_grad, output = y.value, grad_y = y.grad,
                grad_out = padded_only ? tensor<Cout, T>{} : nn::detail::pre_activation_gradient<Act>(t, y), act, weight_grad, bias_grad,
                mode]() mutable {
        conv_transpose2d_backward_activated<Cin, Cout>(act, input, output, grad_y, grad_out, weight.value.data(),
                                                       input_grad ? &grad_in : nullptr, weight_grad ? weight.grad.data() : nullptr,
                                                       bias_grad ? bias.grad.data() : nullptr, mode);
      });
    }
    return y;
  }

  /// y = act(conv_transpose(concat(a, b))) (a's C1 channels first): the values of
  /// (*this)(t, nn::concat(t, a, b), act), bit for bit. Where no gradient flows (neither input
  /// needs one, and the tape is not recording or the weights need none) the concatenation is never
  /// formed: the inputs go straight into the padded buffer the kernel reads, which saves a
  /// tensor and a pass (a U-Net decoder's skip connections at inference); otherwise the two
  /// layers run and are recorded.
  template <int C1, class Act = identity_activation>
    requires(C1 > 0 && C1 < Cin)
  ad::variable<Cout, T> of_concat(ad::tape& t, const ad::variable<C1, T>& a, const ad::variable<Cin - C1, T>& b, const Act& act = {}) {
    if (a.requires_grad || b.requires_grad || (t.recording() && (weight.trainable() || (has_bias_ && bias.trainable()))))
      return (*this)(t, nn::concat(t, a, b), act);
    detail::require_in_place_activation(act, "conv_transpose2d");
    ad::variable<Cout, T> y = t.make_variable<Cout, T>(a.value.batch(), 2 * a.value.height(), 2 * a.value.width(), false);
    conv_transpose2d_forward_concat<C1, Cin - C1, Cout>(a.value, b.value, weight.value.data(), has_bias_ ? bias.value.data() : nullptr,
                                                         y.value);
    nn::detail::activate_output(act, y);
    return y;
  }

  /// Calls f(basic_parameter<T>&) for the weight, then the bias if any.
  template <class F>
  void for_each_parameter(F&& f) {
    f(weight);
    if (has_bias_) f(bias);
  }

 private:
  bool has_bias_;
};

}  // namespace anisocap::nn
