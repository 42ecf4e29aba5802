#pragma once
// Naive loop references for convolution and transposed convolution (the definitions, no blocking),
// and shared helpers of the convolution tests.
#include <cmath>
#include <random>
#include <vector>

#include "anisocap/core/tensor.hpp"

namespace anisocap::testing {

/// Fills n values with uniform numbers in [-1, 1].
template <class T>
void fill_random(T* p, std::size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (std::size_t i = 0; i < n; ++i) p[i] = T(u(rng));
}
template <int C, class T>
void fill_random(tensor<C, T>& t, std::mt19937& rng) {
  for (int b = 0; b < t.batch(); ++b)
    for (int y = 0; y < t.height(); ++y) fill_random(t.pixel(b, y, 0), std::size_t(t.width()) * C, rng);
}

/// Largest |a - b| over two tensors of the same shape, and the largest |b|.
template <int C, class T, class U>
std::pair<double, double> max_difference(const tensor<C, T>& a, const tensor<C, U>& b) {
  double d = 0, m = 0;
  for (int n = 0; n < a.batch(); ++n)
    for (int y = 0; y < a.height(); ++y)
      for (int x = 0; x < a.width(); ++x)
        for (int c = 0; c < C; ++c) {
          d = std::max(d, std::abs(double(a(n, y, x, c)) - double(b(n, y, x, c))));
          m = std::max(m, std::abs(double(b(n, y, x, c))));
        }
  return {d, m};
}

/// out[b][oy][ox][co] = bias[co] + sum in[b][oy*S-pb+kh][ox*S-pb+kw][ci] w[kh][kw][ci][co] (zeros outside).
template <int Cin, int Cout, class T>
void naive_conv(const tensor<Cin, T>& in, const T* w, const T* bias, tensor<Cout, double>& out, int K, int S, int pb) {
  for (int b = 0; b < out.batch(); ++b)
    for (int oy = 0; oy < out.height(); ++oy)
      for (int ox = 0; ox < out.width(); ++ox)
        for (int co = 0; co < Cout; ++co) {
          double s = bias ? double(bias[co]) : 0.0;
          for (int kh = 0; kh < K; ++kh)
            for (int kw = 0; kw < K; ++kw) {
              const int iy = oy * S - pb + kh, ix = ox * S - pb + kw;
              if (iy < 0 || ix < 0 || iy >= in.height() || ix >= in.width()) continue;
              for (int ci = 0; ci < Cin; ++ci) s += double(in(b, iy, ix, ci)) * double(w[((kh * K + kw) * Cin + ci) * Cout + co]);
            }
          out(b, oy, ox, co) = s;
        }
}

/// Adjoint of naive_conv for the input: gin[iy][ix][ci] = sum gout[oy][ox][co] w[kh][kw][ci][co].
template <int Cin, int Cout, class T>
void naive_conv_backward_input(const tensor<Cout, T>& gout, const T* w, tensor<Cin, double>& gin, int K, int S, int pb) {
  gin.fill(0);
  for (int b = 0; b < gout.batch(); ++b)
    for (int oy = 0; oy < gout.height(); ++oy)
      for (int ox = 0; ox < gout.width(); ++ox)
        for (int kh = 0; kh < K; ++kh)
          for (int kw = 0; kw < K; ++kw) {
            const int iy = oy * S - pb + kh, ix = ox * S - pb + kw;
            if (iy < 0 || ix < 0 || iy >= gin.height() || ix >= gin.width()) continue;
            for (int ci = 0; ci < Cin; ++ci)
              for (int co = 0; co < Cout; ++co)
                gin(b, iy, ix, ci) += double(gout(b, oy, ox, co)) * double(w[((kh * K + kw) * Cin + ci) * Cout + co]);
          }
}

/// Adjoint of naive_conv for the weights and bias.
template <int Cin, int Cout, class T>
void naive_conv_backward_weight(const tensor<Cin, T>& in, const tensor<Cout, T>& gout, std::vector<double>& gw,
                                std::vector<double>& gb, int K, int S, int pb) {
  gw.assign(std::size_t(K) * K * Cin * Cout, 0.0);
  gb.assign(Cout, 0.0);
  for (int b = 0; b < gout.batch(); ++b)
    for (int oy = 0; oy < gout.height(); ++oy)
      for (int ox = 0; ox < gout.width(); ++ox) {
        for (int co = 0; co < Cout; ++co) gb[co] += double(gout(b, oy, ox, co));
        for (int kh = 0; kh < K; ++kh)
          for (int kw = 0; kw < K; ++kw) {
            const int iy = oy * S - pb + kh, ix = ox * S - pb + kw;
            if (iy < 0 || ix < 0 || iy >= in.height() || ix >= in.width()) continue;
            for (int ci = 0; ci < Cin; ++ci)
              for (int co = 0; co < Cout; ++co)
                gw[((kh * K + kw) * Cin + ci) * Cout + co] += double(in(b, iy, ix, ci)) * double(gout(b, oy, ox, co));
          }
      }
}

/// PyTorch ConvTranspose2d(4, stride 2, padding 1): out[2i-1+kh][2j-1+kw][co] += in[i][j][ci] w[kh][kw][ci][co].
template <int Cin, int Cout, class T>
void naive_conv_transpose(const tensor<Cin, T>& in, const T* w, const T* bias, tensor<Cout, double>& out) {
  for (int b = 0; b < out.batch(); ++b)
    for (int y = 0; y < out.height(); ++y)
      for (int x = 0; x < out.width(); ++x)
        for (int co = 0; co < Cout; ++co) out(b, y, x, co) = bias ? double(bias[co]) : 0.0;
  for (int b = 0; b < in.batch(); ++b)
    for (int i = 0; i < in.height(); ++i)
      for (int j = 0; j < in.width(); ++j)
        for (int kh = 0; kh < 4; ++kh)
          for (int kw = 0; kw < 4; ++kw) {
            const int oy = 2 * i - 1 + kh, ox = 2 * j - 1 + kw;
            if (oy < 0 || ox < 0 || oy >= out.height() || ox >= out.width()) continue;
            for (int ci = 0; ci < Cin; ++ci)
              for (int co = 0; co < Cout; ++co)
                out(b, oy, ox, co) += double(in(b, i, j, ci)) * double(w[((kh * 4 + kw) * Cin + ci) * Cout + co]);
          }
}

}  // namespace anisocap::testing
