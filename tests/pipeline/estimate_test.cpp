#include <doctest/doctest.h>

#include <cmath>
#include <numbers>

#include "anisocap/pipeline/estimate.hpp"

using namespace anisocap;

TEST_CASE("window starts cover the material with the given stride, the last window ends at the border") {
  CHECK(window_starts(256, 256, 64) == std::vector<int>{0});
  CHECK(window_starts(100, 256, 64) == std::vector<int>{0});
  CHECK(window_starts(300, 256, 64) == std::vector<int>{0, 44});
  CHECK(window_starts(517, 256, 64) == std::vector<int>{0, 64, 128, 192, 256, 261});
  for (int n : {257, 320, 640, 1000}) {
    const auto s = window_starts(n, 256, 64);
    CHECK(s.front() == 0);
    CHECK(s.back() + 256 == n);
    for (std::size_t i = 1; i < s.size(); ++i) CHECK(s[i] - s[i - 1] <= 64);
  }
}

TEST_CASE("mirrored crops reflect without repeating the edge") {
  CHECK(mirror_index(-1, 5) == 1);
  CHECK(mirror_index(5, 5) == 3);
  CHECK(mirror_index(13, 5) == 3);
  CHECK(mirror_index(7, 1) == 0);
  image img(3, 2, 1);
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 3; ++x) img.at(0, x, y) = float(10 * y + x);
  const image c = crop_mirrored(img, 1, 0, 4, 3);
  CHECK(c.at(0, 0, 0) == 1.0f);
  CHECK(c.at(0, 2, 0) == 1.0f);   // x = 3 mirrors to 1
  CHECK(c.at(0, 3, 1) == 10.0f);  // x = 4 -> 0, y = 1
  CHECK(c.at(0, 3, 2) == 0.0f);   // y = 2 mirrors to 0 in a 2-row image
  image reused(4, 3, 1);  // written in place, as the sliding windows do with the images they keep
  reused.at(0, 1, 1) = -7.0f;
  crop_mirrored_into(img, 1, 0, reused);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x) CHECK(reused.at(0, x, y) == c.at(0, x, y));
  image wrong(4, 3, 3);
  CHECK_THROWS_WITH_AS(crop_mirrored_into(img, 0, 0, wrong), doctest::Contains("channel counts differ"), std::invalid_argument);
}

TEST_CASE("window blending reproduces a position-independent estimate exactly, at any size") {
  for (auto [w, h] : {std::pair{300, 517}, std::pair{90, 70}, std::pair{256, 256}}) {
    std::vector<image> photos(2, image(w, h, 3));
    // Each window returns constant maps: the blend of constants is that constant everywhere.
    int calls = 0;
    const material_maps m = estimate_by_windows(photos, 256, 64, [&](const std::vector<image>& crops) {
      ++calls;
      CHECK(crops.size() == 2);
      CHECK(crops[0].width() == 256);
      material_maps out(256, 256);
      const float t[parameter_count] = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f, 0.1f, 0.4f, 0.7f, 0.2f, -0.1f, 1.4f};
      out.fill(t);
      return out;
    });
    CHECK(calls == int(window_starts(w, 256, 64).size() * window_starts(h, 256, 64).size()));
    CHECK(m.width() == w);
    CHECK(m.height() == h);
    for (std::size_t i = 0; i < m.texel_count(); i += 97) {
      CHECK(m.plane(diffuse_g)[i] == doctest::Approx(0.2f));
      CHECK(m.plane(normal_y)[i] == doctest::Approx(-0.1f));
      CHECK(m.plane(rotation)[i] == doctest::Approx(1.4f).epsilon(1e-4));
    }
  }
}

TEST_CASE("rotation blends as a pi-periodic angle") {
  std::vector<image> photos(1, image(320, 256, 3));
  int call = 0;
  const material_maps m = estimate_by_windows(photos, 256, 64, [&](const std::vector<image>&) {
    material_maps out(256, 256);
    // Two windows agree on the orientation but write it as +-(pi/2 - 0.05): plain averaging gives ~0.
    const float a = (call++ % 2 == 0) ? float(std::numbers::pi / 2 - 0.05) : float(-std::numbers::pi / 2 + 0.05);
    const float t[parameter_count] = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f, 0.1f, 0.4f, 0.7f, 0.0f, 0.0f, a};
    out.fill(t);
    return out;
  });
  for (std::size_t i = 0; i < m.texel_count(); i += 101) CHECK(std::abs(std::abs(m.plane(rotation)[i]) - float(std::numbers::pi / 2)) < 0.06f);
}

TEST_CASE("estimate options: a stride larger than the window, or a non-positive size, is refused; the defaults pass") {
  CHECK_NOTHROW(estimate_options{}.validate());
  const estimate_options w192{192, 64}, w128{128, 128}, too_far{128, 129}, no_window{0, 64}, no_stride{256, 0};
  CHECK_NOTHROW(w192.validate());
  CHECK_NOTHROW(w128.validate());
  CHECK_THROWS_WITH_AS(too_far.validate(), doctest::Contains("no estimate"), std::invalid_argument);
  CHECK_THROWS_AS(no_window.validate(), std::invalid_argument);
  CHECK_THROWS_AS(no_stride.validate(), std::invalid_argument);
}
