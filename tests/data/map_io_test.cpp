// Tests for data/map_io.hpp: map set round trips, previews, range handling (clamp within the
// tolerance, wrap alpha modulo pi), and errors that name the file while writing nothing.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <string>

#include "anisocap/data/map_io.hpp"
#include "data/test_folder.hpp"
#include "support/error_of.hpp"

using anisocap::image;
using anisocap::material_maps;
using anisocap::testing::test_folder;
namespace fs = std::filesystem;

using anisocap::testing::error_of;

namespace {

constexpr double pi = 3.14159265358979323846;

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

/// Valid random maps (every value strictly inside its range).
material_maps random_maps(int w, int h, bool height, std::uint32_t seed) {
  material_maps m(w, h);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    for (int k = anisocap::diffuse_r; k <= anisocap::specular_b; ++k) m.plane(k)[i] = u(rng);
    m.plane(anisocap::lobe_x)[i] = 0.001f + 0.99f * u(rng);
    m.plane(anisocap::lobe_y)[i] = 0.001f + 0.99f * u(rng);
    m.plane(anisocap::fresnel_f0)[i] = u(rng);
    const float r = 0.99f * u(rng), phi = float(2 * pi) * u(rng);
    m.plane(anisocap::normal_x)[i] = r * std::cos(phi);
    m.plane(anisocap::normal_y)[i] = r * std::sin(phi);
    m.plane(anisocap::rotation)[i] = float(pi) * (u(rng) - 0.5f);
  }
  if (height) {
    m.enable_height_map();
    for (std::size_t i = 0; i < m.texel_count(); ++i) m.height_map()[i] = 3.0f * u(rng) - 1.0f;
  }
  return m;
}

std::map<std::string, std::vector<unsigned char>> snapshot(const test_folder& dir) {
  std::map<std::string, std::vector<unsigned char>> files;
  for (const auto& name : dir.entries()) files[name] = anisocap::read_file_bytes(dir / name);
  return files;
}

/// Rewrites one file of the set in `dir` after `edit` changes its image.
template <class F>
void edit_file(const test_folder& dir, const std::string& name, F&& edit) {
  image img = anisocap::read_exr(dir / name);
  edit(img);
  anisocap::write_exr(img, dir / name);
}

}  // namespace

TEST_CASE("map set: write then read is exact, with the documented files and previews") {
  test_folder dir;
  const material_maps m = random_maps(19, 11, true, 1);
  anisocap::write_maps(m, dir.path());
  CHECK(dir.entries() == std::vector<std::string>{"diffuse.exr", "diffuse.png", "fresnel.exr", "fresnel.png",
                                                   "height.exr", "height.png", "lobes.exr", "lobes.png",
                                                   "normal.exr", "normal.png", "rotation.exr", "rotation.png",
                                                   "specular.exr", "specular.png"});
  const material_maps back = anisocap::read_maps(dir.path());
  REQUIRE(back.width() == 19);
  REQUIRE(back.height() == 11);
  REQUIRE(back.has_height());
  for (int k = 0; k < anisocap::parameter_count; ++k)
    for (std::size_t i = 0; i < m.texel_count(); ++i) REQUIRE(back.plane(k)[i] == m.plane(k)[i]);
  for (std::size_t i = 0; i < m.texel_count(); ++i) REQUIRE(back.height_map()[i] == m.height_map()[i]);

  // File layout of the issue: lobes B = 0, fresnel replicated, normal z from x and y.
  const image lobes = anisocap::read_exr(dir / "lobes.exr");
  const image fresnel = anisocap::read_exr(dir / "fresnel.exr");
  const image normal = anisocap::read_exr(dir / "normal.exr");
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    CHECK(lobes.plane(2)[i] == 0.0f);
    CHECK(fresnel.plane(1)[i] == m.plane(anisocap::fresnel_f0)[i]);
    CHECK(fresnel.plane(2)[i] == m.plane(anisocap::fresnel_f0)[i]);
    const float x = normal.plane(0)[i], y = normal.plane(1)[i], z = normal.plane(2)[i];
    CHECK(x * x + y * y + z * z == doctest::Approx(1.0f).epsilon(1e-5));
    CHECK(z > 0.0f);
  }
  // Previews: colour maps in sRGB, data maps mapped as documented (8-bit codes).
  const image diffuse_png = anisocap::read_png(dir / "diffuse.png");
  const image normal_png = anisocap::read_png(dir / "normal.png");
  const image rotation_png = anisocap::read_png(dir / "rotation.png");
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    // read_png linearises, so an sRGB preview reads back close to the value itself...
    CHECK(diffuse_png.plane(0)[i] == doctest::Approx(m.plane(anisocap::diffuse_r)[i]).epsilon(0.02).scale(1.0));
    // ...and a linear-coded preview reads back as srgb_to_linear(mapped value).
    const double nx = 0.5 + 0.5 * m.plane(anisocap::normal_x)[i];
    CHECK(normal_png.plane(0)[i] == doctest::Approx(anisocap::srgb_to_linear(std::round(nx * 255) / 255)));
    const double a = m.plane(anisocap::rotation)[i] / pi + 0.5;
    CHECK(rotation_png.plane(0)[i] == doctest::Approx(anisocap::srgb_to_linear(std::round(a * 255) / 255)));
  }
}

TEST_CASE("map set: rewriting without height or previews leaves one consistent set") {
  test_folder dir;
  anisocap::write_maps(random_maps(4, 4, true, 2), dir.path());
  anisocap::write_maps(random_maps(4, 4, false, 3), dir.path(), false);
  CHECK(dir.entries() == std::vector<std::string>{"diffuse.exr", "fresnel.exr", "lobes.exr", "normal.exr",
                                                   "rotation.exr", "specular.exr"});
  CHECK(!anisocap::read_maps(dir.path()).has_height());
  // write_maps creates the folder.
  anisocap::write_maps(random_maps(3, 2, false, 4), dir / "new" / "set");
  CHECK(anisocap::read_maps(dir / "new" / "set").width() == 3);
}

TEST_CASE("map set: a folder without some maps is refused, naming each missing file") {
  test_folder dir;
  anisocap::write_maps(random_maps(4, 4, false, 6), dir.path(), false);
  std::filesystem::remove(dir / "lobes.exr");
  std::filesystem::remove(dir / "normal.exr");
  std::string message;
  try {
    (void)anisocap::read_maps(dir.path());
  } catch (const anisocap::io_error& e) {
    message = e.what();
  }
  CHECK(message.find(dir.path().string()) == 0);
  CHECK(message.find("map set is missing lobes.exr, normal.exr (needed:") != std::string::npos);
}

TEST_CASE("map set: values just outside the ranges are clamped, alpha is wrapped modulo pi") {
  test_folder dir;
  material_maps m = random_maps(4, 1, false, 5);
  m.at(anisocap::diffuse_g, 0, 0) = 1.00005f;
  m.at(anisocap::specular_b, 1, 0) = -0.00005f;
  m.at(anisocap::lobe_x, 2, 0) = 1e-6f;  // positive but below min_lobe_width
  m.at(anisocap::lobe_y, 3, 0) = 1.00009f;
  m.at(anisocap::fresnel_f0, 0, 0) = 1.00001f;
  m.at(anisocap::normal_x, 1, 0) = 0.6f;
  m.at(anisocap::normal_y, 1, 0) = 0.80003f;
  m.at(anisocap::rotation, 0, 0) = 2.0f;
  m.at(anisocap::rotation, 1, 0) = -4.0f;
  m.at(anisocap::rotation, 2, 0) = float(pi / 2);   // the float bounds themselves are kept
  m.at(anisocap::rotation, 3, 0) = -float(pi / 2);
  anisocap::write_maps(m, dir.path(), false);
  const material_maps b = anisocap::read_maps(dir.path());
  CHECK(b.at(anisocap::diffuse_g, 0, 0) == 1.0f);
  CHECK(b.at(anisocap::specular_b, 1, 0) == 0.0f);
  CHECK(b.at(anisocap::lobe_x, 2, 0) == anisocap::min_lobe_width);
  CHECK(b.at(anisocap::lobe_y, 3, 0) == 1.0f);
  CHECK(b.at(anisocap::fresnel_f0, 0, 0) == 1.0f);
  const float nx = b.at(anisocap::normal_x, 1, 0), ny = b.at(anisocap::normal_y, 1, 0);
  CHECK(nx * nx + ny * ny <= 1.0f + 1e-6f);
  CHECK(ny / nx == doctest::Approx(0.80003 / 0.6));
  CHECK(b.at(anisocap::rotation, 0, 0) == doctest::Approx(2.0 - pi));
  CHECK(b.at(anisocap::rotation, 1, 0) == doctest::Approx(-4.0 + pi));
  CHECK(b.at(anisocap::rotation, 2, 0) == float(pi / 2));
  CHECK(b.at(anisocap::rotation, 3, 0) == -float(pi / 2));
  // The same wrapping applies to a file written by another tool.
  edit_file(dir, "rotation.exr", [](image& img) { img.at(0, 2, 0) = float(7 * pi / 4); });
  CHECK(anisocap::read_maps(dir.path()).at(anisocap::rotation, 2, 0) == doctest::Approx(-pi / 4));
}

TEST_CASE("map set: bad sets give one error naming the file") {
  test_folder dir;
  const material_maps m = random_maps(6, 5, true, 6);
  auto fresh = [&] {
    for (const auto& name : dir.entries()) fs::remove(dir / name);
    anisocap::write_maps(m, dir.path(), false);
  };
  std::string e = error_of([&] { anisocap::read_maps(dir / "nope"); });
  CHECK(contains(e, "nope"));
  CHECK(contains(e, "folder not found"));

  fresh();
  fs::remove(dir / "normal.exr");
  fs::remove(dir / "lobes.exr");
  e = error_of([&] { anisocap::read_maps(dir.path()); });
  CHECK(contains(e, dir.path().string()));
  CHECK(contains(e, "missing lobes.exr, normal.exr"));
  fresh();
  fs::remove(dir / "height.exr");  // optional
  CHECK(!anisocap::read_maps(dir.path()).has_height());

  struct bad_case { const char* file; int channel, x, y; float value; const char* keyword; };
  const bad_case cases[] = {
      {"diffuse.exr", 1, 2, 3, 1.5f, "outside [0, 1]"},
      {"specular.exr", 0, 0, 0, -0.01f, "outside [0, 1]"},
      {"lobes.exr", 0, 5, 4, 0.0f, "outside (0, 1]"},
      {"lobes.exr", 1, 1, 1, 2.0f, "outside (0, 1]"},
      {"fresnel.exr", 0, 3, 2, -1.0f, "outside [0, 1]"},
      {"normal.exr", 0, 4, 0, 1.2f, "exceeds 1"},
      {"normal.exr", 2, 4, 0, -0.5f, "below the surface"},
      {"rotation.exr", 0, 1, 2, std::numeric_limits<float>::infinity(), "not finite"},
      {"height.exr", 0, 0, 4, std::numeric_limits<float>::quiet_NaN(), "not finite"},
      {"fresnel.exr", 2, 5, 1, std::numeric_limits<float>::quiet_NaN(), "not finite"},  // an ignored channel too
  };
  for (const auto& c : cases) {
    CAPTURE(c.file);
    CAPTURE(c.keyword);
    fresh();
    edit_file(dir, c.file, [&](image& img) { img.at(c.channel, c.x, c.y) = c.value; });
    e = error_of([&] { anisocap::read_maps(dir.path()); });
    CHECK(contains(e, (dir / c.file).string()));
    CHECK(contains(e, "x=" + std::to_string(c.x) + ", y=" + std::to_string(c.y)));
    CHECK(contains(e, c.keyword));
  }
  fresh();
  anisocap::write_exr(image(6, 4, 3), dir / "rotation.exr");
  e = error_of([&] { anisocap::read_maps(dir.path()); });
  CHECK(contains(e, "rotation.exr"));
  CHECK(contains(e, "size 6x4 differs from diffuse.exr (6x5)"));
  fresh();
  std::FILE* f = std::fopen((dir / "lobes.exr").c_str(), "wb");
  std::fputs("not an exr", f);
  std::fclose(f);
  e = error_of([&] { anisocap::read_maps(dir.path()); });
  CHECK(contains(e, "lobes.exr"));
}

TEST_CASE("map set: an invalid set is refused and the existing set stays untouched") {
  test_folder dir;
  anisocap::write_maps(random_maps(5, 5, true, 7), dir.path());
  const auto before = snapshot(dir);
  struct bad_case { int plane; float value; const char* file; };
  const bad_case cases[] = {
      {anisocap::specular_g, std::numeric_limits<float>::quiet_NaN(), "specular.exr"},
      {anisocap::diffuse_b, 2.0f, "diffuse.exr"},
      {anisocap::lobe_y, 0.0f, "lobes.exr"},
      {anisocap::normal_y, 1.5f, "normal.exr"},
      {anisocap::rotation, std::numeric_limits<float>::infinity(), "rotation.exr"},
  };
  for (const auto& c : cases) {
    CAPTURE(c.file);
    material_maps bad = random_maps(5, 5, false, 8);
    bad.at(c.plane, 4, 3) = c.value;
    const std::string e = error_of([&] { anisocap::write_maps(bad, dir.path()); });
    CHECK(contains(e, c.file));
    CHECK(contains(e, "x=4, y=3"));
    CHECK(snapshot(dir) == before);  // nothing written, nothing removed, no temporaries
  }
  material_maps bad_height = random_maps(5, 5, true, 9);
  bad_height.height_map()[7] = -std::numeric_limits<float>::infinity();
  CHECK(contains(error_of([&] { anisocap::write_maps(bad_height, dir.path()); }), "height.exr"));
  CHECK(snapshot(dir) == before);
  CHECK(contains(error_of([&] { anisocap::write_maps(material_maps(), dir.path()); }), "empty"));
}

TEST_CASE("map set: a staged set appears only on commit; discarded, the existing set stays untouched") {
  test_folder dir;
  anisocap::write_maps(random_maps(4, 4, true, 11), dir.path());
  const auto before = snapshot(dir);
  const material_maps next = random_maps(4, 4, false, 12);
  std::vector<fs::path> stale;
  {
    anisocap::file_transaction files;
    stale = anisocap::stage_maps(next, dir.path(), files);
    CHECK(files.staged() == 12);  // 6 EXRs and their previews
    CHECK(anisocap::read_maps(dir.path()).has_height());  // the earlier set is still the one there
  }  // not committed: discarded
  CHECK(snapshot(dir) == before);
  // The set without a height map makes the earlier height.exr and its preview stale.
  CHECK(stale == std::vector<fs::path>{dir / "height.exr", dir / "height.png"});
  anisocap::file_transaction files;
  stale = anisocap::stage_maps(next, dir.path(), files);
  files.commit();
  anisocap::remove_stale_files(stale);
  const material_maps read = anisocap::read_maps(dir.path());
  CHECK_FALSE(read.has_height());
  CHECK(std::equal(read.plane(anisocap::diffuse_r), read.plane(anisocap::diffuse_r) + 16, next.plane(anisocap::diffuse_r)));
}
