#pragma once
/// @file
/// Evaluation errors grouped by procedural family (eval, eval-networks): which families a
/// capture or a network gets right, and how the families held out of training fare
/// (docs/procedural.md).
#include <cmath>
#include <cstdint>
#include <vector>

#include "anisocap/data/procedural.hpp"
#include "anisocap/render/evaluate.hpp"

namespace anisocap {

/// The errors of one evaluated material, labelled with its family.
struct material_errors {
  material_kind kind = material_kind::plain_weave;  ///< the material's family
  parameter_errors errors;                          ///< compare_maps against the truth
  double novel_view_loss = std::nan("");            ///< novel_view_error, NaN when not measured
};

/// Mean errors over the materials of one family.
struct family_errors {
  material_kind kind = material_kind::plain_weave;  ///< the family
  int count = 0;                                    ///< materials averaged
  parameter_errors mean;     ///< per-parameter means (rotation_anisotropic over the materials that have it; NaN if none)
  double novel_view_loss = std::nan("");  ///< mean over the materials that measured it; NaN if none
};

/// Mean errors over the materials that `keep(material)` accepts (`count` says how many; `kind` is
/// left at its default): rotation_anisotropic and the novel-view loss are averaged over the
/// materials that have them, NaN when none does.
template <class Keep>
family_errors average_errors(const std::vector<material_errors>& materials, Keep keep) {
  family_errors row;
  int anisotropic = 0, novel = 0;
  double rotation_anisotropic = 0, novel_sum = 0;
  for (const material_errors& m : materials) {
    if (!keep(m)) continue;
    ++row.count;
    row.mean.diffuse += m.errors.diffuse;
    row.mean.specular += m.errors.specular;
    row.mean.normal += m.errors.normal;
    row.mean.lobes += m.errors.lobes;
    row.mean.rotation += m.errors.rotation;
    row.mean.fresnel += m.errors.fresnel;
    if (!std::isnan(m.errors.rotation_anisotropic)) { rotation_anisotropic += m.errors.rotation_anisotropic; ++anisotropic; }
    if (!std::isnan(m.novel_view_loss)) { novel_sum += m.novel_view_loss; ++novel; }
  }
  if (row.count > 0) {
    const double n = row.count;
    row.mean.diffuse /= n; row.mean.specular /= n; row.mean.normal /= n; row.mean.lobes /= n;
    row.mean.rotation /= n; row.mean.fresnel /= n;
  }
  row.mean.rotation_anisotropic = anisotropic ? rotation_anisotropic / anisotropic : std::nan("");
  row.novel_view_loss = novel ? novel_sum / novel : std::nan("");
  return row;
}

/// Mean errors over all the materials (average_errors of every one).
inline family_errors average_errors(const std::vector<material_errors>& materials) {
  return average_errors(materials, [](const material_errors&) { return true; });
}

/// Groups per-material errors by family and averages each group: one row per family present, in
/// material_kind order.
inline std::vector<family_errors> errors_by_family(const std::vector<material_errors>& materials) {
  std::vector<family_errors> rows;
  for (int k = 0; k < material_kind_count; ++k) {
    const auto kind = static_cast<material_kind>(k);
    family_errors row = average_errors(materials, [kind](const material_errors& m) { return m.kind == kind; });
    row.kind = kind;
    if (row.count > 0) rows.push_back(row);
  }
  return rows;
}

/// The kind of evaluation material m: families[m mod size] when a list is given (each listed
/// family in turn), otherwise kind_for_seed(seed, mix).
inline material_kind evaluation_kind(int m, std::uint64_t seed, const std::vector<material_kind>& families, material_mix mix) {
  return families.empty() ? kind_for_seed(seed, mix) : families[std::size_t(m) % families.size()];
}

}  // namespace anisocap
