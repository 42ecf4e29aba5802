// Convolution: forward and both backward passes against naive loops (float, odd sizes, batch 2),
// and gradients against central finite differences (double), at small channel counts and at
// counts that take the register-blocked SIMD path.
#include <doctest/doctest.h>
#include <omp.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "anisocap/nn/conv.hpp"
#include "reference.hpp"
#include "support/gradient_check.hpp"

using namespace anisocap;
using anisocap::testing::fill_random;
using anisocap::testing::max_difference;

namespace {

template <int Cin, int Cout, int K, int S, int P>
void check_against_reference(int B, int H, int W, unsigned seed) {
  using G = nn::conv_geometry<K, S, P>;
  std::mt19937 rng(seed);
  const int Ho = nn::conv2d_output_size<K, S, P>(H), Wo = nn::conv2d_output_size<K, S, P>(W);
  tensor<Cin> in(B, H, W);
  fill_random(in, rng);
  std::vector<float> w(static_cast<std::size_t>(K * K * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  const double tol = 1e-5 * std::sqrt(double(K * K * std::max(Cin, Cout)));

  tensor<Cout> out(B, Ho, Wo);
  nn::conv2d_forward<Cin, Cout, K, S, P>(in, w.data(), bias.data(), out);
  tensor<Cout, double> ref(B, Ho, Wo);
  testing::naive_conv(in, w.data(), bias.data(), ref, K, S, G::pad_before);
  auto [d, m] = max_difference(out, ref);
  CHECK(d <= tol * (1 + m));

  // Backward input accumulates: start from random values. Both ways of transposing the
  // kernel for it (block by block in the work items, one whole copy) are checked.
  tensor<Cout> gout(B, Ho, Wo);
  fill_random(gout, rng);
  for (std::size_t threshold : {std::size_t(0), SIZE_MAX}) {
  nn::detail::conv::in_cache_transpose_weights_per_pixel = threshold;
  tensor<Cin> gin(B, H, W);
  fill_random(gin, rng);
  const tensor<Cin> gin0 = gin.clone();
  nn::conv2d_backward_input<Cin, Cout, K, S, P>(gout, w.data(), gin);
  tensor<Cin, double> gref(B, H, W);
  testing::naive_conv_backward_input(gout, w.data(), gref, K, S, G::pad_before);
  for (int b = 0; b < B; ++b)
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int c = 0; c < Cin; ++c) gref(b, y, x, c) += gin0(b, y, x, c);
  std::tie(d, m) = max_difference(gin, gref);
  CHECK(d <= tol * (1 + m));
  }
  nn::detail::conv::in_cache_transpose_weights_per_pixel = 8192;

  // Backward weight and bias accumulate too.
  std::vector<float> gw(w.size(), 0.5f), gb(Cout, 0.25f);
  nn::conv2d_backward_weight<Cin, Cout, K, S, P>(in, gout, gw.data(), gb.data());
  std::vector<double> gw_ref, gb_ref;
  testing::naive_conv_backward_weight(in, gout, gw_ref, gb_ref, K, S, G::pad_before);
  double dw = 0, mw = 0, db = 0;
  for (std::size_t i = 0; i < gw.size(); ++i) {
    dw = std::max(dw, std::abs(gw[i] - 0.5 - gw_ref[i]));
    mw = std::max(mw, std::abs(gw_ref[i]));
  }
  for (int c = 0; c < Cout; ++c) db = std::max(db, std::abs(gb[c] - 0.25 - gb_ref[c]));
  CHECK(dw <= 1e-5 * std::sqrt(double(B * Ho * Wo)) * (1 + mw));
  CHECK(db <= 1e-5 * std::sqrt(double(B * Ho * Wo)) * (1 + mw));
}

/// Central differences of loss = sum(out * R) against the three backward passes, in double.
/// samples = 0 checks every entry, otherwise that many random entries of each array.
template <int Cin, int Cout, int K, int S, int P>
void check_gradients(int B, int H, int W, int samples, unsigned seed) {
  // The sampled (SIMD-width) cases transpose the kernel block by block in the work items, the
  // others through one transposed copy.
  nn::detail::conv::in_cache_transpose_weights_per_pixel = samples ? 0 : SIZE_MAX;
  std::mt19937 rng(seed);
  const int Ho = nn::conv2d_output_size<K, S, P>(H), Wo = nn::conv2d_output_size<K, S, P>(W);
  tensor<Cin, double> in(B, H, W);
  fill_random(in, rng);
  std::vector<double> w(static_cast<std::size_t>(K * K * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  tensor<Cout, double> r(B, Ho, Wo), out(B, Ho, Wo);
  fill_random(r, rng);
  auto loss = [&]() {
    nn::conv2d_forward<Cin, Cout, K, S, P>(in, w.data(), bias.data(), out);
    double s = 0;
    for (std::size_t i = 0; i < out.size(); ++i) s += out.data()[i] * r.data()[i];
    return s;
  };
  tensor<Cin, double> gin(B, H, W);
  nn::conv2d_backward_input<Cin, Cout, K, S, P>(r, w.data(), gin);
  std::vector<double> gw(w.size(), 0.0), gb(Cout, 0.0);
  nn::conv2d_backward_weight<Cin, Cout, K, S, P>(in, r, gw.data(), gb.data());
  // The loss is linear in each argument, so central differences are exact up to rounding: a large
  // step keeps the rounding error far below the tolerance.
  const double step = 1e-3;
  auto check = [&](double* x, std::size_t n, const double* analytic) {
    double worst = 0;
    if (samples == 0) {
      worst = testing::check_gradient<double>(loss, x, n, analytic, step).max_rel_error;
    } else {
      for (int k = 0; k < samples; ++k) {
        const std::size_t i = rng() % n;
        worst = std::max(worst, testing::check_gradient<double>(loss, x + i, 1, analytic + i, step).max_rel_error);
      }
    }
    return worst;
  };
  CHECK(check(in.data(), in.size(), gin.data()) < 1e-7);
  CHECK(check(w.data(), w.size(), gw.data()) < 1e-7);
  CHECK(check(bias.data(), bias.size(), gb.data()) < 1e-7);
  nn::detail::conv::in_cache_transpose_weights_per_pixel = 8192;
}

}  // namespace

TEST_CASE("conv2d 4x4 stride 2 matches the naive loops") {
  check_against_reference<3, 5, 4, 2, 1>(2, 7, 9, 1);
  check_against_reference<64, 64, 4, 2, 1>(2, 9, 11, 2);   // SIMD path, channel chunks, tails
  check_against_reference<64, 64, 4, 2, 1>(1, 5, 61, 3);   // full tiles
}

TEST_CASE("conv2d 3x3, 4x4 'same' and 1x1 match the naive loops") {
  check_against_reference<12, 64, 3, 1, 1>(2, 7, 9, 4);
  check_against_reference<64, 12, 4, 1, nn::same_padding>(2, 7, 9, 5);
  check_against_reference<9, 48, 1, 1, 0>(2, 7, 9, 6);
}

TEST_CASE("conv2d output sizes") {
  CHECK(nn::conv2d_output_size<4, 2, 1>(256) == 128);
  CHECK(nn::conv2d_output_size<4, 2, 1>(7) == 3);
  CHECK(nn::conv2d_output_size<3, 1, 1>(9) == 9);
  CHECK(nn::conv2d_output_size<4, 1, nn::same_padding>(9) == 9);
  CHECK(nn::conv2d_output_size<1, 1, 0>(5) == 5);
  tensor<3> in(1, 8, 8);
  tensor<5> wrong(1, 3, 4);
  std::vector<float> w(16 * 15);
  CHECK_THROWS_AS((nn::conv2d_forward<3, 5, 4, 2, 1>(in, w.data(), nullptr, wrong)), std::invalid_argument);
}

TEST_CASE("conv2d gradients match central differences") {
  check_gradients<3, 5, 4, 2, 1>(2, 7, 9, 0, 11);
  check_gradients<4, 3, 3, 1, 1>(2, 5, 7, 0, 12);
  check_gradients<3, 4, 4, 1, nn::same_padding>(2, 5, 6, 0, 13);
  check_gradients<32, 64, 4, 2, 1>(2, 5, 7, 40, 14);  // SIMD path
  check_gradients<32, 32, 3, 1, 1>(1, 5, 7, 40, 15);
}

namespace {
/// bias_gradient on one thread against the plain loop: channel by channel, pixels in order from the
/// value already there, so the same bits (whole registers, a masked last register, or less than one).
template <int C>
void check_bias_gradient(int B, int H, int W, unsigned seed) {
  std::mt19937 rng(seed);
  tensor<C> g(B, H, W);
  fill_random(g, rng);
  std::vector<float> got(C, 0.5f), want(C, 0.0f);
  const int saved = omp_get_max_threads();
  omp_set_num_threads(1);
  nn::detail::conv::bias_gradient(g, got.data());
  omp_set_num_threads(saved);
  for (int b = 0; b < B; ++b)
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int c = 0; c < C; ++c) want[std::size_t(c)] += g.pixel(b, y, x)[c];
  for (int c = 0; c < C; ++c) want[std::size_t(c)] += 0.5f;
  CHECK(got == want);
}
}  // namespace

TEST_CASE("the bias gradient sums each channel's pixels in order") {
  check_bias_gradient<3>(2, 70, 90, 1);
  check_bias_gradient<12>(1, 256, 260, 2);
  check_bias_gradient<16>(2, 130, 129, 3);
  check_bias_gradient<20>(1, 200, 333, 4);
  check_bias_gradient<64>(1, 64, 64, 5);
}
