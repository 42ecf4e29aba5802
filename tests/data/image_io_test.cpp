// Tests for data/image_io.hpp: EXR and PNG round trips, exact sRGB linearisation, 16-bit PNG input
// (through a tiny PNG writer below, since stb cannot write 16-bit), validation and atomic writes.
#include <doctest/doctest.h>
#include <omp.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstring>
#include <cstdint>
#include <fstream>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/core/parallel.hpp"
#include "anisocap/data/image_io.hpp"
#include "data/png16_writer.hpp"
#include "data/test_folder.hpp"
#include "support/error_of.hpp"

using anisocap::image;
using anisocap::io_error;
using anisocap::testing::png16;
using anisocap::testing::test_folder;
namespace fs = std::filesystem;

using anisocap::testing::error_of;

namespace {

void write_bytes(const fs::path& path, const std::vector<unsigned char>& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

image random_image(int w, int h, int channels, std::uint32_t seed, float lo, float hi) {
  image img(w, h, channels);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(lo, hi);
  for (int c = 0; c < channels; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) img.at(c, x, y) = u(rng);
  return img;
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

bool no_temporaries(const test_folder& dir) {
  for (const auto& name : dir.entries())
    if (contains(name, std::string(anisocap::file_transaction::temporary_marker))) return false;
  return true;
}

}  // namespace

TEST_CASE("sRGB curve: exact at known values and inverse of itself") {
  CHECK(anisocap::srgb_to_linear(0.0) == 0.0);
  CHECK(anisocap::srgb_to_linear(1.0) == doctest::Approx(1.0).epsilon(1e-15));
  CHECK(anisocap::srgb_to_linear(0.04045) == doctest::Approx(0.04045 / 12.92).epsilon(1e-12));
  CHECK(anisocap::srgb_to_linear(0.5) == doctest::Approx(0.21404114048223255).epsilon(1e-12));
  CHECK(anisocap::srgb_to_linear(128.0 / 255.0) == doctest::Approx(0.21586050011389923).epsilon(1e-12));
  CHECK(anisocap::linear_to_srgb(0.18) == doctest::Approx(0.46135612950044164).epsilon(1e-12));
  // The two pieces meet (continuity at the threshold within the standard's rounding).
  CHECK(std::fabs(0.04045 / 12.92 - std::pow((0.04045 + 0.055) / 1.055, 2.4)) < 1e-7);
  for (int i = 0; i <= 1000; ++i) {
    const double v = i / 1000.0;
    CHECK(anisocap::linear_to_srgb(anisocap::srgb_to_linear(v)) == doctest::Approx(v).epsilon(1e-12));
  }
}

TEST_CASE("EXR: float32 RGB and one-channel round trips are bit-exact") {
  test_folder dir;
  const image rgb = random_image(37, 23, 3, 1, -5.0f, 1000.0f);
  anisocap::write_exr(rgb, dir / "rgb.exr");
  const image back = anisocap::read_image(dir / "rgb.exr");
  REQUIRE(back.width() == 37);
  REQUIRE(back.height() == 23);
  REQUIRE(back.channels() == 3);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < 23; ++y)
      for (int x = 0; x < 37; ++x) REQUIRE(back.at(c, x, y) == rgb.at(c, x, y));

  const image grey = random_image(5, 9, 1, 2, 0.0f, 2.0f);
  anisocap::write_image(grey, dir / "grey.EXR");  // extension case does not matter
  const image g = anisocap::read_exr(dir / "grey.EXR");
  REQUIRE(g.channels() == 3);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < 9; ++y)
      for (int x = 0; x < 5; ++x) REQUIRE(g.at(c, x, y) == grey.at(0, x, y));
  CHECK(no_temporaries(dir));
  CHECK(dir.entries() == std::vector<std::string>{"grey.EXR", "rgb.exr"});
}

TEST_CASE("EXR: half channels, RGBA (alpha ignored) and Y with other channels") {
  test_folder dir;
  const int w = 4, h = 2;
  // Values exactly representable in half precision.
  std::vector<float> r = {0.5f, 1.25f, 3.0f, 1024.0f, 0.0f, 0.125f, 7.5f, 65504.0f};
  std::vector<float> g(r.rbegin(), r.rend()), b(8, 2.0f), a(8, 0.25f);
  {
    const float* planes[4] = {a.data(), b.data(), g.data(), r.data()};
    const char* names[4] = {"A", "B", "G", "R"};
    const auto bytes = anisocap::detail::encode_exr(planes, names, 4, w, h, true, dir / "half.exr");
    anisocap::write_file_atomically(dir / "half.exr", std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
  }
  const image img = anisocap::read_exr(dir / "half.exr");
  REQUIRE(img.channels() == 3);
  for (int i = 0; i < w * h; ++i) {
    CHECK(img.plane(0)[i] == r[std::size_t(i)]);
    CHECK(img.plane(1)[i] == g[std::size_t(i)]);
    CHECK(img.plane(2)[i] == b[std::size_t(i)]);
  }
  {
    const float* planes[2] = {a.data(), r.data()};
    const char* names[2] = {"A", "Y"};
    const auto bytes = anisocap::detail::encode_exr(planes, names, 2, w, h, false, dir / "y.exr");
    write_bytes(dir / "y.exr", bytes);
  }
  const image y = anisocap::read_exr(dir / "y.exr");
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < w * h; ++i) CHECK(y.plane(c)[i] == r[std::size_t(i)]);
  {
    const float* planes[2] = {a.data(), r.data()};
    const char* names[2] = {"U", "V"};
    write_bytes(dir / "uv.exr", anisocap::detail::encode_exr(planes, names, 2, w, h, false, dir / "uv.exr"));
  }
  const std::string e = error_of([&] { anisocap::read_exr(dir / "uv.exr"); });
  CHECK(contains(e, "uv.exr"));
  CHECK(contains(e, "expected channels R, G, B"));
  CHECK(contains(e, "U, V"));
}

TEST_CASE("PNG 8-bit: sRGB decoding is exact and sRGB previews round trip on the code grid") {
  test_folder dir;
  const int w = 16, h = 16;
  image codes(w, h, 3);
  for (int i = 0; i < w * h; ++i) {
    // linear-encoded preview stores code = value * 255; reading takes the code as sRGB.
    codes.plane(0)[i] = float(i) / 255.0f;
    codes.plane(1)[i] = float(255 - i) / 255.0f;
    codes.plane(2)[i] = float((i * 7) % 256) / 255.0f;
  }
  anisocap::write_png(codes, dir / "codes.png", 0.0f, anisocap::png_encoding::linear);
  const image back = anisocap::read_png(dir / "codes.png");
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < w * h; ++i) {
      const int code = int(std::lround(codes.plane(c)[i] * 255.0f));
      REQUIRE(back.plane(c)[i] == float(anisocap::srgb_to_linear(code / 255.0)));
    }
  // An sRGB preview of linear values on the decoded grid reads back to the same values.
  anisocap::write_png(back, dir / "again.png");
  const image again = anisocap::read_image(dir / "again.png");
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < w * h; ++i) REQUIRE(again.plane(c)[i] == back.plane(c)[i]);
  // Exposure: +1 stop doubles before clamping; values above 1 clamp to 255.
  image half(1, 1, 1);
  half.plane(0)[0] = 0.25f;
  anisocap::write_png(half, dir / "exposed.png", 1.0f);
  CHECK(anisocap::read_png(dir / "exposed.png").plane(0)[0] == doctest::Approx(0.5).epsilon(0.01));
  half.plane(0)[0] = 7.0f;
  anisocap::write_png(half, dir / "clamped.png");
  CHECK(anisocap::read_png(dir / "clamped.png").plane(2)[0] == 1.0f);
  half.plane(0)[0] = std::numeric_limits<float>::quiet_NaN();
  anisocap::write_png(half, dir / "nan.png");
  CHECK(anisocap::read_png(dir / "nan.png").plane(1)[0] == 0.0f);
  CHECK(no_temporaries(dir));
}

TEST_CASE("PNG 8-bit grey + alpha: grey replicated, alpha ignored") {
  test_folder dir;
  const unsigned char pixels[] = {0, 10, 128, 20, 255, 30};  // (grey, alpha) x 3
  REQUIRE(stbi_write_png((dir / "ga.png").c_str(), 3, 1, 2, pixels, 6));
  const image img = anisocap::read_png(dir / "ga.png");
  REQUIRE(img.width() == 3);
  for (int c = 0; c < 3; ++c) {
    CHECK(img.at(c, 0, 0) == 0.0f);
    CHECK(img.at(c, 1, 0) == float(anisocap::srgb_to_linear(128 / 255.0)));
    CHECK(img.at(c, 2, 0) == 1.0f);
  }
}

TEST_CASE("PNG 16-bit: full precision, grey and RGB") {
  test_folder dir;
  const int w = 300, h = 200;  // 360 kB of samples: several stored deflate blocks
  std::vector<std::uint16_t> rgb(std::size_t(w * h * 3));
  for (std::size_t i = 0; i < rgb.size(); ++i) rgb[i] = std::uint16_t((i * 2654435761u) >> 16);
  write_bytes(dir / "rgb16.png", png16(w, h, 3, rgb));
  const image img = anisocap::read_image(dir / "rgb16.png");
  REQUIRE(img.width() == w);
  REQUIRE(img.height() == h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) {
        const std::uint16_t code = rgb[std::size_t((y * w + x) * 3 + c)];
        REQUIRE(img.at(c, x, y) == float(anisocap::srgb_to_linear(code / 65535.0)));
      }
  const std::vector<std::uint16_t> grey = {1000, 1001, 0, 65535};
  write_bytes(dir / "grey16.png", png16(2, 2, 1, grey));
  const image g = anisocap::read_png(dir / "grey16.png");
  CHECK(g.at(0, 0, 0) < g.at(0, 1, 0));  // adjacent 16-bit codes stay distinct (no 8-bit reduction)
  CHECK(g.at(2, 0, 1) == 0.0f);
  CHECK(g.at(1, 1, 1) == 1.0f);
}

TEST_CASE("image files: clear errors naming the file") {
  test_folder dir;
  std::string e = error_of([&] { anisocap::read_image(dir / "missing.exr"); });
  CHECK(contains(e, "missing.exr"));
  CHECK(contains(e, "not found"));
  e = error_of([&] { anisocap::read_image(dir / "photo.tif"); });
  CHECK(contains(e, "photo.tif"));
  CHECK(contains(e, "unknown image type"));
  e = error_of([&] { anisocap::write_image(image(2, 2, 3), dir / "out.tif"); });
  CHECK(contains(e, "unknown image type"));
  fs::create_directory(dir / "folder.exr");
  e = error_of([&] { anisocap::read_image(dir / "folder.exr"); });
  CHECK(contains(e, "not a regular file"));

  write_bytes(dir / "garbage.exr", std::vector<unsigned char>(100, 0x42));
  e = error_of([&] { anisocap::read_image(dir / "garbage.exr"); });
  CHECK(contains(e, "garbage.exr"));
  CHECK(contains(e, "not an OpenEXR file"));

  // Truncated files at many lengths: always an io_error, never a crash.
  anisocap::write_exr(random_image(40, 30, 3, 3, 0.0f, 1.0f), dir / "good.exr");
  anisocap::write_png(random_image(40, 30, 3, 4, 0.0f, 1.0f), dir / "good.png");
  for (const char* name : {"good.exr", "good.png"}) {
    const auto bytes = anisocap::read_file_bytes(dir / name);
    for (std::size_t cut : {std::size_t(5), std::size_t(40), bytes.size() / 3, bytes.size() / 2, bytes.size() - 20}) {
      const fs::path bad = dir / (std::string("cut_") + name);
      write_bytes(bad, std::vector<unsigned char>(bytes.begin(), bytes.begin() + std::ptrdiff_t(cut)));
      CAPTURE(cut);
      e = error_of([&] { anisocap::read_image(bad); });
      CHECK(contains(e, bad.string()));
    }
  }
  // An EXR under a .png name is refused by signature.
  fs::copy_file(dir / "good.exr", dir / "fake.png");
  e = error_of([&] { anisocap::read_image(dir / "fake.png"); });
  CHECK(contains(e, "not a PNG"));
  // Writing into a folder that does not exist: error, nothing left behind.
  e = error_of([&] { anisocap::write_exr(image(2, 2, 3), dir / "no_such_folder" / "x.exr"); });
  CHECK(contains(e, "x.exr"));
  CHECK(contains(e, "cannot create"));
  e = error_of([&] { anisocap::write_exr(image(2, 2, 2), dir / "two.exr"); });
  CHECK(contains(e, "1 or 3 channels"));
  CHECK(!fs::exists(dir / "two.exr"));
  CHECK(no_temporaries(dir));
}

TEST_CASE("validate_pixels: NaN, infinite and negative pixels name the file, pixel and value") {
  test_folder dir;
  image img = random_image(8, 6, 3, 5, 0.0f, 1.0f);
  CHECK_NOTHROW(anisocap::validate_pixels(img, "ok.exr"));
  img.at(1, 3, 2) = -0.0f;  // negative zero is zero
  CHECK_NOTHROW(anisocap::validate_pixels(img, "ok.exr"));

  img.at(1, 3, 2) = std::numeric_limits<float>::quiet_NaN();
  img.at(0, 5, 4) = -1.0f;
  anisocap::write_exr(img, dir / "input_07.exr");
  const image back = anisocap::read_image(dir / "input_07.exr");
  std::string e = error_of([&] { anisocap::validate_pixels(back, dir / "input_07.exr"); });
  CHECK(contains(e, "input_07.exr"));
  CHECK(contains(e, "x=3, y=2"));
  CHECK(contains(e, "channel G"));
  CHECK(contains(e, "NaN"));
  CHECK(contains(e, "2 bad values"));

  img.at(1, 3, 2) = 0.5f;
  e = error_of([&] { anisocap::validate_pixels(img, "a.exr"); });
  CHECK(contains(e, "x=5, y=4"));
  CHECK(contains(e, "negative (-1)"));
  img.at(0, 5, 4) = std::numeric_limits<float>::infinity();
  e = error_of([&] { anisocap::validate_pixels(img, "a.exr"); });
  CHECK(contains(e, "infinite"));
}

TEST_CASE("file_transaction: nothing appears before commit, discarded temporaries vanish") {
  test_folder dir;
  {
    anisocap::file_transaction t;
    t.stage(dir / "a.txt", "first");
    t.stage(dir / "b.txt", "second");
    CHECK(t.staged() == 2);
    CHECK(!fs::exists(dir / "a.txt"));
    CHECK(dir.entries().size() == 2);  // two hidden temporaries
    CHECK(!no_temporaries(dir));
  }  // destroyed without commit
  CHECK(dir.entries().empty());
  anisocap::write_file_atomically(dir / "a.txt", "old");
  {
    anisocap::file_transaction t;
    t.stage(dir / "a.txt", "new");
    const auto old = anisocap::read_file_bytes(dir / "a.txt");
    CHECK(std::string(old.begin(), old.end()) == "old");
    t.commit();
  }
  const auto bytes = anisocap::read_file_bytes(dir / "a.txt");
  CHECK(std::string(bytes.begin(), bytes.end()) == "new");
  CHECK(dir.entries() == std::vector<std::string>{"a.txt"});
}

TEST_CASE("file_transaction: files staged from many threads at once are all committed, each whole") {
  test_folder dir;
  anisocap::file_transaction t;
  constexpr std::size_t count = 64;
  auto file = [&](std::size_t i) {  // appended piecewise: GCC 12 warns falsely (-Wrestrict) on "f" + string
    std::string name(1, 'f');
    name.append(std::to_string(i)).append(".txt");
    return dir / name;
  };
  anisocap::for_each_index_in_parallel(count, [&](std::size_t i) { t.stage(file(i), std::string(1000 + i, char('a' + i % 26))); });
  CHECK(t.staged() == count);
  t.commit();
  CHECK(dir.entries().size() == count);
  for (std::size_t i = 0; i < count; ++i) {
    const auto bytes = anisocap::read_file_bytes(file(i));
    CHECK(std::string(bytes.begin(), bytes.end()) == std::string(1000 + i, char('a' + i % 26)));
  }
}

TEST_CASE("for_each_index_in_parallel: every job runs once, and the lowest index's exception is rethrown after all have run") {
  std::vector<int> runs(100, 0);
  anisocap::for_each_index_in_parallel(runs.size(), [&](std::size_t i) { runs[i] += 1; });
  CHECK(std::count(runs.begin(), runs.end(), 1) == 100);
  std::fill(runs.begin(), runs.end(), 0);
  CHECK_THROWS_WITH_AS(anisocap::for_each_index_in_parallel(runs.size(),
                                                            [&](std::size_t i) {
                                                              runs[i] += 1;
                                                              if (i == 70 || i == 30 || i == 99) throw std::runtime_error("job " + std::to_string(i));
                                                            }),
                       "job 30", std::runtime_error);
  CHECK(std::count(runs.begin(), runs.end(), 1) == 100);
  anisocap::for_each_index_in_parallel(0, [&](std::size_t) { FAIL("no job for n = 0"); });
}

TEST_CASE("job_batch: every job runs once, the costliest first, and the first added that threw is rethrown") {
  anisocap::job_batch batch;
  std::vector<int> order;
  const double costs[] = {1, 5, 3, 5, 0.5};
  for (int j = 0; j < 5; ++j) batch.add([&order, j] { order.push_back(j); }, costs[j]);
  CHECK(batch.size() == 5);
  {
    const int saved = omp_get_max_threads();
    omp_set_num_threads(1);  // one thread runs the jobs in the batch's order
    batch.run();
    omp_set_num_threads(saved);
  }
  CHECK(order == std::vector<int>{1, 3, 2, 0, 4});  // by cost, ties in the order added
  CHECK(batch.size() == 0);
  batch.run();  // empty: nothing runs
  CHECK(order.size() == 5);
  std::vector<std::atomic<int>> runs(40);
  for (std::size_t j = 0; j < runs.size(); ++j)
    batch.add([&runs, j] {
      runs[j] += 1;
      if (j == 5 || j == 8 || j == 14) throw std::runtime_error("job " + std::to_string(j));
    }, double(j % 5));  // job 5 (cost 0) is added first of the three and runs after 8 and 14 (cost 3, 4)
  CHECK_THROWS_WITH_AS(batch.run(), "job 5", std::runtime_error);
  for (const auto& r : runs) CHECK(r.load() == 1);
}

TEST_CASE("EXR: tiled files are reassembled from their tiles") {
  test_folder dir;
  const int w = 13, h = 10, tile = 8, tiles_x = 2, tiles_y = 2;
  auto value = [](int c, int x, int y) { return float(c * 500 + y * 20 + x); };  // < 2048: exact in half
  std::vector<std::vector<float>> buffers;  // [tile * 3 + channel], tile-size stride
  std::vector<EXRTile> tiles(tiles_x * tiles_y);
  std::vector<std::array<float*, 3>> pointers(tiles.size());
  buffers.reserve(tiles.size() * 3);
  for (int ty = 0; ty < tiles_y; ++ty)
    for (int tx = 0; tx < tiles_x; ++tx) {
      const std::size_t t = std::size_t(ty * tiles_x + tx);
      std::memset(&tiles[t], 0, sizeof(EXRTile));
      tiles[t].offset_x = tx;
      tiles[t].offset_y = ty;
      tiles[t].width = std::min(tile, w - tx * tile);
      tiles[t].height = std::min(tile, h - ty * tile);
      for (int c = 0; c < 3; ++c) {
        buffers.emplace_back(std::size_t(tile * tile), 0.0f);
        for (int j = 0; j < tiles[t].height; ++j)
          for (int i = 0; i < tiles[t].width; ++i)
            buffers.back()[std::size_t(j * tile + i)] = value(2 - c, tx * tile + i, ty * tile + j);  // B, G, R
        pointers[t][std::size_t(c)] = buffers.back().data();
      }
      tiles[t].images = reinterpret_cast<unsigned char**>(pointers[t].data());
    }
  EXRHeader header;
  InitEXRHeader(&header);
  EXRImage exr;
  InitEXRImage(&exr);
  EXRChannelInfo info[3];
  std::memset(info, 0, sizeof info);
  std::strcpy(info[0].name, "B");
  std::strcpy(info[1].name, "G");
  std::strcpy(info[2].name, "R");
  int types[3] = {TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT, TINYEXR_PIXELTYPE_FLOAT};
  int requested[3] = {TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF, TINYEXR_PIXELTYPE_HALF};
  header.num_channels = 3;
  header.channels = info;
  header.pixel_types = types;
  header.requested_pixel_types = requested;
  header.compression_type = TINYEXR_COMPRESSIONTYPE_ZIP;
  header.tiled = 1;
  header.tile_size_x = tile;
  header.tile_size_y = tile;
  header.tile_level_mode = TINYEXR_TILE_ONE_LEVEL;
  header.tile_rounding_mode = TINYEXR_TILE_ROUND_DOWN;
  header.data_window = {0, 0, w - 1, h - 1};
  header.display_window = {0, 0, w - 1, h - 1};
  exr.num_channels = 3;
  exr.width = w;
  exr.height = h;
  exr.tiles = tiles.data();
  exr.num_tiles = int(tiles.size());
  const char* error = nullptr;
  REQUIRE(SaveEXRImageToFile(&exr, &header, (dir / "tiled.exr").c_str(), &error) == TINYEXR_SUCCESS);
  const image img = anisocap::read_exr(dir / "tiled.exr");
  REQUIRE(img.width() == w);
  REQUIRE(img.height() == h);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) REQUIRE(img.at(c, x, y) == value(c, x, y));
}

TEST_CASE("PNG preview codes equal rounding of the exactly encoded value") {
  const int w = 256, h = 64;
  image img(w, h, 3);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-0.1f, 1.2f);
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < img.pixel_count(); ++i) img.plane(c)[i] = c == 0 ? float(i) / float(w * h) : u(rng);
  for (auto encoding : {anisocap::png_encoding::srgb, anisocap::png_encoding::linear}) {
    for (float stops : {0.0f, -1.5f}) {
      const auto bytes = anisocap::encode_png(img, "codes.png", stops, encoding);
      int x = 0, y = 0, n = 0;
      std::unique_ptr<unsigned char, void (*)(void*)> codes(stbi_load_from_memory(bytes.data(), int(bytes.size()), &x, &y, &n, 3), &stbi_image_free);
      REQUIRE(codes);
      REQUIRE(x == w);
      for (int c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < img.pixel_count(); ++i) {
          const double v = std::clamp(double(img.plane(c)[i]) * std::exp2(double(stops)), 0.0, 1.0);
          const double encoded = encoding == anisocap::png_encoding::srgb ? anisocap::linear_to_srgb(v) : v;
          const long expected = std::lround(encoded * 255.0);
          const double tie_distance = std::fabs(encoded * 255.0 - std::floor(encoded * 255.0) - 0.5);
          if (tie_distance > 1e-9) REQUIRE(codes.get()[i * 3 + std::size_t(c)] == expected);
        }
    }
  }
}

TEST_CASE("PNG 8-bit codes: the table-driven quantiser gives every value the rounded encoded code") {
  std::mt19937_64 gen(12);
  std::uniform_real_distribution<double> exponent(-30.0, 2.0);
  for (const auto encoding : {anisocap::png_encoding::srgb, anisocap::png_encoding::linear}) {
    const bool srgb = encoding == anisocap::png_encoding::srgb;
    const anisocap::detail::eight_bit_quantizer quantize(encoding);
    auto encode = [&](double v) { return srgb ? anisocap::linear_to_srgb(v) : v; };
    std::vector<double> bounds;
    for (int k = 0; k < 255; ++k) bounds.push_back(srgb ? anisocap::srgb_to_linear((k + 0.5) / 255.0) : (k + 0.5) / 255.0);
    // The definition: the number of code boundaries at or below the value, NaN and negatives as 0.
    auto reference = [&](double v) {
      if (!(v > 0)) v = 0;
      return int(std::upper_bound(bounds.begin(), bounds.end(), v) - bounds.begin());
    };
    std::vector<double> values = {0.0, -0.0, -1.0, 1.0, 2.0, std::nextafter(1.0, 0.0), 0x1p-16, std::nextafter(0x1p-16, 0.0),
                                  std::nextafter(0x1p-16, 1.0), 1e-310, std::numeric_limits<double>::infinity(),
                                  -std::numeric_limits<double>::infinity(), std::numeric_limits<double>::quiet_NaN()};
    for (double b : bounds) values.insert(values.end(), {b, std::nextafter(b, 0.0), std::nextafter(b, 2.0)});
    for (int i = 0; i < 200000; ++i) values.push_back(std::exp2(exponent(gen)));
    int rounded_checked = 0;
    for (double v : values) {
      const int code = quantize(v);
      REQUIRE(code == reference(v));
      // Away from a boundary it is the rounded encoded value.
      const double e = std::clamp(encode(std::max(v, 0.0)), 0.0, 1.0) * 255.0;
      if (std::isfinite(e) && std::abs(e - std::floor(e) - 0.5) > 1e-6) {
        REQUIRE(code == int(std::lround(e)));
        ++rounded_checked;
      }
    }
    CHECK(rounded_checked > 190000);
  }
}
