#pragma once
// Shared helpers for the layer gradient checks: random tensors and a check of a layer's input and
// weight gradients against central differences of the scalar loss sum(w_i * out_i), random w.
#include <doctest/doctest.h>

#include <cstdint>
#include <vector>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/nn/init.hpp"
#include "anisocap/nn/parameter.hpp"
#include "support/gradient_check.hpp"

namespace anisocap::test_nn {

/// A dense owning tensor of uniform values in [-scale, scale).
template <int C, class T = double>
tensor<C, T> random_tensor(nn::random_generator& g, int b, int h, int w, double scale = 1) {
  tensor<C, T> x(b, h, w);
  for (std::size_t i = 0; i < x.size(); ++i) x.data()[i] = T(g.symmetric_uniform() * scale);
  return x;
}

/// Sum of w_i * y_i over a (possibly strided) tensor and a dense weight tensor of its shape.
template <int C, class T>
double weighted_sum(const tensor<C, T>& y, const tensor<C, T>& w) {
  double s = 0;
  for (int b = 0; b < y.batch(); ++b)
    for (int r = 0; r < y.height(); ++r)
      for (int i = 0; i < y.width(); ++i)
        for (int c = 0; c < C; ++c) s += double(y(b, r, i, c)) * double(w(b, r, i, c));
  return s;
}

/// Checks d loss / d x and d loss / d p for every parameter in `params`, where loss = sum(w * f(x)).
/// `f(tape&, const variable<Cin, double>&)` returns a variable; returns the worst relative error.
template <int Cin, class F>
double check_layer(F&& f, tensor<Cin, double> x, std::vector<nn::basic_parameter<double>*> params,
                   std::uint64_t seed = 7, bool check_input = true) {
  nn::random_generator g(seed);
  double worst = 0;
  for (auto* p : params) p->zero_grad();
  ad::tape t;
  auto xv = t.leaf(x, check_input);
  auto y = f(t, xv);
  using Y = decltype(y.value);
  Y w(y.value.batch(), y.value.height(), y.value.width());
  for (std::size_t i = 0; i < w.size(); ++i) w.data()[i] = g.symmetric_uniform();
  REQUIRE(y.requires_grad);
  y.grad.copy_from(w);
  t.backward();
  auto loss = [&] {
    ad::tape t2;
    ad::tape::no_grad_guard guard(t2);
    auto yy = f(t2, t2.leaf(x));
    return weighted_sum(yy.value, w);
  };
  if (check_input) {
    std::vector<double> analytic(xv.grad.data(), xv.grad.data() + x.size());
    auto r = testing::check_gradient<double>(loss, x.data(), x.size(), analytic.data());
    CHECK(r.max_rel_error < 1e-6);
    worst = std::max(worst, r.max_rel_error);
  }
  for (auto* p : params) {
    std::vector<double> analytic(p->grad.begin(), p->grad.end());
    auto r = testing::check_gradient<double>(loss, p->value.data(), p->size(), analytic.data());
    INFO("parameter " << p->name);
    CHECK(r.max_rel_error < 1e-6);
    worst = std::max(worst, r.max_rel_error);
  }
  return worst;
}

}  // namespace anisocap::test_nn
