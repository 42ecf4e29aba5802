#include <doctest/doctest.h>

#include <cmath>
#include <vector>

#include "anisocap/data/family_errors.hpp"

using namespace anisocap;

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
  // The overall mean: every material, NaN-aware in the same way.
  const family_errors overall = average_errors(all);
  CHECK(overall.count == 4);
  CHECK(overall.mean.lobes == doctest::Approx(2.5));
  CHECK(overall.mean.rotation_anisotropic == doctest::Approx(7.0 / 3));  // materials 0, 1 and 3
  CHECK(overall.novel_view_loss == doctest::Approx(1.5));                 // materials 0, 1 and 3
  CHECK(std::isnan(average_errors({}).mean.rotation_anisotropic));
  // evaluation_kind: a family list is used in turn, otherwise the mix decides.
  const std::vector<material_kind> listed = {material_kind::leather, material_kind::printed};
  CHECK(evaluation_kind(0, 99, listed, material_mix::original) == material_kind::leather);
  CHECK(evaluation_kind(3, 99, listed, material_mix::original) == material_kind::printed);
  CHECK(evaluation_kind(3, 99, {}, material_mix::extended) == kind_for_seed(99, material_mix::extended));
}
