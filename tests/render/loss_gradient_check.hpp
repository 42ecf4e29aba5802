#pragma once
// The fused image loss's gradient (render/renderer.hpp) against central differences, plane by plane.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "anisocap/render/renderer.hpp"
#include "support/gradient_check.hpp"

namespace anisocap::testing {

/// Checks the double-precision gradient of the loss of `maps` against `targets` (masks and floors as
/// they are) against central differences on every texel of every plane, and returns it. The step
/// is one float resolves and small enough to stay clear of the absolute values' kinks.
inline material_maps check_loss_gradient(const material_maps& maps, const capture& cap, const loss_targets& targets) {
  render_options dbl;
  dbl.double_precision = true;
  material_maps g(maps.width(), maps.height());
  loss_and_gradient(maps, cap, targets, &g, {}, dbl);
  material_maps m = maps;
  for (int k = 0; k < parameter_count; ++k) {
    float* x = m.plane(k);
    const std::size_t n = m.texel_count();
    std::vector<double> analytic(g.plane(k), g.plane(k) + n);
    double scale = 1e-9;
    for (double a : analytic) scale = std::max(scale, std::abs(a));
    const double step = 1.0 / 16384;
    std::vector<double> xd(x, x + n);
    auto loss = [&] {
      for (std::size_t i = 0; i < n; ++i) x[i] = float(xd[i]);
      return loss_and_gradient(m, cap, targets, nullptr, {}, dbl);
    };
    const auto r = check_gradient<double>(loss, xd.data(), n, analytic.data(), step);
    for (std::size_t i = 0; i < n; ++i) x[i] = maps.plane(k)[i];
    INFO("plane " << k << " worst texel " << r.worst_index << " max abs error " << r.max_abs_error << " scale " << scale);
    CHECK(r.max_abs_error < 2e-3 * scale + 1e-7);
  }
  return g;
}

}  // namespace anisocap::testing
