#include <doctest/doctest.h>

#include <numbers>

#include "../render/render_reference.hpp"
#include "anisocap/pipeline/evaluate.hpp"

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

TEST_CASE("errors_by_family: means per family in kind order, NaN-aware, absent families left out") {
  auto errors = [](double v) {
    parameter_errors e;
    e.diffuse = e.specular = e.normal = e.lobes = e.rotation = e.fresnel = v;
    e.rotation_anisotropic = v;
    return e;
  };
  std::vector<material_errors> all = {{material_kind::printed, errors(1.0), 0.5},
                                      {material_kind::brushed_metal, errors(2.0), 1.0},
                                      {material_kind::printed, errors(3.0), std::nan("")},
                                      {material_kind::brushed_metal, errors(4.0), 3.0}};
  all[2].errors.rotation_anisotropic = std::nan("");  // an isotropic material has no anisotropic texels
  const std::vector<family_errors> rows = errors_by_family(all);
  REQUIRE(rows.size() == 2);
  CHECK(rows[0].kind == material_kind::brushed_metal);  // material_kind order, not input order
  CHECK(rows[0].count == 2);
  CHECK(rows[0].mean.fresnel == doctest::Approx(3.0));
  CHECK(rows[0].mean.specular == doctest::Approx(3.0));
  CHECK(rows[0].novel_view_loss == doctest::Approx(2.0));
  CHECK(rows[1].kind == material_kind::printed);
  CHECK(rows[1].mean.diffuse == doctest::Approx(2.0));
  CHECK(rows[1].mean.rotation_anisotropic == doctest::Approx(1.0));  // over the material that has it
  CHECK(rows[1].novel_view_loss == doctest::Approx(0.5));
  CHECK(errors_by_family({}).empty());
  // evaluation_kind: a family list is used in turn, otherwise the mix decides.
  const std::vector<material_kind> listed = {material_kind::leather, material_kind::printed};
  CHECK(evaluation_kind(0, 99, listed, material_mix::original) == material_kind::leather);
  CHECK(evaluation_kind(3, 99, listed, material_mix::original) == material_kind::printed);
  CHECK(evaluation_kind(3, 99, {}, material_mix::extended) == kind_for_seed(99, material_mix::extended));
}
