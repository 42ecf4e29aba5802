#pragma once
// Central finite differences against an analytic gradient, for every derivative the library computes.
#include <cmath>
#include <cstddef>
#include <functional>
#include <string>

namespace anisocap::testing {

/// Result of comparing an analytic gradient with central differences.
struct gradient_check_result {
  double max_abs_error = 0;  ///< largest |analytic - numeric|
  double max_rel_error = 0;  ///< largest |analytic - numeric| / max(1, |numeric|, |analytic|)
  std::size_t worst_index = 0;
};

/// Perturbs x[i] by +-step for each i, evaluates loss(), and compares the central difference with
/// analytic[i]. x must be the memory loss() reads. Restores x.
template <class T>
gradient_check_result check_gradient(const std::function<double()>& loss, T* x, std::size_t n,
                                     const T* analytic, double step = 1e-6) {
  gradient_check_result r;
  for (std::size_t i = 0; i < n; ++i) {
    const T saved = x[i];
    x[i] = saved + T(step);
    const double up = loss();
    x[i] = saved - T(step);
    const double down = loss();
    x[i] = saved;
    const double numeric = (up - down) / (2 * step);
    const double err = std::abs(double(analytic[i]) - numeric);
    const double rel = err / std::max({1.0, std::abs(numeric), std::abs(double(analytic[i]))});
    if (rel > r.max_rel_error) { r.max_rel_error = rel; r.worst_index = i; }
    r.max_abs_error = std::max(r.max_abs_error, err);
  }
  return r;
}

}  // namespace anisocap::testing
