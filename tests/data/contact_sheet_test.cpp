#include <doctest/doctest.h>

#include <filesystem>
#include <random>

#include "anisocap/data/contact_sheet.hpp"

using namespace anisocap;

TEST_CASE("contact sheet: layout, scaling and labels") {
  image a(64, 32, 3), b(64, 32, 3);
  for (std::size_t i = 0; i < a.pixel_count(); ++i) { a.plane(0)[i] = 0.5f; b.plane(2)[i] = 0.25f; }
  const image sheet = make_contact_sheet({{{a, "first"}, {b, "second"}}, {{a, ""}}}, 40);
  // Tiles keep the aspect ratio (40 x 20), 2 columns and 2 rows with 12-pixel labels and 4-pixel gaps.
  CHECK(sheet.width() == 2 * (40 + 4) + 4);
  CHECK(sheet.height() == 2 * (20 + 12 + 4) + 4);
  // The first tile's pixels carry the image (box-filtered constant stays constant).
  CHECK(sheet.at(0, 4 + 10, 4 + 12 + 10) == doctest::Approx(0.5f));
  CHECK(sheet.at(2, 4 + 44 + 10, 4 + 12 + 10) == doctest::Approx(0.25f));
  // The label row of the first tile has white pixels, the empty label of row 2 has none.
  int white = 0, white_empty = 0;
  for (int y = 4; y < 4 + 12; ++y)
    for (int x = 4; x < 44; ++x) {
      white += sheet.at(0, x, y) == 1.0f;
      white_empty += sheet.at(0, x, y + 36) == 1.0f;
    }
  CHECK(white > 10);
  CHECK(white_empty == 0);
  CHECK_THROWS(make_contact_sheet({}, 40));
}

TEST_CASE("contact sheet of a capture is written as a PNG") {
  const int w = 24, h = 16;
  material_maps maps(w, h);
  const float t[parameter_count] = {0.4f, 0.3f, 0.2f, 0.1f, 0.1f, 0.1f, 0.2f, 0.3f, 0.5f, 0.1f, 0.0f, 0.3f};
  maps.fill(t);
  std::vector<image> inputs(3, image(w, h, 3)), renders(3, image(w, h, 3));
  const auto dir = std::filesystem::temp_directory_path() / ("anisocap_sheet_" + std::to_string(std::random_device{}()));
  std::filesystem::create_directories(dir);
  write_capture_sheet(dir / "sheet.png", inputs, renders, maps, &maps, 32);
  const image back = read_png(dir / "sheet.png");
  CHECK(back.height() == 5 * (21 + 12 + 4) + 4);
  std::filesystem::remove_all(dir);
}
