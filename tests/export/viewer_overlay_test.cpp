// The viewer's uncertainty overlay: the page embeds the ratios after the maps (and nothing without
// them), refuses ratios of another size, and in headless Chromium (the ctest `viewer_browser`)
// blends magenta where the photographs say nothing and leaves the view alone where they fix it.
#include <doctest/doctest.h>

#include <cstdlib>
#include <cstring>
#include <string>

#include "../data/test_folder.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/export/viewer.hpp"

using namespace anisocap;

namespace {

/// The contents of the page's <script id="NAME"> element.
std::string script_text(const std::string& page, const std::string& name) {
  const std::string open = "<script id=\"" + name + "\" type=\"application/octet-stream\">";
  const std::size_t start = page.find(open);
  REQUIRE(start != std::string::npos);
  const std::size_t from = start + open.size();
  return page.substr(from, page.find("</script>", from) - from);
}

/// Grey diffuse maps with no specular lobe; the uncertainty ratio of F0 is 1 on the left half, 0 on the right.
std::pair<material_maps, material_maps> half_uncertain(int w, int h) {
  material_maps maps(w, h), ratio(w, h);
  const float grey[parameter_count] = {0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 0.0f, 0.2f, 0.2f, 0.04f, 0.0f, 0.0f, 0.0f};
  maps.fill(grey);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) ratio.at(fresnel_f0, x, y) = x < w / 2 ? 1.0f : 0.0f;
  return {maps, ratio};
}

}  // namespace

TEST_CASE("viewer page: the uncertainty ratios embedded after the maps, only when given") {
  const auto [maps, ratio] = half_uncertain(8, 4);
  CHECK(script_text(viewer_html(maps), "uncertainty").empty());
  viewer_options o;
  o.uncertainty = &ratio;
  const std::string page = viewer_html(maps, o);
  CHECK(script_text(page, "maps") == script_text(viewer_html(maps), "maps"));
  const std::string text = script_text(page, "uncertainty");
  CHECK(text.size() == (12 * maps.texel_count() * sizeof(float) + 2) / 3 * 4);
  const material_maps wrong(4, 4);
  o.uncertainty = &wrong;
  CHECK_THROWS_WITH_AS(viewer_html(maps, o), doctest::Contains("size"), std::invalid_argument);
}

TEST_CASE("viewer in headless Chromium blends the uncertainty overlay" * doctest::skip()) {
  std::string chromium;
  for (const char* name : {"chromium", "chromium-browser", "google-chrome"})
    if (chromium.empty() && std::system((std::string("command -v ") + name + " >/dev/null 2>&1").c_str()) == 0) chromium = name;
  if (chromium.empty()) {
    std::fprintf(stderr, "viewer_browser: no chromium installed (scripts/install-deps.sh installs it); skipped\n");
    std::exit(77);
  }
  const int w = 32, h = 16;
  const auto [maps, ratio] = half_uncertain(w, h);
  testing::test_folder dir;
  viewer_options o;
  o.uncertainty = &ratio;
  write_viewer(maps, dir.path() / "page.html", o);
  const std::string url = "file://" + (dir.path() / "page.html").string() + "#view=texel&ui=0&mode=diffuse&overlay=fresnel";
  const std::string command = chromium + " --headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader"
                              " --force-device-scale-factor=1 --hide-scrollbars --virtual-time-budget=5000 --window-size=" +
                              std::to_string(w) + "," + std::to_string(h) + " --screenshot=" + (dir.path() / "shot.png").string() +
                              " '" + url + "' >/dev/null 2>&1";
  REQUIRE(std::system(command.c_str()) == 0);
  const image shot = read_png(dir.path() / "shot.png");  // linear values
  REQUIRE(shot.width() == w);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      CAPTURE(x);
      CAPTURE(y);
      if (x < w / 2) {  // 0.8 magenta over sRGB 0.735: R and B near 0.95 (linear 0.88), G 0.15 (linear 0.02)
        REQUIRE(shot.at(0, x, y) > 0.8f);
        REQUIRE(shot.at(1, x, y) < 0.05f);
        REQUIRE(shot.at(2, x, y) > 0.8f);
      } else {  // the diffuse albedo as it is
        for (int c = 0; c < 3; ++c) REQUIRE(std::abs(shot.at(c, x, y) - 0.5f) < 0.02f);
      }
    }
}
