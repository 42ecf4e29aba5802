#pragma once
/// @file
/// What the estimation network and the auto-encoder share: the leaky-ReLU slope, parameter
/// visiting, cropping on the tape, and He initialisation of convolutions.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
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

/// A parameter visitor with its type erased. A network lists its layers once, in a function that
/// takes this, rather than once per visitor (the optimiser, the weight files, the fingerprint, the
/// freezing...): visiting runs once per parameter, never per value, and each network's listing is
/// then compiled once instead of some fifteen times.
template <class T>
using parameter_visitor = std::function<void(nn::basic_parameter<T>&)>;

/// `f` as a parameter_visitor that calls it by reference (a visitor's state stays the caller's).
template <class T, class F>
parameter_visitor<T> erase_visitor(F& f) {
  return std::ref(f);
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

/// The doubled-angle output of the estimator's normal-and-rotation track: from 4 raw channels
/// (z_x, z_y, c, s) to its 3 network-space channels (tanh z_x, tanh z_y, atan2(s, c) / pi), recorded
/// on the tape. (c, s) is the direction of 2 alpha, so the rotation, pi-periodic, is a continuous
/// function of the raw outputs: alpha near +pi/2 and near -pi/2 (the same lobe) are neighbouring
/// vectors, where a tanh output for alpha / (pi/2) has to jump from +1 to -1. The network value
/// atan2(s, c) / pi is alpha / (pi/2) in (-1, 1] (network_space.hpp). At (c, s) = (0, 0) the angle
/// is 0 and its gradient is taken as 0.
template <class T>
ad::variable<3, T> normals_and_doubled_angle(ad::tape& t, const ad::variable<4, T>& x) {
  auto y = t.make_variable<3, T>(x.value.batch(), x.value.height(), x.value.width(), x.requires_grad);
  const double pi = 3.14159265358979323846;
  for (int b = 0; b < x.value.batch(); ++b)
    for (int r = 0; r < x.value.height(); ++r)
      for (int c = 0; c < x.value.width(); ++c) {
        const T* in = x.value.pixel(b, r, c);
        T* out = y.value.pixel(b, r, c);
        out[0] = T(std::tanh(double(in[0])));
        out[1] = T(std::tanh(double(in[1])));
        out[2] = T(std::atan2(double(in[3]), double(in[2])) / pi);
      }
  if (y.requires_grad)
    t.record([x = x, y, pi]() mutable {
      for (int b = 0; b < x.value.batch(); ++b)
        for (int r = 0; r < x.value.height(); ++r)
          for (int c = 0; c < x.value.width(); ++c) {
            const T* in = x.value.pixel(b, r, c);
            const T* out = y.value.pixel(b, r, c);
            const T* gy = y.grad.pixel(b, r, c);
            T* gx = x.grad.pixel(b, r, c);
            gx[0] += gy[0] * (T(1) - out[0] * out[0]);
            gx[1] += gy[1] * (T(1) - out[1] * out[1]);
            const double cv = in[2], sv = in[3], r2 = cv * cv + sv * sv;
            if (r2 > 0) {  // d atan2(s, c) = (c ds - s dc) / (c^2 + s^2)
              gx[2] += T(-double(gy[2]) * sv / (pi * r2));
              gx[3] += T(double(gy[2]) * cv / (pi * r2));
            }
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
