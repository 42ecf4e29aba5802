#include <doctest/doctest.h>

#include <numbers>

#include "../render/render_reference.hpp"
#include "anisocap/render/evaluate.hpp"

using namespace anisocap;

TEST_CASE("compare_maps: zero for identical maps and for the BRDF's symmetric representations") {
  const material_maps truth = testing::random_maps(11, 9, 1);
  material_maps m = truth;
  parameter_errors e = compare_maps(m, truth);
  CHECK(e.diffuse == 0.0); CHECK(e.lobes == 0.0); CHECK(e.rotation == 0.0); CHECK(e.normal == 0.0);
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    if (i % 2) m.plane(rotation)[i] += float(std::numbers::pi);  // alpha is pi-periodic
    else {                                                      // swapped lobes, rotated by pi/2
      std::swap(m.plane(lobe_x)[i], m.plane(lobe_y)[i]);
      m.plane(rotation)[i] -= float(std::numbers::pi / 2);
    }
  }
  e = compare_maps(m, truth);
  CHECK(e.lobes == doctest::Approx(0.0));
  CHECK(e.rotation == doctest::Approx(0.0).epsilon(1e-9));
  // The two representations render identically (what justifies the symmetry).
  const capture cap = testing::random_capture(3, 2);
  const auto a = render(m, cap), b = render(truth, cap);
  for (std::size_t k = 0; k < a.size(); ++k)
    for (std::size_t i = 0; i < a[k].pixel_count(); ++i) CHECK(a[k].plane(0)[i] == doctest::Approx(b[k].plane(0)[i]).epsilon(1e-3));
}

TEST_CASE("compare_maps: known offsets give known errors") {
  const material_maps truth = testing::random_maps(8, 8, 2);
  material_maps m = truth;
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    m.plane(diffuse_g)[i] += 0.3f;             // one channel of three
    m.plane(fresnel_f0)[i] += 0.1f;
    m.plane(rotation)[i] += 0.2f;
  }
  const parameter_errors e = compare_maps(m, truth);
  CHECK(e.diffuse == doctest::Approx(0.09 / 3).epsilon(1e-4));
  CHECK(e.fresnel == doctest::Approx(0.01).epsilon(1e-4));
  CHECK(e.rotation <= 0.04 + 1e-6);
  CHECK(e.specular == 0.0);
  CHECK_THROWS_AS(compare_maps(material_maps(3, 3), truth), std::invalid_argument);
}

TEST_CASE("novel views: three unseen configurations; the error is zero for the truth and grows with a wrong estimate") {
  const capture views = novel_view_set(5, 30, 20);
  REQUIRE(views.images.size() == 3);
  CHECK(views.images[0].file == "novel_00.exr");
  for (const auto& v : views.images) CHECK(v.camera[2] > 0.0f);
  const capture again = novel_view_set(5, 30, 20);
  CHECK(again.images[1].light == views.images[1].light);
  const material_maps truth = testing::random_maps(30, 20, 4);
  CHECK(novel_view_error(truth, truth, views) < 1e-6);  // float logs computed two ways
  material_maps off = truth;
  for (std::size_t i = 0; i < off.texel_count(); ++i) off.plane(diffuse_r)[i] *= 0.5f;
  material_maps further = truth;
  for (std::size_t i = 0; i < off.texel_count(); ++i) further.plane(diffuse_r)[i] *= 0.25f;
  const double e1 = novel_view_error(off, truth, views), e2 = novel_view_error(further, truth, views);
  CHECK(e1 > 0.0);
  CHECK(e2 > e1);
}
