#include <doctest/doctest.h>

#include "anisocap/render/analysis.hpp"
#include "anisocap/render/renderer.hpp"
#include "render_reference.hpp"

using namespace anisocap;
using namespace anisocap::testing;

TEST_CASE("kernel analysis: the chosen kernel renders like the full one within the tolerance") {
  const capture cap = random_capture(6, 3);
  SUBCASE("full material needs every term") {
    const material_maps m = random_maps(16, 12, 1);
    const auto a = analyse_kernel(m, cap);
    CHECK(a.features == all_features);
  }
  SUBCASE("isotropic, flat, F0 = 1: the cheapest kernel, and it renders the same") {
    material_maps m = random_maps(16, 12, 2, brdf_features{false, false, false});
    const auto a = analyse_kernel(m, cap);
    CHECK_FALSE(a.features.anisotropic);
    CHECK_FALSE(a.features.fresnel);
    CHECK_FALSE(a.features.normal_map);
    CHECK(a.describe() == "isotropic, no Fresnel, flat normals");
    const auto full = render(m, cap);
    const auto cheap = with_features(a.features, [&]<brdf_features F>() { return render<F>(m, cap); });
    for (std::size_t k = 0; k < full.size(); ++k)
      for (std::size_t i = 0; i < full[k].pixel_count(); ++i)
        REQUIRE(cheap[k].plane(1)[i] == doctest::Approx(full[k].plane(1)[i]).epsilon(1e-3));
  }
  SUBCASE("a low F0 under a grazing view keeps the Fresnel term") {
    material_maps m = random_maps(16, 12, 3, brdf_features{false, false, false});
    for (std::size_t i = 0; i < m.texel_count(); ++i) m.plane(fresnel_f0)[i] = 0.04f;
    capture grazing = cap;
    grazing.images[0].camera = {3.0f, 0.0f, 0.1f};
    grazing.images[0].light = {-3.0f, 0.0f, 0.1f};
    CHECK(analyse_kernel(m, grazing).features.fresnel);
    CHECK(analyse_kernel(m, grazing).max_fresnel_excess > 1.0);
  }
}
