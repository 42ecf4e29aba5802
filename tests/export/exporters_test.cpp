// The exporters' files: the glTF document's structure and its anisotropy texture's channel layout,
// the Mitsuba scene and its textures' row order, the Blender and MaterialX folders, the viewer
// page, and clean failures. The Khronos validator, the Blender script's node tree and the MaterialX
// document are checked further by the ctests gltf_validator and export_scripts.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <numbers>
#include <sstream>

#include <nlohmann/json.hpp>

#include "../data/test_folder.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/export/export.hpp"
#include "anisocap/export/viewer.hpp"

using namespace anisocap;
using namespace anisocap::exports;

namespace {

std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<unsigned char> from_base64(std::string_view s) {
  std::vector<unsigned char> out;
  unsigned value = 0;
  int bits = 0;
  for (char c : s) {
    int d = c >= 'A' && c <= 'Z' ? c - 'A' : c >= 'a' && c <= 'z' ? c - 'a' + 26 : c >= '0' && c <= '9' ? c - '0' + 52 : c == '+' ? 62 : c == '/' ? 63 : -1;
    if (d < 0) continue;
    value = value << 6 | unsigned(d), bits += 6;
    if (bits >= 8) bits -= 8, out.push_back(static_cast<unsigned char>(value >> bits & 255));
  }
  return out;
}

material_maps test_maps() {
  material_maps m = generate_material(19, 24, 16);
  // Swapped lobes in some texels: the export must canonicalise them.
  for (std::size_t i = 0; i < m.texel_count(); i += 3) {
    std::swap(m.plane(lobe_x)[i], m.plane(lobe_y)[i]);
    m.plane(rotation)[i] += std::numbers::pi_v<float> / 2;
  }
  return m;
}

}  // namespace

TEST_CASE("base64 round trip") {
  const unsigned char data[] = {0, 1, 2, 250, 251, 252, 253};
  for (std::size_t n = 0; n <= sizeof data; ++n) {
    const auto decoded = from_base64(anisocap::detail::base64(data, n));
    REQUIRE(decoded.size() == n);
    for (std::size_t i = 0; i < n; ++i) CHECK(decoded[i] == data[i]);
  }
}

TEST_CASE("glTF export: structure, extensions and the anisotropy texture's channel layout") {
  testing::test_folder dir;
  const material_maps maps = test_maps();
  export_options with_anisotropy;
  with_anisotropy.conversion.gltf_anisotropy_use = gltf_anisotropy::on;
  export_material(maps, export_format::gltf, dir / "m.gltf", with_anisotropy);
  const auto doc = nlohmann::json::parse(read_text(dir / "m.gltf"));
  CHECK(doc["asset"]["version"] == "2.0");
  const auto& material = doc["materials"][0];
  const auto& anisotropy = material["extensions"]["KHR_materials_anisotropy"];
  CHECK(material["extensions"].contains("KHR_materials_specular"));
  CHECK(doc["meshes"][0]["primitives"][0]["attributes"].contains("TANGENT"));
  // Decode the anisotropy texture and compare with the canonical maps' rotation and the strength.
  const int image_index = doc["textures"][anisotropy["anisotropyTexture"]["index"].get<int>()]["source"];
  const std::string uri = doc["images"][image_index]["uri"];
  const auto png = from_base64(uri.substr(uri.find(',') + 1));
  int w = 0, h = 0, channels = 0;
  unsigned char* pixels = stbi_load_from_memory(png.data(), int(png.size()), &w, &h, &channels, 3);
  REQUIRE(pixels);
  REQUIRE(w == maps.width());
  REQUIRE(h == maps.height());
  material_maps canonical = maps;
  canonicalise(canonical);
  for (std::size_t i = 0; i < canonical.texel_count(); ++i) {
    const gltf_texel g = to_gltf(texel_parameters(canonical, i), with_anisotropy.conversion, true);
    const double dx = pixels[3 * i] / 255.0 * 2 - 1, dy = pixels[3 * i + 1] / 255.0 * 2 - 1;
    CHECK(std::abs(dx - std::cos(canonical.plane(rotation)[i])) < 1.0 / 255 + 1e-6);
    CHECK(std::abs(dy - std::sin(canonical.plane(rotation)[i])) < 1.0 / 255 + 1e-6);
    CHECK(std::abs(pixels[3 * i + 2] / 255.0 - g.anisotropy_strength) < 0.5 / 255 + 1e-6);
  }
  stbi_image_free(pixels);
}

TEST_CASE("glTF export: KHR_materials_anisotropy where it fits better, no normal texture for flat normals") {
  testing::test_folder dir;
  material_maps maps = test_maps();
  canonicalise(maps);
  auto exported = [&](const material_maps& m, gltf_anisotropy use, const char* name) {
    export_options o;
    o.conversion.gltf_anisotropy_use = use;
    export_material(m, export_format::gltf, dir / name, o);
    return nlohmann::json::parse(read_text(dir / name));
  };
  const auto off = exported(maps, gltf_anisotropy::off, "off.gltf");
  CHECK_FALSE(off["materials"][0]["extensions"].contains("KHR_materials_anisotropy"));
  CHECK(off["extensionsUsed"].size() == 1);
  CHECK(off["images"].size() == 4);  // base colour, metallic-roughness, normal, specular
  const auto on = exported(maps, gltf_anisotropy::on, "on.gltf");
  CHECK(on["materials"][0]["extensions"].contains("KHR_materials_anisotropy"));
  CHECK(on["extensionsUsed"].size() == 2);
  // Automatic: the variant whose glTF model has the lower error on the maps.
  const int stride = std::max(1, std::max(maps.width(), maps.height()) / 16);
  const bool anisotropic_better = gltf_error(maps, true, {}, stride) <= gltf_error(maps, false, {}, stride);
  const auto automatic = exported(maps, gltf_anisotropy::automatic, "auto.gltf");
  CHECK(automatic["materials"][0]["extensions"].contains("KHR_materials_anisotropy") == anisotropic_better);
  // A lobe stretched along +x on flat normals needs the extension; on strongly tilted normals the
  // extension's tangent-plane direction cannot follow and the isotropic lobe about the normal wins.
  material_maps stretched = maps;
  for (std::size_t i = 0; i < stretched.texel_count(); ++i) {
    stretched.plane(lobe_x)[i] = 0.4f, stretched.plane(lobe_y)[i] = 0.08f, stretched.plane(rotation)[i] = 0.0f;
    stretched.plane(normal_x)[i] = stretched.plane(normal_y)[i] = 0.0f;
  }
  CHECK(gltf_uses_anisotropy(stretched, {}));
  const auto flat = exported(stretched, gltf_anisotropy::automatic, "flat.gltf");
  CHECK_FALSE(flat["materials"][0].contains("normalTexture"));
  material_maps tilted = stretched;
  for (std::size_t i = 0; i < tilted.texel_count(); ++i) tilted.plane(normal_y)[i] = (i % 2 ? 0.3f : -0.3f);
  CHECK_FALSE(gltf_uses_anisotropy(tilted, {}));
  CHECK(exported(tilted, gltf_anisotropy::automatic, "tilted.gltf")["materials"][0].contains("normalTexture"));
}

TEST_CASE("Mitsuba export: ward balanced with textured alphas, rows bottom first") {
  testing::test_folder dir;
  material_maps maps = test_maps();
  export_material(maps, export_format::mitsuba, dir / "mitsuba");
  const std::string xml = read_text(dir / "mitsuba" / "scene.xml");
  CHECK(xml.find("type=\"ward\"") != std::string::npos);
  CHECK(xml.find("value=\"balanced\"") != std::string::npos);
  CHECK(xml.find("name=\"alphaU\"") != std::string::npos);
  const image alpha_u = read_exr(dir / "mitsuba" / "alpha_u.exr");
  canonicalise(maps);
  const int x = 5, y = 2;
  const mitsuba_texel m = to_mitsuba(texel_parameters(maps, std::size_t(y) * maps.width() + x));
  CHECK(alpha_u.at(0, x, maps.height() - 1 - y) == doctest::Approx(m.alpha_u));
}

TEST_CASE("Blender and MaterialX exports write their script or document with every texture") {
  testing::test_folder dir;
  const material_maps maps = test_maps();
  export_material(maps, export_format::blender, dir / "blender");
  export_material(maps, export_format::mtlx, dir / "mtlx");
  const std::string script = read_text(dir / "blender" / "material.py");
  for (const char* f : {"base_color.exr", "roughness.exr", "anisotropic.exr", "anisotropic_rotation.exr", "ior.exr", "specular_tint.exr", "normal.exr"}) {
    CAPTURE(f);
    CHECK(std::filesystem::exists(dir / "blender" / f));
    CHECK(script.find(f) != std::string::npos);
  }
  const std::string mtlx = read_text(dir / "mtlx" / "material.mtlx");
  for (const char* f : {"base_color.exr", "specular.exr", "specular_color.exr", "specular_roughness.exr", "specular_anisotropy.exr",
                        "specular_rotation.exr", "specular_ior.exr", "normal.exr"}) {
    CAPTURE(f);
    CHECK(std::filesystem::exists(dir / "mtlx" / f));
    CHECK(mtlx.find(f) != std::string::npos);
  }
  // Textures hold the converted values: Standard Surface's rotation in turns, in [0, 1).
  const image rotation_turns = read_exr(dir / "mtlx" / "specular_rotation.exr");
  for (std::size_t i = 0; i < rotation_turns.pixel_count(); ++i) {
    REQUIRE(rotation_turns.plane(0)[i] >= 0.0f);
    REQUIRE(rotation_turns.plane(0)[i] < 1.0f);
  }
}

TEST_CASE("exports fail cleanly on an impossible output, leaving nothing behind") {
  testing::test_folder dir;
  const material_maps maps = test_maps();
  { std::ofstream(dir / "file") << "x"; }
  CHECK_THROWS_AS(export_material(maps, export_format::mitsuba, dir / "file" / "sub"), io_error);
  CHECK_THROWS_AS(export_material(maps, export_format::gltf, dir / "missing" / "m.gltf"), io_error);
  CHECK_FALSE(std::filesystem::exists(dir / "missing"));
  CHECK_THROWS_AS(write_viewer(material_maps(), dir / "v.html"), io_error);
  CHECK_FALSE(std::filesystem::exists(dir / "v.html"));
}

TEST_CASE("viewer page embeds the maps exactly and is self-contained") {
  const material_maps maps = test_maps();
  const std::string page = viewer_html(maps, {"a <title>"});
  CHECK(page.find("a &lt;title&gt;") != std::string::npos);
  CHECK(page.find("http://") == std::string::npos);
  CHECK(page.find("https://") == std::string::npos);
  const std::size_t start = page.find("application/octet-stream\">") + 26, end = page.find("</script>", start);
  const auto bytes = from_base64(std::string_view(page).substr(start, end - start));
  REQUIRE(bytes.size() == 12 * maps.texel_count() * sizeof(float));
  std::vector<float> values(bytes.size() / sizeof(float));
  std::memcpy(values.data(), bytes.data(), bytes.size());
  const std::size_t n = maps.texel_count(), i = 37;
  CHECK(values[i * 4 + 0] == maps.plane(diffuse_r)[i]);
  CHECK(values[i * 4 + 3] == maps.plane(fresnel_f0)[i]);
  CHECK(values[(n + i) * 4 + 3] == maps.plane(rotation)[i]);
  CHECK(values[(2 * n + i) * 4 + 1] == maps.plane(lobe_y)[i]);
  CHECK(values[(2 * n + i) * 4 + 3] == maps.plane(normal_y)[i]);
}
