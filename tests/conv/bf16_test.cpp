// Convolutions in bf16 (nn/precision.hpp): the forward, input-gradient and weight-gradient passes
// of conv2d and conv_transpose2d must equal the naive loops run in double on the bf16-rounded inputs and
// weights (the products are exact in FP32, only the FP32 sums round), at odd channel counts (the
// last pair half empty), shapes that convert the weights once per call and shapes whose work
// items convert their own blocks, and both ways of transposing an input-gradient kernel. Skipped
// on builds without AVX-512 BF16.
#include <doctest/doctest.h>
#include <omp.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "anisocap/nn/conv.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/precision.hpp"
#include "reference.hpp"

using namespace anisocap;
using anisocap::testing::fill_random;
using anisocap::testing::max_difference;

namespace {

float round_bf16(float x) { return simd::from_bf16(simd::to_bf16(x)); }

template <int C>
tensor<C> rounded(const tensor<C>& t) {
  tensor<C> r = t.clone();
  for (std::size_t i = 0; i < r.size(); ++i) r.data()[i] = round_bf16(r.data()[i]);
  return r;
}
std::vector<float> rounded(const std::vector<float>& v) {
  std::vector<float> r(v);
  for (float& x : r) x = round_bf16(x);
  return r;
}

/// The bf16 result `got` against the double reference on rounded operands (`exact`) and on the
/// FP32 operands (`fp32`): FP32-sum close to the first, and visibly rounded against the second
/// (so the bf16 kernel, not the FP32 one, ran).
template <int C>
void check_bf16(const tensor<C>& got, const tensor<C, double>& exact, const tensor<C, double>& fp32, int terms) {
  const auto [d, m] = max_difference(got, exact);
  CHECK(d <= 2e-6 * std::sqrt(double(terms)) * (1 + m));
  const auto [d32, m32] = max_difference(got, fp32);
  CHECK(d32 > 1e-4 * m32);                                  // bf16 rounding shows
  CHECK(d32 <= 2.0 / 256 * std::sqrt(double(terms)) * (1 + m32));  // and stays a bf16 rounding
}

/// The same for a weight gradient accumulated onto 0.5.
void check_bf16_weights(const std::vector<float>& got, const std::vector<double>& exact, const std::vector<double>& fp32, int terms) {
  double d = 0, m = 0, d32 = 0;
  for (std::size_t i = 0; i < got.size(); ++i) {
    d = std::max(d, std::abs(got[i] - 0.5 - exact[i]));
    d32 = std::max(d32, std::abs(got[i] - 0.5 - fp32[i]));
    m = std::max(m, std::abs(exact[i]));
  }
  CHECK(d <= 2e-6 * std::sqrt(double(terms)) * (1 + m));
  CHECK(d32 > 1e-4 * m);
  CHECK(d32 <= 2.0 / 256 * std::sqrt(double(terms)) * (1 + m));
}

template <int Cin, int Cout, int K, int S, int P>
void check_conv(int B, int H, int W, unsigned seed) {
  using G = nn::conv_geometry<K, S, P>;
  std::mt19937 rng(seed);
  const int Ho = nn::conv2d_output_size<K, S, P>(H), Wo = nn::conv2d_output_size<K, S, P>(W);
  tensor<Cin> in(B, H, W);
  fill_random(in, rng);
  std::vector<float> w(std::size_t(K * K * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  const tensor<Cin> in16 = rounded(in);
  const std::vector<float> w16 = rounded(w);

  tensor<Cout> out(B, Ho, Wo);
  {
    nn::precision_scope bf16(nn::precision::bf16);
    nn::conv2d_forward<Cin, Cout, K, S, P>(in, w.data(), bias.data(), out);
  }
  tensor<Cout, double> exact(B, Ho, Wo), fp32(B, Ho, Wo);
  testing::naive_conv(in16, w16.data(), bias.data(), exact, K, S, G::pad_before);
  testing::naive_conv(in, w.data(), bias.data(), fp32, K, S, G::pad_before);
  check_bf16(out, exact, fp32, K * K * Cin);

  tensor<Cout> gout(B, Ho, Wo);
  fill_random(gout, rng);
  const tensor<Cout> gout16 = rounded(gout);
  // One pass: a bf16 input-gradient pass transposes the kernel as it converts it, whatever the
  // in-cache threshold (which decides the FP32 path only).
  {
    tensor<Cin> gin(B, H, W);
    gin.fill(0);
    {
      nn::precision_scope bf16(nn::precision::bf16);
      nn::conv2d_backward_input<Cin, Cout, K, S, P>(gout, w.data(), gin);
    }
    tensor<Cin, double> gexact(B, H, W), g32(B, H, W);
    testing::naive_conv_backward_input(gout16, w16.data(), gexact, K, S, G::pad_before);
    testing::naive_conv_backward_input(gout, w.data(), g32, K, S, G::pad_before);
    check_bf16(gin, gexact, g32, K * K * Cout);
  }

  // The weight gradient accumulates onto what is there.
  std::vector<float> gw(w.size(), 0.5f);
  {
    nn::precision_scope bf16(nn::precision::bf16);
    nn::conv2d_backward_weight<Cin, Cout, K, S, P>(in, gout, gw.data(), nullptr);
  }
  std::vector<double> gw_exact, gw32, unused;
  testing::naive_conv_backward_weight(in16, gout16, gw_exact, unused, K, S, G::pad_before);
  testing::naive_conv_backward_weight(in, gout, gw32, unused, K, S, G::pad_before);
  check_bf16_weights(gw, gw_exact, gw32, B * Ho * Wo);
  CHECK(nn::convolution_precision() == nn::precision::fp32);  // the scopes restored it
}

template <int Cin, int Cout>
void check_transposed(int B, int H, int W, unsigned seed) {
  std::mt19937 rng(seed);
  tensor<Cin> in(B, H, W);
  fill_random(in, rng);
  std::vector<float> w(std::size_t(16 * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  const tensor<Cin> in16 = rounded(in);
  const std::vector<float> w16 = rounded(w);
  tensor<Cout> out(B, 2 * H, 2 * W);
  {
    nn::precision_scope bf16(nn::precision::bf16);
    nn::conv_transpose2d_forward<Cin, Cout>(in, w.data(), bias.data(), out);
  }
  tensor<Cout, double> exact(B, 2 * H, 2 * W), fp32(B, 2 * H, 2 * W);
  testing::naive_conv_transpose(in16, w16.data(), bias.data(), exact);
  testing::naive_conv_transpose(in, w.data(), bias.data(), fp32);
  check_bf16(out, exact, fp32, 4 * Cin);

  // The input gradient is the 4x4 stride-2 convolution of gout with the weights read [kh][kw][out][in].
  tensor<Cout> gout(B, 2 * H, 2 * W);
  fill_random(gout, rng);
  const tensor<Cout> gout16 = rounded(gout);
  std::vector<float> wt(w.size()), wt16(w.size());
  for (int t = 0; t < 16; ++t)
    for (int ci = 0; ci < Cin; ++ci)
      for (int co = 0; co < Cout; ++co) {
        wt[(t * Cout + co) * Cin + ci] = w[(t * Cin + ci) * Cout + co];
        wt16[(t * Cout + co) * Cin + ci] = w16[(t * Cin + ci) * Cout + co];
      }
  // One pass: a bf16 input-gradient pass transposes the kernel as it converts it, whatever the
  // in-cache threshold (which decides the FP32 path only).
  {
    tensor<Cin> gin(B, H, W);
    gin.fill(0);
    {
      nn::precision_scope bf16(nn::precision::bf16);
      nn::conv_transpose2d_backward_input<Cin, Cout>(gout, w.data(), gin);
    }
    tensor<Cin, double> gexact(B, H, W), g32(B, H, W);
    testing::naive_conv(gout16, wt16.data(), static_cast<const float*>(nullptr), gexact, 4, 2, 1);
    testing::naive_conv(gout, wt.data(), static_cast<const float*>(nullptr), g32, 4, 2, 1);
    check_bf16(gin, gexact, g32, 16 * Cout);
  }

  // gW[kh][kw][ci][co] = sum in[i][j][ci] gout[2i-1+kh][2j-1+kw][co]: the conv weight gradient with
  // input gout and output gradient in, transposed.
  std::vector<float> gw(w.size(), 0.5f);
  {
    nn::precision_scope bf16(nn::precision::bf16);
    nn::conv_transpose2d_backward_weight<Cin, Cout>(in, gout, gw.data(), nullptr);
  }
  std::vector<double> t_exact, t32, unused, gw_exact(w.size()), gw32(w.size());
  testing::naive_conv_backward_weight(gout16, in16, t_exact, unused, 4, 2, 1);
  testing::naive_conv_backward_weight(gout, in, t32, unused, 4, 2, 1);
  for (int t = 0; t < 16; ++t)
    for (int ci = 0; ci < Cin; ++ci)
      for (int co = 0; co < Cout; ++co) {
        gw_exact[(t * Cin + ci) * Cout + co] = t_exact[(t * Cout + co) * Cin + ci];
        gw32[(t * Cin + ci) * Cout + co] = t32[(t * Cout + co) * Cin + ci];
      }
  check_bf16_weights(gw, gw_exact, gw32, B * H * W);
}

}  // namespace

TEST_CASE("precision names and the bf16 switch") {
  CHECK(nn::parse_precision("fp32") == nn::precision::fp32);
  CHECK(nn::parse_precision("bf16") == nn::precision::bf16);
  CHECK_THROWS_WITH_AS(nn::parse_precision("fp16"), doctest::Contains("fp16"), std::invalid_argument);
  CHECK_THROWS_WITH_AS(nn::parse_precision("fp16", "train_options::precision"),
                       "train_options::precision: unknown precision 'fp16' (expected fp32 or bf16)", std::invalid_argument);
  CHECK(std::string(nn::to_string(nn::precision::bf16)) == "bf16");
  if (!nn::bf16_available()) {
    CHECK_THROWS_AS(nn::set_convolution_precision(nn::precision::bf16), std::invalid_argument);
    CHECK(nn::convolution_precision() == nn::precision::fp32);
  }
}

#if ANISOCAP_BF16_DOT
TEST_CASE("interleave_to_bf16 rounds every channel in hardware and writes 2n values, whatever n") {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-3, 3);
  for (int n = 1; n <= 40; ++n) {
    CAPTURE(n);
    std::vector<float> a(static_cast<std::size_t>(n)), b(static_cast<std::size_t>(n));
    for (int j = 0; j < n; ++j) a[std::size_t(j)] = u(rng), b[std::size_t(j)] = u(rng);
    a[0] = 1e-40f;  // a denormal reads as zero, in the last channels too
    std::vector<std::uint16_t> got(std::size_t(2 * n + 8), 0xABCD);
    simd::interleave_to_bf16(a.data(), b.data(), n, got.data());
    CHECK(got[0] == 0);
    bool same = got[1] == simd::to_bf16(b[0]);
    for (int j = 1; j < n; ++j)
      same = same && got[std::size_t(2 * j)] == simd::to_bf16(a[std::size_t(j)]) && got[std::size_t(2 * j + 1)] == simd::to_bf16(b[std::size_t(j)]);
    CHECK(same);
    for (std::size_t k = std::size_t(2 * n); k < got.size(); ++k) CHECK(got[k] == 0xABCD);  // nothing beyond
  }
}

TEST_CASE("convert_to_bf16 converts every value in hardware, the last ones too, and writes n values") {
  std::mt19937 rng(6);
  std::uniform_real_distribution<float> u(-3, 3);
  for (int n = 1; n <= 70; ++n) {
    CAPTURE(n);
    std::vector<float> a(static_cast<std::size_t>(n));
    for (auto& v : a) v = u(rng);
    a[std::size_t(n - 1)] = 1e-40f;  // a denormal reads as zero wherever it sits, the tail included
    std::vector<std::uint16_t> got(std::size_t(n + 8), 0xABCD);
    simd::convert_to_bf16(a.data(), n, got.data());
    CHECK(got[std::size_t(n - 1)] == 0);
    bool same = true;
    for (int j = 0; j + 1 < n; ++j) same = same && got[std::size_t(j)] == simd::to_bf16(a[std::size_t(j)]);
    CHECK(same);
    for (std::size_t k = std::size_t(n); k < got.size(); ++k) CHECK(got[k] == 0xABCD);  // nothing beyond
  }
}

TEST_CASE("transpose_to_bf16_pairs writes each row's pairs down a column, zero rows past nrows, nothing else") {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-3, 3);
  const std::ptrdiff_t ld = 100, stride = 48;  // rows 100 floats apart; 48 pairs per written row, 16 of them ours
  std::vector<float> src(std::size_t(16 * ld));
  for (auto& v : src) v = u(rng);
  src[3] = 1e-40f;  // a denormal reads as zero, as in convert_to_bf16
  for (int nrows : {0, 1, 7, 16})
    for (int pairs : {1, 5, 16, 17, 40}) {
      CAPTURE(nrows);
      CAPTURE(pairs);
      std::vector<std::uint16_t> got(std::size_t(2 * pairs * stride), 0xABCD);
      simd::transpose_to_bf16_pairs(nrows ? src.data() : nullptr, ld, nrows, pairs, got.data(), stride);
      bool same = true, untouched = true;
      for (int q = 0; q < pairs; ++q)
        for (int c = 0; c < stride; ++c)
          for (int h = 0; h < 2; ++h) {
            const std::uint16_t g = got[std::size_t(2 * (q * stride + c) + h)];
            if (c >= 16) {
              untouched = untouched && g == 0xABCD;
            } else {
              const float x = src[std::size_t(c * ld + 2 * q + h)];
              const std::uint16_t want = c >= nrows ? 0 : std::fabs(x) < 1e-38f ? 0 : simd::to_bf16(x);
              same = same && g == want;
            }
          }
      CHECK(same);
      CHECK(untouched);
    }
}
#endif

TEST_CASE("bf16 convolutions equal the naive loops on bf16-rounded operands" * doctest::skip(!nn::bf16_available())) {
  check_conv<3, 5, 4, 2, 1>(2, 7, 9, 1);                    // odd channels, partial registers
  check_conv<64, 64, 4, 2, 1>(2, 9, 11, 2);                 // SIMD path, tails
  check_conv<64, 64, 4, 2, 1>(2, 33, 61, 3);                // many items: weights converted once
  check_conv<9, 48, 1, 1, 0>(2, 7, 9, 4);                   // odd Ca, 1x1
  check_conv<12, 64, 3, 1, 1>(2, 7, 9, 5);
  check_conv<64, 12, 4, 1, nn::same_padding>(2, 7, 9, 6);
  check_conv<256, 32, 4, 2, 1>(1, 6, 6, 7);                 // few pixels: items convert their blocks
  check_conv<1024, 32, 3, 1, 1>(1, 3, 3, 8);                // input-channel chunks
  check_conv<64, 64, 3, 1, 1>(1, 2, 201, 12);               // rows cut into pixel chunks, odd last chunk
  check_transposed<64, 32>(2, 5, 7, 9);
  check_transposed<33, 16>(1, 4, 4, 10);                    // odd Ca
  check_transposed<128, 64>(1, 16, 16, 11);
  check_transposed<32, 12>(1, 3, 200, 13);                  // the decoder's last layer: one row a chunk, rows cut
                                                            // into segments, each kernel row's rows reused a chunk later
}

TEST_CASE("bf16 weight gradients are the same bits on any thread count" * doctest::skip(!nn::bf16_available())) {
  // The work items group taps by the thread count (each converts an operand the taps share once),
  // but every item owns its part of the gradient and sums its pixels in one order.
  nn::precision_scope scope(nn::precision::bf16);
  std::mt19937 rng(21);
  tensor<32> in(1, 24, 20), in2(1, 24, 20);
  tensor<12> gout(1, 48, 40);
  tensor<64> gout2(1, 12, 10);
  fill_random(in, rng);
  fill_random(in2, rng);
  fill_random(gout, rng);
  fill_random(gout2, rng);
  const int saved = omp_get_max_threads();
  std::vector<float> first_t, first_c;
  for (const int threads : {1, 2, 3, 5, 16}) {
    CAPTURE(threads);
    omp_set_num_threads(threads);
    std::vector<float> gt(16 * 32 * 12, 0.25f), gc(16 * 32 * 64, 0.25f);
    nn::conv_transpose2d_backward_weight<32, 12>(in, gout, gt.data(), nullptr);
    nn::conv2d_backward_weight<32, 64, 4, 2, 1>(in2, gout2, gc.data(), nullptr);
    if (first_t.empty()) {
      first_t = gt;
      first_c = gc;
    }
    CHECK(gt == first_t);
    CHECK(gc == first_c);
  }
  omp_set_num_threads(saved);
}
