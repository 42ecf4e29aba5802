// ANISOCAP_TEXEL_KERNELS as a program of several translation units uses it: the declarations
// first (as a shared header would have them), the definitions at the end of this unit. The test
// compiles and links only if the macros name the kernels exactly, and the declared kernels run.
#include <doctest/doctest.h>

#include "../render/render_reference.hpp"
#include "anisocap/pipeline/texel_kernels.hpp"

ANISOCAP_TEXEL_KERNELS(extern)

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("the explicitly instantiated texel kernels refine every feature set, score it with the same loss and render it") {
  const int w = 10, h = 9;
  const capture cap = random_capture(6, 21);
  const loss_targets targets = make_loss_targets(render(random_maps(w, h, 22), cap));
  for (int code = 0; code < 8; ++code) {
    const brdf_features features{(code & 4) != 0, (code & 2) != 0, (code & 1) != 0};
    CAPTURE(code);
    with_features(features, [&]<brdf_features F>() {
      material_maps maps = random_maps(w, h, 23);
      refine_options options;
      options.steps = 30;
      const refine_result r = refine<F>(maps, cap, targets, options);
      CHECK(r.final_loss < r.losses.front());
      CHECK(r.final_loss == loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, options.render));
      render_options in_double = options.render;
      in_double.double_precision = true;  // the double-batch instance
      CHECK(loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, in_double) ==
            doctest::Approx(r.final_loss).epsilon(1e-4));
      // The declared renderer: the refined maps fit their own renders to float rounding, and those
      // are not the targets they were refined towards.
      const std::vector<image> own = render<F>(maps, cap);
      const double own_loss = loss_and_gradient<F>(maps, cap, make_loss_targets(own), nullptr, options.placement, options.render);
      CHECK(own_loss < 1e-6);
      CHECK(own_loss < 1e-3 * r.final_loss);
    });
  }
}

ANISOCAP_TEXEL_KERNELS()
