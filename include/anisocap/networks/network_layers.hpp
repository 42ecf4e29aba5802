#pragma once
/// @file
/// What the estimation network and the auto-encoder share: the leaky-ReLU slope, parameter
/// visiting, cropping on the tape, and He initialisation of convolutions.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/image.hpp"
#include "anisocap/nn/nn.hpp"
#include "anisocap/networks/network_space.hpp"

namespace anisocap {

namespace network_detail {

/// Leaky-ReLU slope of both networks (Deschaintre 2018 uses 0.2).
inline constexpr double leaky_slope = 0.2;

/// Visits every parameter of a list of layers.
template <class F, class... L>
void visit(F& f, L&... layers) {
  (layers.for_each_parameter(f), ...);
}

/// y = x cropped to its top-left height x width (recorded on the tape).
template <int C, class T>
ad::variable<C, T> crop(ad::tape& t, const ad::variable<C, T>& x, int height, int width) {
  if (height == x.value.height() && width == x.value.width()) return x;
  auto y = t.make_variable<C, T>(x.value.batch(), height, width, x.requires_grad);
  for (int b = 0; b < x.value.batch(); ++b)
    for (int r = 0; r < height; ++r) std::copy_n(x.value.pixel(b, r, 0), std::size_t(width) * C, y.value.pixel(b, r, 0));
  if (y.requires_grad)
    t.record([x = x, y, height, width]() mutable {
      for (int b = 0; b < x.value.batch(); ++b)
        for (int r = 0; r < height; ++r) {
          T* g = x.grad.pixel(b, r, 0);
          const T* gy = y.grad.pixel(b, r, 0);
          for (std::size_t i = 0; i < std::size_t(width) * C; ++i) g[i] += gy[i];
        }
    });
  return y;
}

/// He-uniform weights (leaky ReLU) and zero biases for a convolution, from the layer's name.
template <class Conv>
void init_conv(Conv& c, int fan_in, std::uint64_t seed) {
  nn::he_uniform(c.weight, fan_in, seed, leaky_slope);
  if (c.has_bias()) nn::constant_init(c.bias, decltype(c.bias.value[0] + 0)(0));
}

}  // namespace network_detail

}  // namespace anisocap
