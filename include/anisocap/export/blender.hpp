#pragma once
/// @file
/// Blender export: a folder with `material.py` and float EXR textures. Run in Blender 4.x
/// (`blender --python material.py`, or the Text Editor's Run Script) it adds a plane of the
/// material's size with a material whose Principled BSDF (GGX) reads, per texel (exports::to_blender):
/// Base Color, Roughness, Anisotropic, Anisotropic Rotation (nearest-texel lookup, since the value
/// wraps from 1 to 0), IOR, Specular Tint, Normal (Normal Map node, tangent space of the UV map)
/// and Tangent (Tangent node from the UV map). Colour textures are linear EXRs, data textures are
/// marked Non-Color. The plane's UVs put the first texture row at the top (v = 1), +u along +x.
#include <filesystem>
#include <string>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/textures.hpp"

namespace anisocap::exports {

/// The Blender script (textures named as write_blender writes them).
inline std::string blender_script(int width, int height) {
  const double n = std::max(width, height);
  return R"PY(# Built by `anisocap export --format blender`: the captured material as a Principled BSDF
# (Blender 4.x). Run with `blender --python material.py` or from Blender's Text Editor; the textures
# are read from this script's folder. Conversion and its measured error: the anisocap README, "Exports".
import os

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
SIZE_X, SIZE_Y = )PY" + std::to_string(width / n) + ", " + std::to_string(height / n) + R"PY(  # scene units (longest side 1)


def build_material(name="anisocap material"):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    nodes = material.node_tree.nodes
    links = material.node_tree.links
    nodes.clear()

    def link(from_node, from_socket, to_node, to_socket):
        links.new(from_node.outputs[from_socket], to_node.inputs[to_socket])

    output = nodes.new("ShaderNodeOutputMaterial")
    principled = nodes.new("ShaderNodeBsdfPrincipled")
    principled.distribution = "GGX"
    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = "UVMap"

    def texture(file, data, interpolation="Linear"):
        node = nodes.new("ShaderNodeTexImage")
        node.image = bpy.data.images.load(os.path.join(HERE, file), check_existing=True)
        if data:
            node.image.colorspace_settings.name = "Non-Color"
        node.interpolation = interpolation
        node.extension = "EXTEND"
        link(uv, "UV", node, "Vector")
        return node

    link(texture("base_color.exr", False), "Color", principled, "Base Color")
    link(texture("roughness.exr", True), "Color", principled, "Roughness")
    link(texture("anisotropic.exr", True), "Color", principled, "Anisotropic")
    link(texture("anisotropic_rotation.exr", True, "Closest"), "Color", principled, "Anisotropic Rotation")
    link(texture("ior.exr", True), "Color", principled, "IOR")
    link(texture("specular_tint.exr", False), "Color", principled, "Specular Tint")
    normal_map = nodes.new("ShaderNodeNormalMap")
    normal_map.space = "TANGENT"
    normal_map.uv_map = "UVMap"
    link(texture("normal.exr", True), "Color", normal_map, "Color")
    link(normal_map, "Normal", principled, "Normal")
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.uv_map = "UVMap"
    link(tangent, "Tangent", principled, "Tangent")
    link(principled, "BSDF", output, "Surface")
    return material


def build_plane(material):
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    plane.name = "anisocap sample"
    plane.scale = (SIZE_X, SIZE_Y, 1.0)
    plane.data.materials.append(material)
    return plane


if __name__ == "__main__":
    build_plane(build_material())
)PY";
}

/// Writes the Blender script and its textures for `maps` into folder `dir` (staged, then renamed together).
inline void write_blender(const material_maps& maps, const std::filesystem::path& dir, const conversion_options& options = {}) {
  if (maps.texel_count() == 0) throw io_error(dir, "cannot export an empty map set");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir, ec)) throw io_error(dir, "cannot create the export folder");
  const auto t = convert_texels(maps, [&](const ward_parameters<float>& p) { return to_blender(p, options); });
  file_transaction files;
  auto grey = [&](const char* name, auto value) { write_exr(float_texture(maps, 3, [&](std::size_t i, int) { return value(t[i]); }), dir / name, files); };
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) { return t[i].base_color[c]; }), dir / "base_color.exr", files);
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) { return t[i].specular_tint[c]; }), dir / "specular_tint.exr", files);
  grey("roughness.exr", [](const blender_texel& b) { return b.roughness; });
  grey("anisotropic.exr", [](const blender_texel& b) { return b.anisotropic; });
  grey("anisotropic_rotation.exr", [](const blender_texel& b) { return b.anisotropic_rotation; });
  grey("ior.exr", [](const blender_texel& b) { return b.ior; });
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) {
              const double nz = std::sqrt(std::max(0.0, 1 - t[i].nx * t[i].nx - t[i].ny * t[i].ny));
              return 0.5 + 0.5 * (c == 0 ? t[i].nx : c == 1 ? t[i].ny : nz);
            }),
            dir / "normal.exr", files);
  files.stage(dir / "material.py", blender_script(maps.width(), maps.height()));
  files.commit();
}

}  // namespace anisocap::exports
