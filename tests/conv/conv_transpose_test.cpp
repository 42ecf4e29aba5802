// Transposed convolution (4x4, stride 2, padding 1): forward and backward passes against naive
// loops (float) and gradients against central finite differences (double).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/precision.hpp"
#include "reference.hpp"
#include "support/gradient_check.hpp"

using namespace anisocap;
using anisocap::testing::fill_random;
using anisocap::testing::max_difference;

namespace {

template <int Cin, int Cout>
void check_against_reference(int B, int H, int W, unsigned seed) {
  std::mt19937 rng(seed);
  tensor<Cin> in(B, H, W);
  fill_random(in, rng);
  std::vector<float> w(static_cast<std::size_t>(16 * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  const double tol = 1e-5 * std::sqrt(double(16 * std::max(Cin, Cout)));

  tensor<Cout> out(B, 2 * H, 2 * W);
  nn::conv_transpose2d_forward<Cin, Cout>(in, w.data(), bias.data(), out);
  tensor<Cout, double> ref(B, 2 * H, 2 * W);
  testing::naive_conv_transpose(in, w.data(), bias.data(), ref);
  auto [d, m] = max_difference(out, ref);
  CHECK(d <= tol * (1 + m));

  // The transposed convolution is the adjoint of the 4x4 stride-2 convolution with the same
  // weights read as [kh][kw][out][in]; its backward passes are checked through that identity's
  // naive loops: gin[i][j][ci] = sum gout[2i-1+kh][2j-1+kw][co] w[kh][kw][ci][co].
  tensor<Cout> gout(B, 2 * H, 2 * W);
  fill_random(gout, rng);
  std::vector<float> wt(w.size());
  for (int t = 0; t < 16; ++t)
    for (int ci = 0; ci < Cin; ++ci)
      for (int co = 0; co < Cout; ++co) wt[(t * Cout + co) * Cin + ci] = w[(t * Cin + ci) * Cout + co];
  for (std::size_t threshold : {std::size_t(0), SIZE_MAX}) {
  nn::detail::conv::in_cache_transpose_weights_per_pixel = threshold;
  tensor<Cin> gin(B, H, W);
  fill_random(gin, rng);
  const tensor<Cin> gin0 = gin.clone();
  nn::conv_transpose2d_backward_input<Cin, Cout>(gout, w.data(), gin);
  tensor<Cin, double> gref(B, H, W);
  testing::naive_conv(gout, wt.data(), static_cast<const float*>(nullptr), gref, 4, 2, 1);
  for (int b = 0; b < B; ++b)
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int c = 0; c < Cin; ++c) gref(b, y, x, c) += gin0(b, y, x, c);
  std::tie(d, m) = max_difference(gin, gref);
  CHECK(d <= tol * (1 + m));
  }
  nn::detail::conv::in_cache_transpose_weights_per_pixel = 8192;

  // gW[kh][kw][ci][co] = sum in[i][j][ci] gout[2i-1+kh][2j-1+kw][co]: the conv weight gradient
  // with input gout and output gradient in, transposed.
  std::vector<float> gw(w.size(), 0.5f), gb(Cout, 0.25f);
  nn::conv_transpose2d_backward_weight<Cin, Cout>(in, gout, gw.data(), gb.data());
  std::vector<double> gwt_ref, unused;
  testing::naive_conv_backward_weight(gout, in, gwt_ref, unused, 4, 2, 1);
  double dw = 0, mw = 0;
  for (int t = 0; t < 16; ++t)
    for (int ci = 0; ci < Cin; ++ci)
      for (int co = 0; co < Cout; ++co) {
        const double r = gwt_ref[(t * Cout + co) * Cin + ci];
        dw = std::max(dw, std::abs(gw[(t * Cin + ci) * Cout + co] - 0.5 - r));
        mw = std::max(mw, std::abs(r));
      }
  CHECK(dw <= 1e-5 * std::sqrt(double(B * H * W)) * (1 + mw));
  double db = 0;
  for (int co = 0; co < Cout; ++co) {
    double s = 0;
    for (int b = 0; b < B; ++b)
      for (int y = 0; y < 2 * H; ++y)
        for (int x = 0; x < 2 * W; ++x) s += gout(b, y, x, co);
    db = std::max(db, std::abs(gb[co] - 0.25 - s));
  }
  CHECK(db <= 1e-4 * std::sqrt(double(B * H * W)));
}

template <int Cin, int Cout>
void check_gradients(int B, int H, int W, int samples, unsigned seed) {
  // The sampled (SIMD-width) cases transpose the kernel block by block in the work items, the
  // others through one transposed copy.
  nn::detail::conv::in_cache_transpose_weights_per_pixel = samples ? 0 : SIZE_MAX;
  std::mt19937 rng(seed);
  tensor<Cin, double> in(B, H, W);
  fill_random(in, rng);
  std::vector<double> w(static_cast<std::size_t>(16 * Cin * Cout)), bias(Cout);
  fill_random(w.data(), w.size(), rng);
  fill_random(bias.data(), bias.size(), rng);
  tensor<Cout, double> r(B, 2 * H, 2 * W), out(B, 2 * H, 2 * W);
  fill_random(r, rng);
  auto loss = [&]() {
    nn::conv_transpose2d_forward<Cin, Cout>(in, w.data(), bias.data(), out);
    double s = 0;
    for (std::size_t i = 0; i < out.size(); ++i) s += out.data()[i] * r.data()[i];
    return s;
  };
  tensor<Cin, double> gin(B, H, W);
  nn::conv_transpose2d_backward_input<Cin, Cout>(r, w.data(), gin);
  std::vector<double> gw(w.size(), 0.0), gb(Cout, 0.0);
  nn::conv_transpose2d_backward_weight<Cin, Cout>(in, r, gw.data(), gb.data());
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

TEST_CASE("conv_transpose2d matches the naive loops") {
  check_against_reference<3, 5>(2, 7, 9, 21);
  check_against_reference<64, 32>(2, 5, 7, 22);   // SIMD path
  check_against_reference<64, 12>(1, 6, 31, 23);  // 12 outputs: padded register, wide rows
}

TEST_CASE("conv_transpose2d gradients match central differences") {
  check_gradients<3, 5>(2, 3, 5, 0, 31);
  check_gradients<32, 64>(1, 3, 4, 40, 32);  // SIMD path
}

namespace {
/// conv_transpose2d_backward against conv_transpose2d_backward_input and _weight called apart:
/// the same bits, with or without each gradient asked for.
template <int Cin, int Cout>
void check_backward_at_once(int B, int H, int W, unsigned seed) {
  std::mt19937 rng(seed);
  tensor<Cin> in(B, H, W);
  tensor<Cout> gout(B, 2 * H, 2 * W);
  fill_random(in, rng);
  fill_random(gout, rng);
  std::vector<float> w(16 * Cin * Cout);
  std::uniform_real_distribution<float> u(-1, 1);
  for (float& v : w) v = u(rng);
  tensor<Cin> gin_apart(B, H, W), gin_once(B, H, W);
  fill_random(gin_apart, rng);
  std::copy(gin_apart.data(), gin_apart.data() + gin_apart.size(), gin_once.data());
  std::vector<float> gw_apart(w.size(), 0.25f), gw_once = gw_apart, gb_apart(Cout, -0.5f), gb_once = gb_apart;
  nn::conv_transpose2d_backward_input<Cin, Cout>(gout, w.data(), gin_apart);
  nn::conv_transpose2d_backward_weight<Cin, Cout>(in, gout, gw_apart.data(), gb_apart.data());
  nn::conv_transpose2d_backward<Cin, Cout>(in, gout, w.data(), &gin_once, gw_once.data(), gb_once.data());
  CHECK(std::equal(gin_apart.data(), gin_apart.data() + gin_apart.size(), gin_once.data()));
  CHECK(gw_once == gw_apart);
  CHECK(gb_once == gb_apart);
  // Without the input gradient, and without the weights': the rest as before.
  std::vector<float> gw_alone(w.size(), 0.25f), gb_alone(Cout, -0.5f);
  nn::conv_transpose2d_backward<Cin, Cout>(in, gout, w.data(), nullptr, gw_alone.data(), gb_alone.data());
  CHECK(gw_alone == gw_apart);
  CHECK(gb_alone == gb_apart);
  tensor<Cin> gin_alone(B, H, W);
  std::copy(gin_once.data(), gin_once.data() + gin_once.size(), gin_alone.data());
  nn::conv_transpose2d_backward<Cin, Cout>(in, gout, w.data(), &gin_alone, nullptr, nullptr);
  nn::conv_transpose2d_backward_input<Cin, Cout>(gout, w.data(), gin_once);
  CHECK(std::equal(gin_once.data(), gin_once.data() + gin_once.size(), gin_alone.data()));
}
}  // namespace

TEST_CASE("conv_transpose2d_backward pads the output gradient once and gives the passes' own bits") {
  check_backward_at_once<32, 12>(2, 9, 13, 41);  // the weight pass exchanges roles: one 12-channel copy
  check_backward_at_once<64, 32>(1, 12, 10, 42);  // whole registers: one copy
  check_backward_at_once<3, 5>(2, 5, 7, 43);      // a padded 16-channel copy for the weights: two copies
  if (nn::bf16_available()) {
    nn::precision_scope bf16(nn::precision::bf16);
    check_backward_at_once<32, 12>(1, 16, 20, 44);
    check_backward_at_once<64, 32>(2, 8, 8, 45);
  }
}
