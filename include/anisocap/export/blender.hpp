#pragma once
/// @file
/// Blender export: a folder with `material.py` and float EXR textures. Run in Blender 3.x or 4.x,
/// from the command line (`blender --python material.py`, `blender -b --python material.py`) or
/// from the Text Editor's Run Script, it adds a plane of the material's size with a material whose
/// Principled BSDF (GGX) reads, per texel: Base Color, Roughness, Anisotropic, Anisotropic Rotation
/// (nearest-texel lookup, since the value wraps from 1 to 0), Normal (Normal Map node, tangent
/// space of the UV map) and Tangent (Tangent node from the UV map), and the Fresnel inputs whose
/// meaning changed in Blender 4.0: IOR and a colour Specular Tint in 4.x (exports::to_blender),
/// Specular, a number Specular Tint, Metallic and an undarkened base colour in 3.x
/// (exports::to_blender3, export/blender_fit.hpp). The script picks the set by bpy.app.version.
/// Colour textures are linear EXRs, data textures are marked Non-Color. The plane's UVs put the
/// first texture row at the top (v = 1), +u along +x.
///
/// The textures are looked up in the export folder's absolute path, written into the script, then
/// beside the script (when it is run as a file), then beside the open .blend: a script run from the
/// Text Editor has a `__file__` inside the .blend. On a scene that still holds Blender's factory
/// cube (a mesh "Cube" of 8 vertices at the origin) the cube is removed, since the plane would lie
/// inside it; the script adds a camera looking down at 45 degrees and a point light ("anisocap
/// camera", "anisocap light"), makes that camera the scene's, and leaves everything else as it is.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/blender_fit.hpp"
#include "anisocap/export/textures.hpp"

namespace anisocap::exports {

namespace detail {
/// `text` as a Python string literal (double quotes, backslashes and control characters escaped).
inline std::string python_string(const std::string& text) {
  std::string out = "\"";
  for (const unsigned char c : text) {
    if (c == '\\' || c == '"') out += '\\', out += char(c);
    else if (c < 0x20) {
      char buffer[8];
      std::snprintf(buffer, sizeof buffer, "\\x%02x", c);
      out += buffer;
    } else out += char(c);
  }
  return out + "\"";
}
}  // namespace detail

namespace detail {
/// The opening of the Blender script, before the lines blender_script fills in.
inline constexpr std::string_view blender_script_head = R"PY(# Built by `anisocap export --format blender`: the captured material as a Principled BSDF for
# Blender 3.x and 4.x (the Fresnel inputs are set per version). Run it with
# `blender --python material.py`, `blender -b --python material.py`, or from Blender's Text Editor
# (Run Script). Conversion and its measured error: the anisocap README, "Exports".
import os

import bpy

# The export folder, where the textures are; if it has moved, the script looks beside itself and
# beside the open .blend file. Edit this line to point elsewhere.
)PY";
/// The rest of the Blender script, after its TEXTURES and SIZE_X, SIZE_Y lines: the material's
/// nodes (per Blender version), the plane and the scene.
inline constexpr std::string_view blender_script_body = R"PY(# False: add only the plane and its material (no camera, light or removal of the factory cube).
SETUP_SCENE = True


def texture_folder():
    """The first folder holding the textures: TEXTURES, this script's, the .blend's."""
    candidates = [TEXTURES]
    script = globals().get("__file__")
    if script:
        candidates.append(os.path.dirname(os.path.abspath(script)))
    if bpy.data.filepath:
        candidates.append(os.path.dirname(bpy.data.filepath))
    for folder in candidates:
        if folder and os.path.isfile(os.path.join(folder, "base_color.exr")):
            return folder
    raise RuntimeError("anisocap material.py: no base_color.exr in " + ", ".join(repr(c) for c in candidates if c)
                       + ": set TEXTURES at the top of the script to the export folder")


def build_material(name="anisocap material", folder=None):
    folder = folder or texture_folder()
    blender4 = bpy.app.version >= (4, 0, 0)
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
        node.image = bpy.data.images.load(os.path.join(folder, file), check_existing=True)
        if data:
            node.image.colorspace_settings.name = "Non-Color"
        node.interpolation = interpolation
        node.extension = "EXTEND"
        link(uv, "UV", node, "Vector")
        return node

    link(texture("roughness.exr", True), "Color", principled, "Roughness")
    link(texture("anisotropic.exr", True), "Color", principled, "Anisotropic")
    link(texture("anisotropic_rotation.exr", True, "Closest"), "Color", principled, "Anisotropic Rotation")
    if blender4:
        # 4.x: F0 from the IOR, tinted per channel; the base colour is darkened under the specular layer.
        link(texture("base_color.exr", False), "Color", principled, "Base Color")
        link(texture("ior.exr", True), "Color", principled, "IOR")
        link(texture("specular_tint.exr", False), "Color", principled, "Specular Tint")
    else:
        # 3.x: IOR is for transmission only; F0 = 0.08 Specular, Specular Tint is a number, Metallic
        # takes the specular colour from the base colour, and the base colour is not darkened.
        link(texture("base_color_3x.exr", False), "Color", principled, "Base Color")
        link(texture("specular_3x.exr", True), "Color", principled, "Specular")
        link(texture("specular_tint_3x.exr", True), "Color", principled, "Specular Tint")
        link(texture("metallic_3x.exr", True), "Color", principled, "Metallic")
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


def remove_factory_cube():
    """Removes Blender's factory-startup cube, inside which the plane would lie."""
    cube = bpy.data.objects.get("Cube")
    if cube is not None and cube.type == "MESH" and len(cube.data.vertices) == 8 and cube.location.length < 1e-6:
        bpy.data.objects.remove(cube, do_unlink=True)


def add_camera_and_light(plane):
    """A camera 45 degrees above the plane looking at it, and a point light above, as the scene's."""
    import math
    size = max(SIZE_X, SIZE_Y)
    camera = bpy.data.objects.new("anisocap camera", bpy.data.cameras.new("anisocap camera"))
    camera.location = (0.0, -1.6 * size, 1.6 * size)
    camera.rotation_euler = (math.radians(45), 0.0, 0.0)
    light_data = bpy.data.lights.new("anisocap light", "POINT")
    light_data.energy = 60.0 * size * size  # watts
    light = bpy.data.objects.new("anisocap light", light_data)
    light.location = (0.4 * size, -0.6 * size, 1.2 * size)
    for item in (camera, light):
        plane.users_collection[0].objects.link(item)
    bpy.context.scene.camera = camera


def build_plane(material):
    if SETUP_SCENE:
        remove_factory_cube()
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.0, 0.0, 0.0))
    plane = bpy.context.active_object
    plane.name = "anisocap sample"
    plane.scale = (SIZE_X, SIZE_Y, 1.0)
    plane.data.materials.append(material)
    if SETUP_SCENE:
        add_camera_and_light(plane)
    return plane


if __name__ == "__main__":
    build_plane(build_material())
)PY";
}  // namespace detail

/// The Blender script (textures named as write_blender writes them), reading its textures first from
/// `texture_folder` (an absolute path; empty: only beside the script or the .blend).
inline std::string blender_script(int width, int height, const std::filesystem::path& texture_folder = {}) {
  const double n = std::max(width, height);
  return std::string(detail::blender_script_head) + "TEXTURES = " + detail::python_string(texture_folder.string()) + "\nSIZE_X, SIZE_Y = " +
         std::to_string(width / n) + ", " + std::to_string(height / n) + "  # scene units (longest side 1)\n" +
         std::string(detail::blender_script_body);
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
  // Blender 3.x inputs (export/blender_fit.hpp), grey textures like the 4.x data textures.
  std::vector<blender3_texel> t3(t.size());
  for (std::size_t i = 0; i < t.size(); ++i) t3[i] = to_blender3(texel_parameters(maps, i), f0_of_ior(t[i].ior));
  auto grey3 = [&](const char* name, auto value) { write_exr(float_texture(maps, 3, [&](std::size_t i, int) { return value(t3[i]); }), dir / name, files); };
  write_exr(float_texture(maps, 3, [&](std::size_t i, int c) { return t3[i].base_color[c]; }), dir / "base_color_3x.exr", files);
  grey3("specular_3x.exr", [](const blender3_texel& b) { return b.specular; });
  grey3("specular_tint_3x.exr", [](const blender3_texel& b) { return b.specular_tint; });
  grey3("metallic_3x.exr", [](const blender3_texel& b) { return b.metallic; });
  std::error_code absolute_error;
  const std::filesystem::path folder = std::filesystem::absolute(dir, absolute_error).lexically_normal();
  files.stage(dir / "material.py", blender_script(maps.width(), maps.height(), absolute_error ? std::filesystem::path{} : folder));
  files.commit();
}

}  // namespace anisocap::exports
