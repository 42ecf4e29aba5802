#pragma once
/// @file
/// A trainable array of weights with its gradient; `frozen` parameters get no gradient at all.
#include <string>
#include <vector>

#include "anisocap/core/memory.hpp"

namespace anisocap::nn {

/// Weights of one layer, in T (float for networks, double for gradient checks) (a convolution kernel, a bias, ...), flat and 64-byte aligned, with a
/// logical shape for weight files. Layers document their weight layout.
template <class T>
struct basic_parameter {
  std::string name;          ///< unique name within a network, used in weight files
  std::vector<int> shape;    ///< logical shape, outermost first
  aligned_buffer<T> value;
  aligned_buffer<T> grad;  ///< same size as value; accumulated by backward, zeroed by the optimiser
  bool frozen = false;         ///< frozen: backward computes no weight gradient for it

  basic_parameter() = default;
  basic_parameter(std::string n, std::vector<int> s) : name(std::move(n)), shape(std::move(s)) {
    std::size_t count = 1;
    for (int d : shape) count *= std::size_t(d);
    value = aligned_buffer<T>(count);
    grad = aligned_buffer<T>(count);
  }
  std::size_t size() const noexcept { return value.size(); }
  /// True when backward should compute this parameter's gradient.
  bool trainable() const noexcept { return !frozen; }
  void zero_grad() noexcept { for (auto& g : grad) g = T(0); }
};

/// The float parameter networks train; double instances serve gradient checks.
using parameter = basic_parameter<float>;

}  // namespace anisocap::nn
