// Masks in the fused loss (render/renderer.hpp, loss_targets): a masked pixel adds exact zeros to
// the loss and to every gradient entry, whatever its target holds, in float and in double.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "anisocap/render/renderer.hpp"
#include "render_reference.hpp"

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("masked pixels add exact zeros to the loss and the gradient, whatever their targets hold") {
  const int w = 37, h = 29;  // odd sizes: the last register of every image is partial
  const material_maps maps = random_maps(w, h, 31);
  const capture cap = random_capture(5, 17);
  const std::vector<image> photos = render(random_maps(w, h, 32), cap);
  // Per image a different scattered pattern; texels with x < 5 are masked in every image.
  std::vector<image> masks;
  for (std::size_t k = 0; k < photos.size(); ++k) {
    image m(w, h, 1);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) m.at(0, x, y) = x < 5 || (x * 7 + y * 3 + int(k)) % 4 == 0 ? 0.0f : 1.0f;
    masks.push_back(std::move(m));
  }
  const loss_targets clean = make_loss_targets(photos, masks);
  // The same targets with NaN, infinities and huge values where the masks leave pixels out.
  loss_targets garbage = clean;
  const float junk[] = {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                        -std::numeric_limits<float>::infinity(), 1e30f, -1e30f};
  int n = 0;
  for (std::size_t k = 0; k < photos.size(); ++k)
    for (int c = 0; c < 3; ++c)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          if (masks[k].at(0, x, y) == 0.0f) garbage.log_images[k].at(c, x, y) = junk[n++ % 5];

  for (const bool double_precision : {false, true}) {
    CAPTURE(double_precision);
    render_options o;
    o.double_precision = double_precision;
    material_maps g_clean(w, h), g_garbage(w, h);
    const double l_clean = loss_and_gradient(maps, cap, clean, &g_clean, {}, o);
    const double l_garbage = loss_and_gradient(maps, cap, garbage, &g_garbage, {}, o);
    CHECK(std::isfinite(l_clean));
    CHECK(l_garbage == l_clean);  // bit for bit
    bool identical = true, zero_where_always_masked = true, some_nonzero = false;
    for (int k = 0; k < parameter_count; ++k)
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const float a = g_clean.at(k, x, y), b = g_garbage.at(k, x, y);
          identical &= a == b && std::signbit(a) == std::signbit(b);
          if (x < 5) zero_where_always_masked &= a == 0.0f;
          else some_nonzero |= a != 0.0f;
        }
    CHECK(identical);
    CHECK(zero_where_always_masked);
    CHECK(some_nonzero);
    // The masks matter: without them the same maps and photographs give another loss.
    const double l_unmasked = loss_and_gradient(maps, cap, make_loss_targets(photos), nullptr, {}, o);
    CHECK(l_unmasked != l_clean);
  }
}
