// The viewer page as a user sees it: headless Chromium screenshots the page in its texel view at a
// fixed camera, light and exposure, and the screenshot (sRGB decoded) is compared with the
// renderer's image of the same configuration; and a tile shown 2 x 2 times repeats. Run by the
// ctest `viewer_browser` (exit 77, a skip, when no Chromium is installed); skipped in the plain
// `export` run.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>
#include <vector>

#include "../data/test_folder.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/export/tileable.hpp"
#include "anisocap/export/viewer.hpp"
#include "anisocap/render/renderer.hpp"

using namespace anisocap;

namespace {

std::string chromium_binary() {
  for (const char* name : {"chromium", "chromium-browser", "google-chrome"})
    if (std::system((std::string("command -v ") + name + " >/dev/null 2>&1").c_str()) == 0) return name;
  return {};
}

std::string triple(const vec3f& v) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "%.6g,%.6g,%.6g", v[0], v[1], v[2]);
  return buf;
}

}  // namespace

TEST_CASE("viewer in headless Chromium matches the renderer" * doctest::skip()) {
  const std::string chromium = chromium_binary();
  if (chromium.empty()) {
    std::fprintf(stderr, "viewer_browser: no chromium installed (scripts/install-deps.sh installs it); skipped\n");
    std::exit(77);
  }
  testing::test_folder dir;
  struct view_case {
    std::uint64_t seed;
    int width, height;
    capture_image config;
  };
  const view_case cases[] = {
      {3, 48, 40, {"a", {0.2f, -0.3f, 1.4f}, {-0.3f, 0.25f, 0.9f}, {2.0f, 2.2f, 2.5f}, "", 1.0f, 0.0f}},
      {11, 40, 40, {"b", {-0.5f, 0.4f, 0.8f}, {0.45f, -0.35f, 0.6f}, {1.2f, 1.0f, 0.9f}, "", 1.0f, 0.0f}},
      {26, 36, 44, {"c", {0.0f, 0.1f, 1.0f}, {0.05f, -0.1f, 1.2f}, {3.0f, 3.0f, 3.0f}, "", 1.0f, 0.0f}},
  };
  for (const view_case& vc : cases) {
    material_maps maps = generate_material(vc.seed, vc.width, vc.height);
    canonicalise(maps);
    capture cap;
    cap.images.push_back(vc.config);
    const image reference = render(maps, cap)[0];
    // Exposure that puts the median value of the render at 0.3, so most values lie in the page's range.
    std::vector<float> values;
    for (int c = 0; c < 3; ++c) values.insert(values.end(), reference.plane(c), reference.plane(c) + reference.pixel_count());
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    const double stops = std::round(10 * std::log2(0.3 / std::max(1e-6f, values[values.size() / 2]))) / 10;
    const double scale = std::exp2(stops);
    const auto page = dir / ("material_" + std::to_string(vc.seed) + ".html");
    const auto shot = dir / ("shot_" + std::to_string(vc.seed) + ".png");
    write_viewer(maps, page);
    char exposure[32];
    std::snprintf(exposure, sizeof exposure, "%.2f", stops);
    const std::string url = "file://" + page.string() + "#view=texel&ui=0&camera=" + triple(vc.config.camera) + "&light=" +
                            triple(vc.config.light) + "&intensity=" + triple(vc.config.intensity) + "&exposure=" + exposure;
    const std::string command = chromium + " --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader"
                                " --force-device-scale-factor=1 --hide-scrollbars --virtual-time-budget=5000 --window-size=" +
                                std::to_string(vc.width) + "," + std::to_string(vc.height) + " --screenshot=" + shot.string() +
                                " '" + url + "' >/dev/null 2>&1";
    REQUIRE(std::system(command.c_str()) == 0);
    const image screenshot = read_png(shot);
    REQUIRE(screenshot.width() == vc.width);
    REQUIRE(screenshot.height() == vc.height);
    // Mean relative error over the pixels the 8-bit page shows unclipped and above its darkest codes.
    double sum = 0;
    std::size_t count = 0;
    for (int c = 0; c < 3; ++c)
      for (std::size_t i = 0; i < reference.pixel_count(); ++i) {
        const double want = scale * reference.plane(c)[i];
        if (want < 0.05 || want > 0.95) continue;
        sum += std::abs(screenshot.plane(c)[i] - want) / want;
        ++count;
      }
    CAPTURE(vc.seed);
    REQUIRE(count > reference.pixel_count());  // over a third of the values take part
    const double mean_relative_error = sum / double(count);
    std::fprintf(stderr, "viewer_browser: material seed %llu: mean relative error %.4f over %zu values\n",
                 static_cast<unsigned long long>(vc.seed), mean_relative_error, count);
    CHECK(mean_relative_error < 0.02);
  }
}

TEST_CASE("viewer in headless Chromium repeats a tile 2 x 2" * doctest::skip()) {
  const std::string chromium = chromium_binary();
  if (chromium.empty()) {
    std::fprintf(stderr, "viewer_browser: no chromium installed (scripts/install-deps.sh installs it); skipped\n");
    std::exit(77);
  }
  testing::test_folder dir;
  const material_maps tile = make_tileable(generate_material(3, 40, 40), {0.25, false});  // 30 x 30: copies 100 pixels apart both ways
  const auto page = dir / "tile.html";
  write_viewer(tile, page);
  // Camera straight above at the height where one copy spans exactly 100 of the 256 pixels (the
  // page's perspective has a 35-degree field of view): copies side by side are 100 pixels apart.
  const int n = std::max(tile.width(), tile.height());
  const double cot = 1 / std::tan(35 * std::numbers::pi / 360);
  const double height = cot * (double(tile.width()) / n) * 128 / 100;
  auto shoot = [&](int repeat) {
    const auto shot = dir / ("repeat_" + std::to_string(repeat) + ".png");
    char camera[64];
    std::snprintf(camera, sizeof camera, "0,0,%.6f", height);
    const std::string url = "file://" + page.string() + "#view=perspective&ui=0&mode=diffuse&camera=" + camera + "&repeat=" + std::to_string(repeat);
    const std::string command = chromium + " --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader"
                                " --force-device-scale-factor=1 --hide-scrollbars --virtual-time-budget=5000 --window-size=256,256"
                                " --screenshot=" + shot.string() + " '" + url + "' >/dev/null 2>&1";
    REQUIRE(std::system(command.c_str()) == 0);
    const image img = read_png(shot);
    REQUIRE(img.width() == 256);
    REQUIRE(img.height() == 256);
    return img;
  };
  // Mean absolute difference between the lower-left copy and the one `dx`, `dy` pixels away.
  auto difference = [](const image& img, int dx, int dy) {
    double sum = 0;
    std::size_t count = 0;
    for (int c = 0; c < 3; ++c)
      for (int y = 132; y < 224; ++y)
        for (int x = 32; x < 124; ++x) sum += std::abs(img.at(c, x, y) - img.at(c, x + dx, y - dy)), ++count;
    return sum / double(count);
  };
  const image two = shoot(2), one = shoot(1);
  const double right = difference(two, 100, 0), up = difference(two, 0, 100), unrelated = difference(two, 50, 0);
  std::fprintf(stderr, "viewer_browser: 2 x 2 repeats: copy to copy %.4f (right) %.4f (up), half a copy apart %.4f\n", right, up, unrelated);
  CHECK(unrelated > 0.02);  // the tile has visible structure
  CHECK(right < 0.25 * unrelated);
  CHECK(up < 0.25 * unrelated);
  // Without repeats the neighbouring copies are background.
  CHECK(difference(one, 100, 0) > 2 * right);
}
