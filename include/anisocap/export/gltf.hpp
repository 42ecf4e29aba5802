#pragma once
/// @file
/// glTF 2.0 export: one `.gltf` file with everything embedded (buffers and PNG textures as base64
/// data URIs), a quad of the material's size in scene units (longest side 1; `gltf_options::width`
/// gives a physical size in metres) in the XY plane facing +Z, UV (0,0) at the top-left texel, tangent
/// +X. The material is metallic-roughness (metallic 0) with
///   - KHR_materials_anisotropy where it fits the maps better than isotropic GGX
///     (`gltf_uses_anisotropy`, export/fidelity.hpp): anisotropyTexture RG = direction (cos, sin)
///     of the wide axis in the tangent frame remapped from [-1, 1] to [0, 1], B = strength (linear);
///   - KHR_materials_specular: specularTexture A = weight w (linear), specularColorTexture RGB =
///     F0 colour (sRGB) with specularColorFactor 25 = 1 / 0.04 (0.04: F0 of the default IOR 1.5);
///   - baseColorTexture (sRGB), metallicRoughnessTexture G = roughness (linear), normalTexture (linear;
///     left out where every normal is flat, which 8 bits cannot encode exactly).
/// The per-texel values come from exports::to_gltf (export/conversion.hpp).
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/textures.hpp"
#include "anisocap/export/viewer.hpp"

namespace anisocap::exports {

/// Options of the glTF export.
struct gltf_options {
  double width = 0;  ///< physical width of the material in metres (0: longest side 1)
  conversion_options conversion;
};

namespace gltf_detail {

using nlohmann::json;

/// The glTF textures of a map set, 8 bits per channel (see the file comment).
struct textures {
  texture8 base, metal_rough, normal, anisotropy, specular;
  /// Every normal is flat: no normal texture (a flat normal has no 8-bit code: 128 decodes to
  /// 0.0039, a 0.3 degree tilt).
  bool flat = true;
};

/// The textures of `maps` converted texel by texel (exports::to_gltf).
inline textures make_textures(const material_maps& maps, const gltf_options& options, bool anisotropic) {
  const int w = maps.width(), h = maps.height();
  const auto texels = convert_texels(maps, [&](const ward_parameters<float>& p) { return to_gltf(p, options.conversion, anisotropic); });
  textures t{texture8(w, h, 3), texture8(w, h, 3), texture8(w, h, 3), texture8(w, h, 3), texture8(w, h, 4), true};
  t.flat = std::all_of(texels.begin(), texels.end(), [](const gltf_texel& g) { return g.nx == 0 && g.ny == 0; });
  for (std::size_t i = 0; i < maps.texel_count(); ++i) {
    const gltf_texel& g = texels[i];
    for (int c = 0; c < 3; ++c) t.base.set(i, c, g.base_color[c], true), t.specular.set(i, c, g.specular_color[c], true);
    t.specular.set(i, 3, g.specular);
    t.metal_rough.set(i, 0, 1.0), t.metal_rough.set(i, 1, g.roughness), t.metal_rough.set(i, 2, 0.0);
    const double nz = std::sqrt(std::max(0.0, 1 - g.nx * g.nx - g.ny * g.ny));
    t.normal.set(i, 0, 0.5 + 0.5 * g.nx), t.normal.set(i, 1, 0.5 + 0.5 * g.ny), t.normal.set(i, 2, 0.5 + 0.5 * nz);
    t.anisotropy.set(i, 0, 0.5 + 0.5 * std::cos(g.anisotropy_angle)), t.anisotropy.set(i, 1, 0.5 + 0.5 * std::sin(g.anisotropy_angle));
    t.anisotropy.set(i, 2, g.anisotropy_strength);
  }
  return t;
}

/// The quad's geometry: one buffer of 4 vertices (position, normal, tangent, uv) and 6 indices,
/// its buffer views and accessors.
struct quad {
  std::vector<unsigned char> buffer;
  json views = json::array(), accessors = json::array();
  std::size_t position = 0, normal = 0, tangent = 0, uv = 0, indices = 0;  ///< accessor indices
};

/// The quad of a width x height material, `scale` scene units per texel, centred in the XY plane.
inline quad make_quad(int w, int h, double scale) {
  quad q;
  const float hx = float(0.5 * w * scale), hy = float(0.5 * h * scale);
  const float positions[12] = {-hx, -hy, 0, hx, -hy, 0, hx, hy, 0, -hx, hy, 0};
  const float normals[12] = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1};
  const float tangents[16] = {1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1};
  const float uvs[8] = {0, 1, 1, 1, 1, 0, 0, 0};
  const std::uint16_t indices[6] = {0, 1, 2, 0, 2, 3};
  auto append = [&](const void* data, std::size_t size) {
    const std::size_t offset = q.buffer.size();
    q.buffer.resize(offset + size);
    std::memcpy(q.buffer.data() + offset, data, size);
    return offset;
  };
  auto attribute = [&](const float* data, int count, int components, const char* type, bool bounds) {
    const std::size_t offset = append(data, sizeof(float) * count * components);
    q.views.push_back({{"buffer", 0}, {"byteOffset", offset}, {"byteLength", sizeof(float) * count * components}, {"target", 34962}});
    json a = {{"bufferView", q.views.size() - 1}, {"componentType", 5126}, {"count", count}, {"type", type}};
    if (bounds) a["min"] = {-hx, -hy, 0.0}, a["max"] = {hx, hy, 0.0};
    q.accessors.push_back(a);
    return q.accessors.size() - 1;
  };
  q.position = attribute(positions, 4, 3, "VEC3", true);
  q.normal = attribute(normals, 4, 3, "VEC3", false);
  q.tangent = attribute(tangents, 4, 4, "VEC4", false);
  q.uv = attribute(uvs, 4, 2, "VEC2", false);
  const std::size_t index_offset = append(indices, sizeof indices);
  q.views.push_back({{"buffer", 0}, {"byteOffset", index_offset}, {"byteLength", sizeof indices}, {"target", 34963}});
  q.accessors.push_back({{"bufferView", q.views.size() - 1}, {"componentType", 5123}, {"count", 6}, {"type", "SCALAR"}});
  q.indices = q.accessors.size() - 1;
  while (q.buffer.size() % 4) q.buffer.push_back(0);
  return q;
}

/// The material (its textures added to `images` and `textures` as embedded PNGs).
inline json make_material(const gltf_detail::textures& t, bool anisotropic, json& images, json& textures) {
  auto add_texture = [&](const texture8& texture, const char* name) {
    const auto png = png_bytes(texture, name);
    images.push_back({{"name", name}, {"mimeType", "image/png"}, {"uri", "data:image/png;base64," + anisocap::detail::base64(png.data(), png.size())}});
    textures.push_back({{"sampler", 0}, {"source", images.size() - 1}});
    return textures.size() - 1;
  };
  const auto base_texture = add_texture(t.base, "base_color");
  const auto metal_rough_texture = add_texture(t.metal_rough, "metallic_roughness");
  const auto normal_texture = t.flat ? 0 : add_texture(t.normal, "normal");
  const auto anisotropy_texture = anisotropic ? add_texture(t.anisotropy, "anisotropy") : 0;
  const auto specular_texture = add_texture(t.specular, "specular");
  json material = {
      {"name", "anisocap material"},
      {"pbrMetallicRoughness",
       {{"baseColorTexture", {{"index", base_texture}}},
        {"metallicFactor", 0.0},
        {"roughnessFactor", 1.0},
        {"metallicRoughnessTexture", {{"index", metal_rough_texture}}}}},
      {"extensions",
       {{"KHR_materials_specular",
         {{"specularFactor", 1.0},
          {"specularTexture", {{"index", specular_texture}}},
          {"specularColorFactor", {25.0, 25.0, 25.0}},
          {"specularColorTexture", {{"index", specular_texture}}}}}}}};
  if (!t.flat) material["normalTexture"] = {{"index", normal_texture}};
  if (anisotropic)
    material["extensions"]["KHR_materials_anisotropy"] = {
        {"anisotropyStrength", 1.0}, {"anisotropyRotation", 0.0}, {"anisotropyTexture", {{"index", anisotropy_texture}}}};
  return material;
}

}  // namespace gltf_detail

/// The glTF document for `maps` (canonical form expected), as JSON text.
inline std::string gltf_document(const material_maps& maps, const gltf_options& options = {}) {
  using nlohmann::json;
  const int w = maps.width(), h = maps.height();
  const bool anisotropic = gltf_uses_anisotropy(maps, options.conversion);
  const gltf_detail::textures t = gltf_detail::make_textures(maps, options, anisotropic);
  const gltf_detail::quad q = gltf_detail::make_quad(w, h, options.width > 0 ? options.width / w : 1.0 / std::max(w, h));
  json images = json::array(), textures = json::array();
  const json material = gltf_detail::make_material(t, anisotropic, images, textures);
  json extensions_used = {"KHR_materials_specular"};
  if (anisotropic) extensions_used.push_back("KHR_materials_anisotropy");
  json doc = {
      {"asset", {{"version", "2.0"}, {"generator", "anisocap export"}}},
      {"extensionsUsed", extensions_used},
      {"scene", 0},
      {"scenes", {{{"nodes", {0}}}}},
      {"nodes", {{{"name", "material sample"}, {"mesh", 0}}}},
      {"meshes",
       {{{"name", "quad"},
         {"primitives",
          {{{"attributes", {{"POSITION", q.position}, {"NORMAL", q.normal}, {"TANGENT", q.tangent}, {"TEXCOORD_0", q.uv}}},
            {"indices", q.indices},
            {"material", 0}}}}}}},
      {"materials", {material}},
      {"samplers", {{{"magFilter", 9729}, {"minFilter", 9987}, {"wrapS", 33071}, {"wrapT", 33071}}}},
      {"images", images},
      {"textures", textures},
      {"accessors", q.accessors},
      {"bufferViews", q.views},
      {"buffers", {{{"byteLength", q.buffer.size()}, {"uri", "data:application/octet-stream;base64," + anisocap::detail::base64(q.buffer.data(), q.buffer.size())}}}}};
  return doc.dump(1);
}

/// Writes the glTF asset of `maps` to `path` (a .gltf file) atomically.
inline void write_gltf(const material_maps& maps, const std::filesystem::path& path, const gltf_options& options = {}) {
  if (maps.texel_count() == 0) throw io_error(path, "cannot export an empty map set");
  write_file_atomically(path, gltf_document(maps, options));
}

}  // namespace anisocap::exports
