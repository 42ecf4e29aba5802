#pragma once
/// @file
/// 2-d convolution on NHWC tensors: forward, backward for the input, backward for the weights,
/// and the `conv2d` layer that records them on the tape. The estimator's and the auto-encoder's
/// encoders are 4x4 stride-2 convolutions, their decoders and heads 3x3 / 4x4 stride-1 and 1x1
/// ones (docs/method.md section 7).
///
/// Weight layout [K][K][Cin][Cout] (kh, kw, in, out), bias [Cout]. Every pass is a direct
/// convolution blocked in registers (see detail/conv_kernels.hpp): no im2col matrix is built.
///
/// Padding: `Pad >= 0` pads Pad zeros on every side (output size (n + 2 Pad - K) / Stride + 1);
/// `Pad == same_padding` (stride 1 only) pads like PyTorch's padding='same': (K-1)/2 before,
/// the rest after, so a 4x4 stride-1 'same' convolution pads 1 top/left and 2 bottom/right and
/// keeps the size.
#include <cstdint>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/core/tensor.hpp"
#include "anisocap/nn/activation.hpp"
#include "anisocap/nn/detail/conv_kernels.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

/// `Pad` value asking for PyTorch's padding='same' (stride 1): (K-1)/2 before, K-1-(K-1)/2 after.
inline constexpr int same_padding = -1;

/// Padding and output size of a K x K convolution with the given stride and `Pad`.
template <int K, int Stride, int Pad>
struct conv_geometry {
  static_assert(K >= 1 && K <= 4, "convolution kernels are 1x1 to 4x4 (tap lists hold 16 taps)");
  static_assert(Stride >= 1, "stride must be positive");
  static_assert(Pad >= 0 || (Pad == same_padding && Stride == 1), "same_padding needs stride 1");
  static constexpr int pad_before = Pad >= 0 ? Pad : (K - 1) / 2;  ///< zeros above / left
  static constexpr int pad_after = Pad >= 0 ? Pad : K - 1 - pad_before;  ///< zeros below / right
  static_assert(pad_before < K && pad_after < K, "padding must be smaller than the kernel");
  /// Output rows (or columns) for n input rows; 0 when the kernel does not fit.
  static constexpr int output_size(int n) {
    const int span = n + pad_before + pad_after - K;
    return span < 0 ? 0 : span / Stride + 1;
  }
};

/// Output height (or width) of conv2d<.., K, Stride, Pad> for an input of n rows.
template <int K, int Stride, int Pad>
constexpr int conv2d_output_size(int n) { return conv_geometry<K, Stride, Pad>::output_size(n); }

namespace detail::conv {

/// The exception require_shape throws; out of line and not a template, so that each kernel's check
/// stays a comparison and a call.
[[noreturn, gnu::cold, gnu::noinline]] inline void throw_shape_mismatch(const char* op, const char* what, int b, int h, int w,
                                                                      int batch, int height, int width) {
  throw std::invalid_argument(std::string(op) + ": " + what + " is " + std::to_string(b) + "x" + std::to_string(h) + "x" +
                              std::to_string(w) + ", expected " + std::to_string(batch) + "x" + std::to_string(height) + "x" +
                              std::to_string(width));
}

/// Throws std::invalid_argument naming `op` when t is not batch x height x width.
template <int C, class T>
void require_shape(const tensor<C, T>& t, int batch, int height, int width, const char* op, const char* what) {
  if (t.batch() != batch || t.height() != height || t.width() != width)
    throw_shape_mismatch(op, what, t.batch(), t.height(), t.width(), batch, height, width);
}

/// A source tensor's data as the padded dense buffer the kernels read: either the tensor itself
/// (no padding needed) or a zero-padded copy in scratch `slot`.
template <class T>
struct padded_source {
  const T* data;
  std::ptrdiff_t batch_stride, row_stride;
};
template <int C, class T>
padded_source<T> padded(const tensor<C, T>& x, int top, int left, int Hp, int Wp, int ldc, int slot) {
  if (top == 0 && left == 0 && ldc == C && x.height() >= Hp && x.width() >= Wp)
    return {x.data(), x.batch_stride(), x.row_stride()};
  T* buffer = scratch<T>(slot, std::size_t(x.batch()) * Hp * Wp * ldc);
  pad_copy(x, top, left, Hp, Wp, ldc, buffer);
  return {buffer, std::ptrdiff_t(Hp) * Wp * ldc, std::ptrdiff_t(Wp) * ldc};
}

/// padded() of the channel concatenation [a, b], which is never formed (pad_copy_concat).
template <int C1, int C2, class T>
padded_source<T> padded_concat(const tensor<C1, T>& a, const tensor<C2, T>& b, int top, int left, int Hp, int Wp, int slot) {
  require_shape(b, a.batch(), a.height(), a.width(), "padded_concat", "the second input");
  T* buffer = scratch<T>(slot, std::size_t(a.batch()) * Hp * Wp * (C1 + C2));
  pad_copy_concat(a, b, top, left, Hp, Wp, buffer);
  return {buffer, std::ptrdiff_t(Hp) * Wp * (C1 + C2), std::ptrdiff_t(Wp) * (C1 + C2)};
}

/// Output channels per register block of a pass with Cb output channels.
template <class T, int Cb>
inline constexpr int block_of = vectors_per_tile<T>(Cb) * lanes<T>;

/// The forward weights as run_forward reads them: the caller's array when it is one aligned
/// block of whole registers, else packed block by block inside the work items; with the bias
/// padded to whole blocks when needed.
template <int Taps, int Ci, int Co, class T>
std::pair<weight_layout<T>, const T*> forward_weights(const T* w, const T* bias) {
  constexpr int block = block_of<T, Co>;
  const T* b = bias;
  if (bias && Co % block != 0) {
    T* pb = scratch<T>(3, std::size_t(padded_channels<T>(Co)) + block);
    for (int c = 0; c < padded_channels<T>(Co) + block; ++c) pb[c] = c < Co ? bias[c] : T(0);
    b = pb;
  }
  weight_layout<T> wl{w, Co, std::ptrdiff_t(Ci) * Co, block, false};
  wl.pack = !(Co == block && reinterpret_cast<std::uintptr_t>(w) % simd::alignment == 0);
  return {wl, b};
}

/// The kernel of an input-gradient pass as one transposed copy (used when many work items share
/// each block, i.e. many pixels for the kernel's size): weights [Taps][Ci][Co] transposed to Co
/// rows of Ci columns, packed in blocks of the inputs.
template <int Taps, int Ci, int Co, class T>
weight_layout<T> input_gradient_weights(const T* w, bool flip) {
  constexpr int block = block_of<T, Ci>;
  T* packed = scratch<T>(1, std::size_t(Taps) * Co * ((Ci + block - 1) / block) * block);
  return pack_weights(w, Taps, Ci, Co, true, flip, block, packed);
}

/// The kernel of an input-gradient pass read in its stored layout [taps][Ci][Co] and transposed
/// block by block inside the work items (see weight_layout::transposed).
template <int Ci, int Co, class T>
weight_layout<T> in_cache_transposed(const T* w) {
  weight_layout<T> wl{w, Co, std::ptrdiff_t(Ci) * Co, 0, true};
  wl.transposed = true;
  return wl;
}

/// The pass of a stride-S K x K convolution of a padded source into out (Ho x Wo from out); tap
/// (kh, kw) reads the weights of tap (K-1-kh, K-1-kw) when `flip`.
template <int Ca, int K, int S, int Cb, class T>
forward_pass<T> conv_pass(const padded_source<T>& a, tensor<Cb, T>& out, std::ptrdiff_t tap_stride, bool flip) {
  forward_pass<T> ps;
  ps.a = a.data;
  ps.a_batch = a.batch_stride;
  ps.a_row = S * a.row_stride;
  ps.a_col = S * Ca;
  ps.o = out.data();
  ps.o_batch = out.batch_stride();
  ps.o_row = out.row_stride();
  ps.o_col = Cb;
  ps.batch = out.batch();
  ps.rows = out.height();
  ps.cols = out.width();
  ps.taps = K * K;
  for (int kh = 0; kh < K; ++kh)
    for (int kw = 0; kw < K; ++kw) {
      ps.a_tap[kh * K + kw] = kh * a.row_stride + kw * Ca;
      ps.w_tap[kh * K + kw] = (flip ? K * K - 1 - (kh * K + kw) : kh * K + kw) * tap_stride;
    }
  return ps;
}

/// The four passes (one per output parity, each a 2x2 convolution) of a 4x4 stride-2 pad-1
/// transposed convolution. `a` is the input padded by one pixel above/left (rows ceil(Ho/2)+2,
/// columns ceil(Wo/2)+2); out has any size Ho x Wo up to twice the input. Returns the count.
template <int Ca, int Cb, class T>
int transposed_passes(const padded_source<T>& a, tensor<Cb, T>& out, std::ptrdiff_t tap_stride, forward_pass<T>* ps) {
  int n = 0;
  for (int py = 0; py < 2; ++py)
    for (int px = 0; px < 2; ++px) {
      forward_pass<T>& p = ps[n];
      p = forward_pass<T>{};
      p.rows = (out.height() - py + 1) / 2;
      p.cols = (out.width() - px + 1) / 2;
      if (p.rows <= 0 || p.cols <= 0 || out.batch() == 0) continue;
      p.a = a.data;
      p.a_batch = a.batch_stride;
      p.a_row = a.row_stride;
      p.a_col = Ca;
      p.o = out.data() + py * out.row_stride() + px * Cb;
      p.o_batch = out.batch_stride();
      p.o_row = 2 * out.row_stride();
      p.o_col = 2 * Cb;
      p.batch = out.batch();
      p.taps = 0;
      // Output row 2i+py reads input row i + (py+1-kh)/2 for the kernel rows of matching parity.
      for (int kh = 0; kh < 4; ++kh) {
        if ((py + 1 - kh) % 2 != 0) continue;
        for (int kw = 0; kw < 4; ++kw) {
          if ((px + 1 - kw) % 2 != 0) continue;
          const int dy = (py + 1 - kh) / 2 + 1, dx = (px + 1 - kw) / 2 + 1;
          p.a_tap[p.taps] = dy * a.row_stride + dx * Ca;
          p.w_tap[p.taps] = (kh * 4 + kw) * tap_stride;
          ++p.taps;
        }
      }
      ++n;
    }
  return n;
}

/// True when an input-gradient pass should transpose the kernel block by block inside its work
/// items rather than through one transposed copy: when the kernel is large for the number of
/// pixels (few work items share a block), the copy (memory-bound, about 2 ns per weight) would
/// cost more than the pass itself.
/// Tests set it to 0 (always in cache) or SIZE_MAX (never) to check both paths on small shapes.
/// A bf16 pass (float, precision::bf16) always transposes in cache: it converts the kernel to bf16
/// pairs itself, transposing as it converts, so a transposed FP32 copy would only add a pass over
/// the weights.
inline std::size_t in_cache_transpose_weights_per_pixel = 8192;
template <class T>
bool prefer_in_cache_transpose(std::size_t weights, std::size_t pixels) {
  if constexpr (std::is_same_v<T, float> && simd::bf16_dot_available)
    if (convolution_precision() == precision::bf16) return true;
  return in_cache_transpose_weights_per_pixel == 0 || (pixels <= weights / in_cache_transpose_weights_per_pixel);
}

/// Runs the passes that `make_passes(target)` builds for an output tensor `target`. When Cb is
/// not a whole number of register blocks (3, 9 or 12 channels), the tiles' last register holds the
/// channels that are left: on AVX-512 they load and store it masked, straight into out; elsewhere
/// such loads and stores go through the stack and would cost more than the pass, so the kernel
/// writes whole blocks into a padded scratch tensor that is then added (or copied) into out. Each
/// output value is the same sum either way.
template <int Ca, int Cb, int ACOL, class T, class MakePasses>
void run_forward_into(tensor<Cb, T>& out, const weight_layout<T>& w, const T* bias, bool accumulate,
                      MakePasses&& make_passes) {
  constexpr int NV = vectors_per_tile<T>(Cb);
  constexpr int block = NV * lanes<T>;
  // The passes' column step (ACOL) compiled in only for one-register tiles (see forward_pass).
  constexpr int A = NV == 1 ? ACOL : 0;
  forward_pass<T> ps[4];
  if constexpr (Cb % block == 0 || simd::masked_first_v<batch<T>>) {
    const int n = make_passes(out, ps);
    if (n) run_forward<NV, A>(ps, n, Ca, Cb, w, bias, accumulate);
  } else {
    constexpr int Cp = (Cb + block - 1) / block * block;
    const int B = out.batch(), H = out.height(), W = out.width();
    auto padded_out = tensor<Cp, T>::wrap(scratch<T>(6, std::size_t(B) * H * W * Cp), B, H, W);
    const int n = make_passes(padded_out, ps);
    if (n) run_forward<NV, A>(ps, n, Ca, Cb, w, bias, false, true);
#pragma omp parallel for schedule(static) if (out.size() > (1u << 16))
    for (int r = 0; r < B * H; ++r) {
      const int b = r / H, y = r % H;
      T* o = out.pixel(b, y, 0);
      const T* p = padded_out.pixel(b, y, 0);
      for (int x = 0; x < W; ++x, o += Cb, p += Cp)
        for (int c = 0; c < Cb; ++c) o[c] = accumulate ? o[c] + p[c] : p[c];
    }
  }
}

/// Stride-S K x K convolution of a padded source into out (register-blocked forward kernel).
template <int Ca, int Cb, int K, int S, class T>
void conv_core(const padded_source<T>& a, const weight_layout<T>& w, const std::type_identity_t<T>* bias,
               tensor<Cb, T>& out, bool accumulate, bool flip = false) {
  run_forward_into<Ca, Cb, S * Ca>(out, w, bias, accumulate, [&](auto& target, forward_pass<T>* ps) {
    ps[0] = conv_pass<Ca, K, S>(a, target, w.tap_stride, flip);
    return 1;
  });
}

/// 4x4 stride-2 pad-1 transposed convolution of a padded source into out (forward kernel).
template <int Ca, int Cb, class T>
void transposed_core(const padded_source<T>& a, const weight_layout<T>& w, const std::type_identity_t<T>* bias,
                     tensor<Cb, T>& out, bool accumulate) {
  run_forward_into<Ca, Cb, Ca>(out, w, bias, accumulate, [&](auto& target, forward_pass<T>* ps) {
    return transposed_passes<Ca>(a, target, w.tap_stride, ps);
  });
}

}  // namespace detail::conv

/// Forward convolution: out = conv(in, weight) + bias. `out` must be batch x Ho x Wo with
/// Ho, Wo = conv2d_output_size<K, Stride, Pad>(in's height, width); bias may be null.
template <int Cin, int Cout, int K, int Stride, int Pad, class T>
void conv2d_forward(const tensor<Cin, T>& in, const T* weight, const std::type_identity_t<T>* bias, tensor<Cout, T>& out) {
  using G = conv_geometry<K, Stride, Pad>;
  namespace dc = detail::conv;
  const int Ho = G::output_size(in.height()), Wo = G::output_size(in.width());
  dc::require_shape(out, in.batch(), Ho, Wo, "conv2d_forward", "output");
  if (out.empty()) return;
  const auto [w, b] = dc::forward_weights<K * K, Cin, Cout>(weight, bias);
  const auto a = dc::padded(in, G::pad_before, G::pad_before, (Ho - 1) * Stride + K, (Wo - 1) * Stride + K, Cin, 0);
  dc::conv_core<Cin, Cout, K, Stride>(a, w, b, out, false);
}

/// Gradient of the convolution for its input, ACCUMULATED into grad_in (input-sized).
template <int Cin, int Cout, int K, int Stride, int Pad, class T>
void conv2d_backward_input(const tensor<Cout, T>& grad_out, const T* weight, tensor<Cin, T>& grad_in) {
  using G = conv_geometry<K, Stride, Pad>;
  namespace dc = detail::conv;
  const int B = grad_in.batch(), H = grad_in.height(), W = grad_in.width();
  dc::require_shape(grad_out, B, G::output_size(H), G::output_size(W), "conv2d_backward_input", "output gradient");
  if (grad_in.empty() || grad_out.empty()) return;
  if constexpr (Stride == 1) {
    // A stride-1 convolution's input gradient is the convolution of the padded output gradient
    // with the kernel rotated by 180 degrees and transposed (in <-> out).
    const int top = K - 1 - G::pad_before;
    const auto a = dc::padded(grad_out, top, top, H + K - 1, W + K - 1, Cout, 0);
    constexpr std::size_t weights = std::size_t(K) * K * Cin * Cout;
    if (dc::prefer_in_cache_transpose<T>(weights, grad_in.size() / Cin)) {
      dc::conv_core<Cout, Cin, K, 1>(a, dc::in_cache_transposed<Cin, Cout>(weight), nullptr, grad_in, true, true);
    } else {
      dc::conv_core<Cout, Cin, K, 1>(a, dc::input_gradient_weights<K * K, Cin, Cout>(weight, true), nullptr, grad_in, true);
    }
  } else if constexpr (Stride == 2 && K == 4 && G::pad_before == 1) {
    // The input gradient of a 4x4 stride-2 convolution is a transposed convolution of the output
    // gradient with the transposed kernel: four 2x2 sub-convolutions.
    const int Hh = (H + 1) / 2, Wh = (W + 1) / 2;
    const auto a = dc::padded(grad_out, 1, 1, Hh + 2, Wh + 2, Cout, 0);
    constexpr std::size_t weights = std::size_t(K) * K * Cin * Cout;
    if (dc::prefer_in_cache_transpose<T>(weights, grad_in.size() / Cin)) {
      dc::transposed_core<Cout, Cin>(a, dc::in_cache_transposed<Cin, Cout>(weight), nullptr, grad_in, true);
    } else {
      dc::transposed_core<Cout, Cin>(a, dc::input_gradient_weights<K * K, Cin, Cout>(weight, false), nullptr, grad_in, true);
    }
  } else {
    // Other strides: direct scatter (no layer of the paper's networks uses it).
    const int Ho = grad_out.height(), Wo = grad_out.width();
    for (int b = 0; b < B; ++b)
      for (int oy = 0; oy < Ho; ++oy)
        for (int ox = 0; ox < Wo; ++ox) {
          const T* g = grad_out.pixel(b, oy, ox);
          for (int kh = 0; kh < K; ++kh) {
            const int iy = oy * Stride - G::pad_before + kh;
            if (iy < 0 || iy >= H) continue;
            for (int kw = 0; kw < K; ++kw) {
              const int ix = ox * Stride - G::pad_before + kw;
              if (ix < 0 || ix >= W) continue;
              T* gi = grad_in.pixel(b, iy, ix);
              const T* wk = weight + std::ptrdiff_t(kh * K + kw) * Cin * Cout;
              for (int ci = 0; ci < Cin; ++ci) {
                T s = 0;
                for (int co = 0; co < Cout; ++co) s += g[co] * wk[ci * Cout + co];
                gi[ci] += s;
              }
            }
          }
        }
  }
}

/// Gradients of the convolution for its weights [K][K][Cin][Cout] and bias [Cout] (null: skipped),
/// ACCUMULATED into grad_weight / grad_bias.
template <int Cin, int Cout, int K, int Stride, int Pad, class T>
void conv2d_backward_weight(const tensor<Cin, T>& in, const tensor<Cout, T>& grad_out, std::type_identity_t<T>* grad_weight, std::type_identity_t<T>* grad_bias) {
  using G = conv_geometry<K, Stride, Pad>;
  namespace dc = detail::conv;
  const int Ho = G::output_size(in.height()), Wo = G::output_size(in.width());
  dc::require_shape(grad_out, in.batch(), Ho, Wo, "conv2d_backward_weight", "output gradient");
  if (grad_out.empty()) return;
  if (grad_bias) dc::bias_gradient(grad_out, grad_bias);
  if (!grad_weight) return;
  constexpr int ldg = dc::weight_gradient_channels<T, Cin, Cout>;
  const auto a = dc::padded(in, G::pad_before, G::pad_before, (Ho - 1) * Stride + K, (Wo - 1) * Stride + K, Cin, 0);
  const auto g = dc::padded(grad_out, 0, 0, Ho, Wo, ldg, 2);
  dc::weight_pass<T> ps;
  ps.a = a.data;
  ps.a_batch = a.batch_stride;
  ps.a_row = Stride * a.row_stride;
  ps.a_col = Stride * Cin;
  ps.g = g.data;
  ps.g_batch = g.batch_stride;
  ps.g_row = g.row_stride;
  ps.g_col = ldg;
  ps.batch = in.batch();
  ps.rows = Ho;
  ps.cols = Wo;
  ps.taps = K * K;
  for (int kh = 0; kh < K; ++kh)
    for (int kw = 0; kw < K; ++kw) ps.a_tap[kh * K + kw] = kh * a.row_stride + kw * Cin;
  dc::run_weight_of<Cin, Cout>(ps, grad_weight);
}

/// A convolution layer (weights [K][K][Cin][Cout] named name+".weight", bias [Cout] name+".bias").
/// Records its backward on the tape when the input needs a gradient or a parameter is trainable;
/// computes the input gradient only when the input needs it and a parameter's gradient only when
/// it is not frozen, so nothing is computed below the lowest trainable layer.
template <int Cin, int Cout, int K, int Stride, int Pad, class T = float>
class conv2d {
 public:
  basic_parameter<T> weight;  ///< [K][K][Cin][Cout]
  basic_parameter<T> bias;    ///< [Cout]; empty when built without bias

  /// Zero-initialised parameters (initialisation is the network's job).
  explicit conv2d(std::string name, bool with_bias = true)
      : weight(name + ".weight", {K, K, Cin, Cout}), has_bias_(with_bias) {
    if (with_bias) bias = basic_parameter<T>(name + ".bias", {Cout});
  }

  /// True when the layer has a bias.
  bool has_bias() const noexcept { return has_bias_; }

  /// y = act(conv(x) (+ bias)), recorded on t; `act` (nn/activation.hpp) is applied in place:
  /// the same values and gradients as act(t, layer(t, x)) with less memory.
  template <class Act = identity_activation>
  ad::variable<Cout, T> operator()(ad::tape& t, const ad::variable<Cin, T>& x, const Act& act = {}) {
    detail::require_in_place_activation(act, "conv2d");
    const bool weight_grad = weight.trainable();
    const bool bias_grad = has_bias_ && bias.trainable();
    const int Ho = conv2d_output_size<K, Stride, Pad>(x.value.height());
    const int Wo = conv2d_output_size<K, Stride, Pad>(x.value.width());
    ad::variable<Cout, T> y = t.make_variable<Cout, T>(x.value.batch(), Ho, Wo, x.requires_grad || weight_grad || bias_grad,
                                                       ad::tape::gradient_init::by_caller);
    conv2d_forward<Cin, Cout, K, Stride, Pad>(x.value, weight.value.data(), has_bias_ ? bias.value.data() : nullptr, y.value);
    detail::activate_output(act, y);
    if (y.requires_grad) {
      t.record([this, input = x.value, grad_in = x.grad, input_grad = x.requires_grad, output = y.value, grad_y = y.grad,
                grad_out = detail::pre_activation_gradient<Act>(t, y), act, weight_grad, bias_grad]() mutable {
        detail::activation_gradient(act, output, grad_y, grad_out);
        if (input_grad) conv2d_backward_input<Cin, Cout, K, Stride, Pad>(grad_out, weight.value.data(), grad_in);
        conv2d_backward_weight<Cin, Cout, K, Stride, Pad>(input, grad_out, weight_grad ? weight.grad.data() : nullptr,
                                                          bias_grad ? bias.grad.data() : nullptr);
      });
    }
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
