// Tests for data/capture_io.hpp: capture.json round trips, every malformed case
// (one error naming the file, the image and the problem), and loading the capture's images.
#include <doctest/doctest.h>

#include <fstream>
#include <limits>
#include <string>

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "data/test_folder.hpp"

using anisocap::capture;
using anisocap::capture_image;
using anisocap::image;
using anisocap::testing::test_folder;
namespace fs = std::filesystem;

namespace {

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
}

/// Error message of reading `text` as `<dir>/capture.json`.
std::string capture_error(const test_folder& dir, const std::string& text) {
  const fs::path path = dir / "capture.json";
  write_text(path, text);
  try {
    anisocap::read_capture(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  FAIL("expected an error for: " << text);
  return {};
}

capture sample_capture() {
  capture c;
  c.images.push_back({"input_00.exr", {0.1f, -0.2f, 1.5f}, {-0.3f, 0.4f, 2.0f}, {1.0f, 1.0f, 1.0f}, "", 1.0f});
  c.images.push_back({"input_01.png", {0.0f, 0.0f, 0.25f}, {0.5f, 0.5f, 0.01f}, {2.0f, 3.5f, 1e-6f}, "", 1.0f});
  c.images.push_back({"sub/input_02.exr", {3.0f, 4.0f, 4.0f}, {1.0f, 2.0f, 3.0f}, {1e6f, 1e6f, 1e6f}, "", 1.0f});
  return c;
}

const char* valid_entry = R"({"file": "a.exr", "camera": [0, 0, 1], "light": [0, 0, 1], "intensity": 1})";

}  // namespace

TEST_CASE("capture.json: write then read gives the same capture, in a readable file") {
  test_folder dir;
  capture c = sample_capture();
  c.images.push_back({"IMG_0003.jpg", {0.0f, 0.3f, 2.0f}, {0.0f, -0.3f, 2.0f}, {1.0f, 1.0f, 1.0f}, "masks/mask_03.png", 0.5f, 0.004f,
                      anisocap::photo_encoding::jpeg_subsampled});
  anisocap::write_capture(c, dir / "capture.json");
  CHECK(dir.entries() == std::vector<std::string>{"capture.json"});  // no temporaries left
  const capture back = anisocap::read_capture(dir / "capture.json");
  REQUIRE(back.images.size() == c.images.size());
  for (std::size_t i = 0; i < c.images.size(); ++i) {
    CHECK(back.images[i].file == c.images[i].file);
    CHECK(back.images[i].camera == c.images[i].camera);
    CHECK(back.images[i].light == c.images[i].light);
    CHECK(back.images[i].intensity == c.images[i].intensity);
    CHECK(back.images[i].mask == c.images[i].mask);
    CHECK(back.images[i].exposure == c.images[i].exposure);
    CHECK(back.images[i].floor == c.images[i].floor);
    CHECK(back.images[i].encoding == c.images[i].encoding);
  }
  const auto bytes = anisocap::read_file_bytes(dir / "capture.json");
  const std::string text(bytes.begin(), bytes.end());
  CHECK(contains(text, "\"intensity\": 1\n"));         // grey intensity as one number
  CHECK(contains(text, "\"camera\": [\n        0.1,"));  // shortest float form, not 0.100000001490116
  CHECK(contains(text, "1e-06"));
  CHECK(contains(text, "\"mask\": \"masks/mask_03.png\""));
  CHECK(contains(text, "\"exposure\": 0.5"));
  CHECK(!contains(text, "\"exposure\": 1"));  // the default is not written
  CHECK(contains(text, "\"floor\": 0.004"));
  CHECK(text.find("\"floor\"") == text.rfind("\"floor\""));  // only the image that has one
  CHECK(contains(text, "\"encoding\": \"jpeg_subsampled\""));
  CHECK(text.find("\"encoding\"") == text.rfind("\"encoding\""));  // lossless, the default, is not written
}

TEST_CASE("capture.json: accepted forms") {
  test_folder dir;
  const fs::path path = dir / "capture.json";
  write_text(path, R"({"images": [
    {"intensity": [1, 2, 3], "light": [0, 0, 0.001], "camera": [0.5, 0.5, 0.001], "file": "x.PNG"}]})");
  const capture c = anisocap::read_capture(path);
  REQUIRE(c.images.size() == 1);
  CHECK(c.images[0].file == "x.PNG");
  CHECK(c.images[0].intensity == anisocap::vec3f{1, 2, 3});
  CHECK(c.images[0].light[2] == 0.001f);
  write_text(path, R"({"images": [{"file": "a.exr", "camera": [0, 0, 1], "light": [0, 0, 1], "intensity": 2.5}]})");
  CHECK(anisocap::read_capture(path).images[0].intensity == anisocap::vec3f{2.5f, 2.5f, 2.5f});
}

TEST_CASE("capture.json: every malformed input gives one error naming the file and the problem") {
  test_folder dir;
  const std::string entry = valid_entry;
  auto images = [](const std::string& list) { return "{\"images\": [" + list + "]}"; };
  auto with = [](const std::string& fields) { return "{\"file\": \"b.exr\", " + fields + "}"; };
  struct bad_case { std::string text, keywords[2]; };
  const bad_case cases[] = {
      {"{\"images\": [" + entry + ",]}", {"trailing comma", ":1:"}},
      {"{\n  \"images\": [\n    {\"file\": \"a.exr\" \"camera\": [0,0,1]}\n  ]\n}", {":3:", "expected '}'"}},
      {"", {"end of input", ":1:1"}},
      {"[]", {"expected a JSON object", "array"}},
      {"{}", {"missing field \"images\"", ""}},
      {"{\"images\": {}}", {"\"images\" must be an array", "object"}},
      {"{\"images\": []}", {"\"images\" is empty", ""}},
      {"{\"imagse\": []}", {"unknown field \"imagse\"", ""}},
      {"{\"images\": [" + entry + "], \"note\": 1}", {"unknown field \"note\"", ""}},
      {images("3"), {"images[0]", "expected an object"}},
      {images(entry + ", " + with("\"camera\": [0,0,1], \"light\": [0,0,1]")), {"images[1] (\"b.exr\")", "missing field \"intensity\""}},
      {images("{\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1}"), {"images[0]", "missing field \"file\""}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"intesity\": 2")), {"images[0] (\"b.exr\")", "unknown field \"intesity\" (expected \"file\", \"camera\", \"light\", \"intensity\", optional \"mask\", \"exposure\", \"floor\", \"encoding\")"}},
      {images("{\"file\": 7, \"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1}"), {"images[0]", "\"file\" must be a string"}},
      {images("{\"file\": \"\", \"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1}"), {"images[0]", "\"file\" is empty"}},
      {images("{\"file\": \"a.tif\", \"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1}"), {"images[0] (\"a.tif\")", ".jpg"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"mask\": 3")), {"images[0] (\"b.exr\")", "\"mask\" must be a non-empty file name"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"mask\": \"m.txt\"")), {"\"mask\" must name an image", ".png"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"exposure\": 0")), {"images[0] (\"b.exr\")", "exposure must be a positive"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"exposure\": \"2\"")), {"\"exposure\" must hold numbers", "string"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"floor\": -0.01")), {"images[0] (\"b.exr\")", "floor must be a finite number >= 0"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"floor\": [0]")), {"\"floor\" must hold numbers", "array"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"encoding\": \"png\"")), {"images[0] (\"b.exr\")", "\"encoding\" must be \"lossless\", \"eight_bit\", \"jpeg\" or \"jpeg_subsampled\", got \"png\""}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 1, \"encoding\": 2")), {"images[0] (\"b.exr\")", "\"encoding\" must be \"lossless\", \"eight_bit\", \"jpeg\" or \"jpeg_subsampled\", got 2"}},
      {images(with("\"camera\": \"up\", \"light\": [0,0,1], \"intensity\": 1")), {"\"camera\" must be an array", "string"}},
      {images(with("\"camera\": [0,0], \"light\": [0,0,1], \"intensity\": 1")), {"\"camera\" must have 3 elements", "got 2"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1,1], \"intensity\": 1")), {"\"light\" must have 3 elements", "got 4"}},
      {images(with("\"camera\": [0,\"0\",1], \"light\": [0,0,1], \"intensity\": 1")), {"images[0] (\"b.exr\")", "\"camera\" must hold numbers"}},
      {images(with("\"camera\": [0,0,1], \"light\": [null,0,1], \"intensity\": 1")), {"\"light\" must hold numbers", "null"}},
      {images(with("\"camera\": [0,0,1e39], \"light\": [0,0,1], \"intensity\": 1")), {"\"camera\"", "not finite"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": -1e40")), {"\"intensity\"", "not finite"}},
      {images(with("\"camera\": [0,0,NaN], \"light\": [0,0,1], \"intensity\": 1")), {"NaN", ":1:"}},
      {images(with("\"camera\": [0,0,0], \"light\": [0,0,1], \"intensity\": 1")), {"at or below the material plane", "from above"}},
      {images(with("\"camera\": [0.2,0.1,-2], \"light\": [0,0,1], \"intensity\": 1")), {"camera z = -2", "from above"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0.3,0,-1], \"intensity\": 1")), {"light z = -1", "below the material plane"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0.1,0.2,0], \"intensity\": 1")), {"light z = 0", "from above"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": 0")), {"images[0] (\"b.exr\")", "intensity must be > 0"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": [1, -0.5, 1]")), {"intensity must be > 0", "-0.5"}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": [1, 1]")), {"\"intensity\" must have 3 elements", ""}},
      {images(with("\"camera\": [0,0,1], \"light\": [0,0,1], \"intensity\": \"bright\"")), {"\"intensity\" must be a number or [r, g, b]", "string"}},
      {images(entry + ", " + entry), {"images[1] (\"a.exr\")", "duplicate file, already used by images[0]"}},
      {images(entry + ", " + R"({"file": "./a.exr", "camera": [0, 0, 2], "light": [0, 0, 1], "intensity": 1})"), {"images[1]", "duplicate file"}},
  };
  for (const auto& c : cases) {
    CAPTURE(c.text);
    const std::string e = capture_error(dir, c.text);
    CAPTURE(e);
    CHECK(contains(e, (dir / "capture.json").string()));
    CHECK(contains(e, c.keywords[0]));
    CHECK(contains(e, c.keywords[1]));
  }
  fs::remove(dir / "capture.json");
  const std::string e = [&] {
    try { anisocap::read_capture(dir / "capture.json"); } catch (const std::runtime_error& x) { return std::string(x.what()); }
    return std::string();
  }();
  CHECK(contains(e, "capture.json: file not found"));
}

TEST_CASE("write_capture refuses an invalid capture and writes nothing") {
  test_folder dir;
  capture c = sample_capture();
  c.images[1].camera[2] = 0.0f;
  CHECK_THROWS_WITH_AS(anisocap::write_capture(c, dir / "capture.json"), doctest::Contains("from above"), anisocap::io_error);
  c = sample_capture();
  c.images[2].intensity[1] = std::numeric_limits<float>::infinity();
  CHECK_THROWS_WITH_AS(anisocap::write_capture(c, dir / "capture.json"), doctest::Contains("images[2]"), anisocap::io_error);
  c = sample_capture();
  c.images[2].file = c.images[0].file;
  CHECK_THROWS_WITH_AS(anisocap::write_capture(c, dir / "capture.json"), doctest::Contains("duplicate"), anisocap::io_error);
  CHECK_THROWS_WITH_AS(anisocap::write_capture(capture{}, dir / "capture.json"), doctest::Contains("empty"), anisocap::io_error);
  CHECK(dir.entries().empty());
}

TEST_CASE("load_capture_images: relative files, mixed formats, sizes and pixels checked") {
  test_folder dir;
  fs::create_directory(dir / "sub");
  capture c = sample_capture();
  image a(6, 4, 3), b(6, 4, 3), d(6, 4, 1);
  for (int i = 0; i < 24; ++i) {
    a.plane(0)[i] = a.plane(1)[i] = a.plane(2)[i] = float(i);
    b.plane(0)[i] = b.plane(1)[i] = b.plane(2)[i] = 0.5f;
    d.plane(0)[i] = 0.25f * float(i);
  }
  anisocap::write_exr(a, dir / "input_00.exr");
  anisocap::write_png(b, dir / "input_01.png");
  anisocap::write_exr(d, dir / "sub" / "input_02.exr");
  anisocap::write_capture(c, dir / "capture.json");
  const auto images = anisocap::load_capture_images(anisocap::read_capture(dir / "capture.json"), dir.path());
  REQUIRE(images.size() == 3);
  for (const image& img : images) {
    CHECK(img.channels() == 3);
    CHECK(img.width() == 6);
    CHECK(img.height() == 4);
  }
  CHECK(images[0].at(2, 5, 3) == 23.0f);
  CHECK(images[1].at(0, 0, 0) == doctest::Approx(0.5).epsilon(0.01));
  CHECK(images[2].at(1, 1, 1) == 0.25f * 7);

  // A different size names the file, its index and both sizes.
  anisocap::write_exr(image(5, 4, 3), dir / "sub" / "input_02.exr");
  std::string e;
  try { anisocap::load_capture_images(c, dir.path()); } catch (const anisocap::io_error& x) { e = x.what(); }
  CHECK(contains(e, "input_02.exr"));
  CHECK(contains(e, "image 2 is 5x4"));
  CHECK(contains(e, "input_00.exr) is 6x4"));
  // A NaN pixel names the file, the pixel and the image index.
  d.at(0, 2, 1) = std::numeric_limits<float>::quiet_NaN();
  anisocap::write_exr(d, dir / "sub" / "input_02.exr");
  e.clear();
  try { anisocap::load_capture_images(c, dir.path()); } catch (const anisocap::io_error& x) { e = x.what(); }
  CHECK(contains(e, "input_02.exr"));
  CHECK(contains(e, "x=2, y=1"));
  CHECK(contains(e, "NaN"));
  CHECK(contains(e, "capture image 2"));
  // A negative pixel too.
  a.at(1, 0, 0) = -0.25f;
  anisocap::write_exr(a, dir / "input_00.exr");
  e.clear();
  try { anisocap::load_capture_images(c, dir.path()); } catch (const anisocap::io_error& x) { e = x.what(); }
  CHECK(contains(e, "input_00.exr"));
  CHECK(contains(e, "negative"));
  // A missing file.
  fs::remove(dir / "input_01.png");
  e.clear();
  try { anisocap::load_capture_images(sample_capture(), dir / "elsewhere"); } catch (const anisocap::io_error& x) { e = x.what(); }
  CHECK(contains(e, "elsewhere/input_00.exr: file not found"));
}
