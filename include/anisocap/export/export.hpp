#pragma once
/// @file
/// Exports of a map set to other renderers (one header per target) behind one entry point:
///   gltf     glTF 2.0 asset, KHR_materials_anisotropy + KHR_materials_specular (export/gltf.hpp)
///   mitsuba  Mitsuba 0.6 scene with the `ward` BSDF (export/mitsuba.hpp)
///   blender  Blender 4.x Python script building a Principled BSDF node tree (export/blender.hpp)
///   mtlx     MaterialX document with Autodesk Standard Surface (export/materialx.hpp)
/// The maps are brought into canonical form first (brdf/canonical_maps.hpp); the conversions and
/// their measured error are in export/conversion.hpp and export/fidelity.hpp.
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>

#include "anisocap/export/blender.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/export/gltf.hpp"
#include "anisocap/export/materialx.hpp"
#include "anisocap/export/mitsuba.hpp"

namespace anisocap::exports {

/// The export formats.
enum class export_format { gltf, mitsuba, blender, mtlx };

/// The format named `name` (gltf, mitsuba, blender, mtlx), or nothing.
inline std::optional<export_format> export_format_from_name(std::string_view name) {
  if (name == "gltf") return export_format::gltf;
  if (name == "mitsuba") return export_format::mitsuba;
  if (name == "blender") return export_format::blender;
  if (name == "mtlx") return export_format::mtlx;
  return std::nullopt;
}

/// Options of every export.
struct export_options {
  double width = 0;  ///< physical width of the material in metres for glTF (0: longest side 1)
  conversion_options conversion;
};

/// Exports `maps` in `format` to `out`: a .gltf file for gltf, a folder for the others.
inline void export_material(material_maps maps, export_format format, const std::filesystem::path& out, const export_options& options = {}) {
  canonicalise(maps);
  switch (format) {
    case export_format::gltf: return write_gltf(maps, out, {options.width, options.conversion});
    case export_format::mitsuba: return write_mitsuba(maps, out);
    case export_format::blender: return write_blender(maps, out, options.conversion);
    case export_format::mtlx: return write_materialx(maps, out, options.conversion);
  }
}

}  // namespace anisocap::exports
