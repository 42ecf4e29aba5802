#pragma once
/// @file
/// MaterialX export: a folder with `material.mtlx` (MaterialX 1.38, Autodesk Standard Surface)
/// and float EXR textures, per texel from exports::to_standard_surface: base_color,
/// specular (weight), specular_color, specular_roughness, specular_anisotropy, specular_rotation
/// (in turns; nearest-texel lookup since it wraps from 1 to 0), specular_IOR and the tangent-space
/// normal through a `normalmap` node. Texture rows follow MaterialX's convention: the file's first
/// row at v = 1.
#include <filesystem>
#include <string>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/textures.hpp"

namespace anisocap::exports {

/// The MaterialX document (textures named as write_materialx writes them).
inline std::string materialx_document() {
  struct bound {
    const char* input;
    const char* type;
    const char* file;
    const char* filter;
  };
  static constexpr bound inputs[] = {
      {"base_color", "color3", "base_color.exr", "linear"},
      {"specular", "float", "specular.exr", "linear"},
      {"specular_color", "color3", "specular_color.exr", "linear"},
      {"specular_roughness", "float", "specular_roughness.exr", "linear"},
      {"specular_anisotropy", "float", "specular_anisotropy.exr", "linear"},
      {"specular_rotation", "float", "specular_rotation.exr", "closest"},
      {"specular_IOR", "float", "specular_ior.exr", "linear"},
  };
  std::string images, shader;
  for (const bound& b : inputs) {
    images += std::string("  <image name=\"") + b.input + "_image\" type=\"" + b.type + "\">\n    <input name=\"file\" type=\"filename\" value=\"" +
              b.file + "\" />\n    <input name=\"filtertype\" type=\"string\" value=\"" + b.filter + "\" />\n  </image>\n";
    shader += std::string("    <input name=\"") + b.input + "\" type=\"" + b.type + "\" nodename=\"" + b.input + "_image\" />\n";
  }
  return "<?xml version=\"1.0\"?>\n"
         "<!-- anisocap export: the captured material as Autodesk Standard Surface. Conversion and its\n"
         "     measured error: the anisocap README, \"Exports\". -->\n"
         "<materialx version=\"1.38\" colorspace=\"lin_rec709\">\n" +
         images +
         "  <image name=\"normal_image\" type=\"vector3\">\n"
         "    <input name=\"file\" type=\"filename\" value=\"normal.exr\" />\n"
         "  </image>\n"
         "  <normalmap name=\"normal_map\" type=\"vector3\">\n"
         "    <input name=\"in\" type=\"vector3\" nodename=\"normal_image\" />\n"
         "  </normalmap>\n"
         "  <standard_surface name=\"anisocap_surface\" type=\"surfaceshader\">\n"
         "    <input name=\"base\" type=\"float\" value=\"1\" />\n"
         "    <input name=\"metalness\" type=\"float\" value=\"0\" />\n" +
         shader +
         "    <input name=\"normal\" type=\"vector3\" nodename=\"normal_map\" />\n"
         "  </standard_surface>\n"
         "  <surfacematerial name=\"anisocap_material\" type=\"material\">\n"
         "    <input name=\"surfaceshader\" type=\"surfaceshader\" nodename=\"anisocap_surface\" />\n"
         "  </surfacematerial>\n"
         "</materialx>\n";
}

/// Writes the MaterialX document and its textures for `maps` into folder `dir` (staged, then renamed together).
inline void write_materialx(const material_maps& maps, const std::filesystem::path& dir, const conversion_options& options = {}) {
  if (maps.texel_count() == 0) throw io_error(dir, "cannot export an empty map set");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir, ec)) throw io_error(dir, "cannot create the export folder");
  const auto t = convert_texels(maps, [&](const ward_parameters<float>& p) { return to_standard_surface(p, options); });
  file_transaction files;
  auto grey = [&](const char* name, auto value) { write_exr(float_texture(maps, 3, [&](std::size_t i, int) { return value(t[i]); }), dir / name, files); };
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) { return t[i].base_color[c]; }), dir / "base_color.exr", files);
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) { return t[i].specular_color[c]; }), dir / "specular_color.exr", files);
  grey("specular.exr", [](const standard_surface_texel& s) { return s.specular; });
  grey("specular_roughness.exr", [](const standard_surface_texel& s) { return s.specular_roughness; });
  grey("specular_anisotropy.exr", [](const standard_surface_texel& s) { return s.specular_anisotropy; });
  grey("specular_rotation.exr", [](const standard_surface_texel& s) { return s.specular_rotation; });
  grey("specular_ior.exr", [](const standard_surface_texel& s) { return s.specular_ior; });
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) {
              const double nz = std::sqrt(std::max(0.0, 1 - t[i].nx * t[i].nx - t[i].ny * t[i].ny));
              return 0.5 + 0.5 * (c == 0 ? t[i].nx : c == 1 ? t[i].ny : nz);
            }),
            dir / "normal.exr", files);
  files.stage(dir / "material.mtlx", materialx_document());
  files.commit();
}

}  // namespace anisocap::exports
