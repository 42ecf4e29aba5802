// Tests for data/photo_io.hpp and the new input formats of data/image_io.hpp: JPEG, 8/16-bit PNG
// and Radiance HDR read as linear radiance; clipped pixels found at the format's largest code or a
// saturation level; exposure factors; mask files combined with the clip mask; clear errors.
#include <doctest/doctest.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <stb/stb_image_write.h>

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/photo_io.hpp"
#include "data/png16_writer.hpp"
#include "data/test_folder.hpp"
#include "support/error_of.hpp"

using anisocap::capture;
using anisocap::image;
using anisocap::photo;
using anisocap::photo_options;
using anisocap::testing::png16;
using anisocap::testing::test_folder;
namespace fs = std::filesystem;

using anisocap::testing::error_of;

namespace {

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

void write_bytes(const fs::path& path, const std::vector<unsigned char>& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

float srgb(int code, int levels = 256) { return float(anisocap::srgb_to_linear(double(code) / double(levels - 1))); }

/// One capture entry looking straight down, for load_capture_photos.
anisocap::capture_image entry(const std::string& file, const std::string& mask = "", float exposure = 1.0f) {
  return {file, {0.0f, 0.0f, 2.0f}, {0.1f, 0.0f, 2.0f}, {1.0f, 1.0f, 1.0f}, mask, exposure};
}

}  // namespace

TEST_CASE("8-bit PNG: linearised, a pixel with any channel at 255 is clipped and masked") {
  test_folder dir;
  // 4 x 2 RGB: (255, 10, 10) clipped by its red channel alone, (254, 254, 254) not clipped.
  const unsigned char codes[] = {255, 10, 10, 254, 254, 254, 0, 0, 0, 128, 64, 32,
                                 10, 255, 10, 10, 10, 255, 255, 255, 255, 200, 100, 50};
  REQUIRE(stbi_write_png((dir / "p.png").c_str(), 4, 2, 3, codes, 12));
  const photo p = anisocap::read_photo(dir / "p.png");
  REQUIRE(p.pixels.width() == 4);
  REQUIRE(p.mask.channels() == 1);
  CHECK(p.pixels.at(0, 0, 0) == 1.0f);
  CHECK(p.pixels.at(1, 3, 0) == srgb(64));
  CHECK(p.pixels.at(2, 1, 0) == srgb(254));
  const float expected_mask[] = {0, 1, 1, 1, 0, 0, 0, 1};
  for (int i = 0; i < 8; ++i) CHECK(p.mask.plane(0)[i] == expected_mask[i]);
  CHECK(p.clipped == 4);
  CHECK(p.masked == 4);
  CHECK(p.clipped_fraction() == 0.5);

  // Fitted on request: counted, not masked.
  photo_options fit;
  fit.exclude_clipped = false;
  const photo q = anisocap::read_photo(dir / "p.png", fit);
  CHECK(q.clipped == 4);
  CHECK(q.masked == 0);
  CHECK(q.mask.plane(0)[0] == 1.0f);

  // The exposure factor scales the linear values; the clip test uses the codes, before it.
  photo_options bright;
  bright.exposure = 4.0f;
  const photo r = anisocap::read_photo(dir / "p.png", bright);
  CHECK(r.pixels.at(1, 3, 0) == srgb(64) * 4.0f);
  CHECK(r.clipped == 4);

  // A saturation level also clips 8-bit pixels below the largest code (254 is 0.9911 linear).
  photo_options level;
  level.saturation = 0.99f;
  CHECK(anisocap::read_photo(dir / "p.png", level).clipped == 5);
}

TEST_CASE("16-bit PNG: read through the 16-bit loader, clipped only at 65535") {
  test_folder dir;
  const std::vector<std::uint16_t> rgb = {65535, 0, 0, 65534, 65534, 65534, 1000, 30000, 65535, 257, 257, 257};
  write_bytes(dir / "p16.png", png16(2, 2, 3, rgb));
  const photo p = anisocap::read_photo(dir / "p16.png");
  CHECK(p.pixels.at(0, 1, 0) == srgb(65534, 65536));
  CHECK(p.pixels.at(0, 1, 0) < 1.0f);
  CHECK(p.pixels.at(1, 0, 1) == srgb(30000, 65536));
  CHECK(p.mask.plane(0)[0] == 0.0f);
  CHECK(p.mask.plane(0)[1] == 1.0f);  // 65534 is not clipped: no reduction to 8 bits
  CHECK(p.mask.plane(0)[2] == 0.0f);
  CHECK(p.mask.plane(0)[3] == 1.0f);
  CHECK(p.clipped == 2);
}

TEST_CASE("JPEG: linearised sRGB, saturated blocks clipped, the rest not") {
  test_folder dir;
  // 16 x 16: the left 8 columns white (255), the right 8 columns grey 128 (whole 8 x 8 blocks, so
  // the DCT reproduces each block's constant exactly at quality 100).
  const int w = 16, h = 16;
  std::vector<unsigned char> codes(std::size_t(w * h * 3));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int c = 0; c < 3; ++c) codes[std::size_t((y * w + x) * 3 + c)] = x < 8 ? 255 : 128;
  REQUIRE(stbi_write_jpg((dir / "IMG_0001.jpg").c_str(), w, h, 3, codes.data(), 100));
  for (const char* name : {"IMG_0001.jpg", "IMG_0001.JPEG"}) {
    if (std::string(name) != "IMG_0001.jpg") fs::copy_file(dir / "IMG_0001.jpg", dir / name);
    const photo p = anisocap::read_photo(dir / name);
    CHECK(p.clipped == 128);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        CHECK(p.mask.at(0, x, y) == (x < 8 ? 0.0f : 1.0f));
        if (x >= 8) CHECK(p.pixels.at(1, x, y) == doctest::Approx(srgb(128)).epsilon(0.02));
      }
  }
  CHECK(anisocap::read_image(dir / "IMG_0001.jpg").at(0, 0, 0) == 1.0f);
  // A PNG under a .jpg name is refused by name.
  const unsigned char one[] = {1, 2, 3};
  REQUIRE(stbi_write_png((dir / "fake.jpg").c_str(), 1, 1, 3, one, 3));
  const std::string e = error_of([&] { anisocap::read_photo(dir / "fake.jpg"); });
  CHECK(contains(e, "fake.jpg"));
  CHECK(contains(e, "not a JPEG file"));
  write_bytes(dir / "cut.jpg", {0xFF, 0xD8, 0xFF, 0xE0, 0x00});
  CHECK(contains(error_of([&] { anisocap::read_image(dir / "cut.jpg"); }), "cut.jpg: corrupt JPEG"));
}

namespace {

/// The bytes of a JPEG up to its frame header: SOI, an APP0 segment, then a frame header of
/// `marker` (SOF0 0xC0, SOF2 0xC2, ...) whose components have the sampling factors `factors`
/// (horizontal << 4 | vertical), after `before` (whole segments placed ahead of it).
std::vector<unsigned char> jpeg_header(unsigned char marker, const std::vector<unsigned char>& factors,
                                       const std::vector<unsigned char>& before = {}) {
  std::vector<unsigned char> b = before;  // the segments ahead of the frame header, then prefixed below
  const std::vector<unsigned char> start = {0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x06, 'J', 'F', 'I', 'F'};
  b.insert(b.begin(), start.begin(), start.end());
  const auto count = static_cast<unsigned char>(factors.size());
  for (const unsigned char v : {0xFF, int(marker), 0x00, 8 + 3 * int(count), 8, 0x00, 0x10, 0x00, 0x10, int(count)})
    b.push_back(static_cast<unsigned char>(v));
  for (unsigned char c = 0; c < count; ++c) {
    b.push_back(static_cast<unsigned char>(c + 1));
    b.push_back(factors[c]);
    b.push_back(0);
  }
  return b;
}

}  // namespace

TEST_CASE("JPEG colour subsampling: read from the frame header; each photograph's encoding set on its capture entry") {
  using anisocap::jpeg_colour_subsampled;
  CHECK(jpeg_colour_subsampled(jpeg_header(0xC0, {0x22, 0x11, 0x11})));   // 4:2:0
  CHECK(jpeg_colour_subsampled(jpeg_header(0xC0, {0x21, 0x11, 0x11})));   // 4:2:2
  CHECK(jpeg_colour_subsampled(jpeg_header(0xC2, {0x22, 0x11, 0x11})));   // progressive
  CHECK(jpeg_colour_subsampled(jpeg_header(0xC1, {0x12, 0x12, 0x11})));   // one chroma plane at half height
  CHECK(!jpeg_colour_subsampled(jpeg_header(0xC0, {0x11, 0x11, 0x11})));  // 4:4:4
  CHECK(!jpeg_colour_subsampled(jpeg_header(0xC0, {0x22, 0x22, 0x22})));  // every plane alike
  CHECK(!jpeg_colour_subsampled(jpeg_header(0xC0, {0x22})));              // grey
  // A Huffman table (C4, not a frame header) whose bytes would read as factors is skipped, and so
  // are fill bytes before a marker.
  const std::vector<unsigned char> table = {0xFF, 0xC4, 0x00, 0x0B, 8, 0, 16, 0, 16, 3, 1, 0x22, 0};
  CHECK(!jpeg_colour_subsampled(jpeg_header(0xC0, {0x11, 0x11, 0x11}, table)));
  CHECK(jpeg_colour_subsampled(jpeg_header(0xC0, {0x22, 0x11, 0x11}, {0xFF, 0xFF})));
  // Not a JPEG, cut inside the frame header, or a scan before any frame header: false.
  const std::vector<unsigned char> whole = jpeg_header(0xC0, {0x22, 0x11, 0x11});
  REQUIRE(whole.size() > 4);
  const std::vector<unsigned char> cut(whole.begin(), whole.end() - 4);
  CHECK(!jpeg_colour_subsampled(cut));
  CHECK(!jpeg_colour_subsampled(std::vector<unsigned char>{0x89, 'P', 'N', 'G', 0, 0, 0, 0}));
  CHECK(!jpeg_colour_subsampled(std::vector<unsigned char>{0xFF, 0xD8, 0xFF, 0xDA, 0x00, 0x02, 0xFF, 0xC0}));
  CHECK(!jpeg_colour_subsampled(std::vector<unsigned char>{}));

  // stb_image_write stores the colour at half resolution at quality 90 and below, in full above.
  test_folder dir;
  const int w = 16, h = 16;
  std::vector<unsigned char> codes(std::size_t(w * h * 3));
  for (std::size_t i = 0; i < codes.size(); ++i) codes[i] = static_cast<unsigned char>(i * 37 % 200 + 20);
  REQUIRE(stbi_write_jpg((dir / "q90.jpg").c_str(), w, h, 3, codes.data(), 90));
  REQUIRE(stbi_write_jpg((dir / "q95.jpg").c_str(), w, h, 3, codes.data(), 95));
  REQUIRE(stbi_write_png((dir / "full.png").c_str(), w, h, 3, codes.data(), w * 3));
  using anisocap::photo_encoding;
  CHECK(anisocap::read_photo(dir / "q90.jpg").encoding == photo_encoding::jpeg_subsampled);
  CHECK(anisocap::read_photo(dir / "q95.jpg").encoding == photo_encoding::jpeg);
  CHECK(anisocap::read_photo(dir / "full.png").encoding == photo_encoding::eight_bit);
  const std::vector<std::uint16_t> deep(std::size_t(w * h * 3), 30000);
  write_bytes(dir / "deep.png", png16(w, h, 3, deep));
  CHECK(anisocap::read_photo(dir / "deep.png").encoding == photo_encoding::lossless);

  // read_capture_photographs sets each entry's encoding from its file; a lossier one given in
  // capture.json stays (a rectified photograph stored losslessly from a JPEG).
  capture c;
  c.images = {entry("q90.jpg"), entry("q95.jpg"), entry("full.png"), entry("copy.png")};
  fs::copy_file(dir / "full.png", dir / "copy.png");
  c.images[1].encoding = photo_encoding::jpeg_subsampled;
  c.images[3].encoding = photo_encoding::jpeg;
  anisocap::write_capture(c, dir / "capture.json");
  const anisocap::capture_photographs input = anisocap::read_capture_photographs(dir / "capture.json");
  CHECK(input.description.images[0].encoding == photo_encoding::jpeg_subsampled);
  CHECK(input.description.images[1].encoding == photo_encoding::jpeg_subsampled);
  CHECK(input.description.images[2].encoding == photo_encoding::eight_bit);
  CHECK(input.description.images[3].encoding == photo_encoding::jpeg);
  capture short_capture = c;
  short_capture.images.pop_back();
  CHECK_THROWS_WITH_AS(anisocap::set_photo_encodings(short_capture, input.photos),
                       "set_photo_encodings: one photograph per image of the capture", std::invalid_argument);
}

TEST_CASE("Radiance HDR: linear values, clipping only above a given saturation level") {
  test_folder dir;
  // Powers of two and small integers are exact in RGBE.
  const float values[] = {0.5f, 0.25f, 2.0f, 4.0f, 8.0f, 1.0f, 0.0f, 0.125f, 3.0f};
  REQUIRE(stbi_write_hdr((dir / "sky.hdr").c_str(), 3, 1, 3, values));
  const photo p = anisocap::read_photo(dir / "sky.hdr");
  for (int x = 0; x < 3; ++x)
    for (int c = 0; c < 3; ++c) CHECK(p.pixels.at(c, x, 0) == values[x * 3 + c]);
  CHECK(p.clipped == 0);  // no largest code in a linear file: off unless a level is given
  photo_options o;
  o.saturation = 4.0f;
  o.exposure = 0.5f;
  const photo q = anisocap::read_photo(dir / "sky.hdr", o);
  CHECK(q.clipped == 1);  // the second pixel reaches 4 (and 8) before the exposure factor
  CHECK(q.mask.plane(0)[1] == 0.0f);
  CHECK(q.pixels.at(2, 0, 0) == 1.0f);  // 2 * 0.5
  CHECK(anisocap::read_image(dir / "sky.hdr").at(0, 1, 0) == 4.0f);
  // An 8-bit file named .hdr is refused, not gamma-expanded.
  const unsigned char one[] = {1, 2, 3};
  REQUIRE(stbi_write_png((dir / "fake.hdr").c_str(), 1, 1, 3, one, 3));
  const std::string e = error_of([&] { anisocap::read_image(dir / "fake.hdr"); });
  CHECK(contains(e, "fake.hdr"));
  CHECK(contains(e, "not a Radiance HDR file"));
}

TEST_CASE("EXR photographs: saturation level, NaN and negative pixels keep their errors") {
  test_folder dir;
  image img(3, 2, 3);
  for (int c = 0; c < 3; ++c)
    for (int i = 0; i < 6; ++i) img.plane(c)[i] = 0.5f * float(i);
  anisocap::write_exr(img, dir / "a.exr");
  CHECK(anisocap::read_photo(dir / "a.exr").clipped == 0);
  photo_options o;
  o.saturation = 1.5f;
  const photo p = anisocap::read_photo(dir / "a.exr", o);
  CHECK(p.clipped == 3);  // 1.5, 2.0, 2.5
  CHECK(p.mask.plane(0)[2] == 1.0f);
  CHECK(p.mask.plane(0)[3] == 0.0f);
  img.at(1, 2, 1) = std::numeric_limits<float>::quiet_NaN();
  anisocap::write_exr(img, dir / "nan.exr");
  const std::string e = error_of([&] { anisocap::read_photo(dir / "nan.exr", o); });
  CHECK(contains(e, "nan.exr"));
  CHECK(contains(e, "x=2, y=1"));
  CHECK(contains(e, "NaN"));
  photo_options bad;
  bad.exposure = 0.0f;
  CHECK(contains(error_of([&] { anisocap::read_photo(dir / "a.exr", bad); }), "exposure must be a positive"));
  bad = {};
  bad.saturation = -1.0f;
  CHECK(contains(error_of([&] { anisocap::read_photo(dir / "a.exr", bad); }), "saturation must be"));
}

TEST_CASE("read_mask: weights, one channel or RGB, PNG codes as stored or EXR values, 0 = ignore; size checked") {
  test_folder dir;
  // PNG: the code over 255, not sRGB-decoded (128 is half weight, not 0.22).
  const unsigned char grey[] = {0, 255, 1, 0, 128, 0};
  REQUIRE(stbi_write_png((dir / "m1.png").c_str(), 3, 2, 1, grey, 3));
  image m = anisocap::read_mask(dir / "m1.png", 3, 2);
  for (int i = 0; i < 6; ++i) CHECK(m.plane(0)[i] == doctest::Approx(grey[i] / 255.0).epsilon(1e-4));
  CHECK(m.plane(0)[0] == 0.0f);
  CHECK(m.plane(0)[1] == 1.0f);
  // RGB: the largest channel.
  const unsigned char rgb[] = {0, 0, 0, 0, 0, 9, 255, 255, 255, 0, 0, 0, 3, 0, 0, 0, 0, 0};
  REQUIRE(stbi_write_png((dir / "m3.png").c_str(), 3, 2, 3, rgb, 9));
  m = anisocap::read_mask(dir / "m3.png", 3, 2);
  const float expected_rgb[] = {0, 9 / 255.0f, 1, 0, 3 / 255.0f, 0};
  for (int i = 0; i < 6; ++i) CHECK(m.plane(0)[i] == doctest::Approx(expected_rgb[i]).epsilon(1e-4));
  // EXR: the values, capped at 1.
  image e1(3, 2, 1);
  e1.plane(0)[4] = 0.5f;
  e1.plane(0)[5] = 3.0f;
  anisocap::write_exr(e1, dir / "m.exr");
  m = anisocap::read_mask(dir / "m.exr", 3, 2);
  for (int i = 0; i < 6; ++i) CHECK(m.plane(0)[i] == (i == 4 ? 0.5f : i == 5 ? 1.0f : 0.0f));
  const std::string e = error_of([&] { anisocap::read_mask(dir / "m.exr", 4, 2); });
  CHECK(contains(e, "m.exr"));
  CHECK(contains(e, "the mask is 3x2 but its photograph is 4x2"));
}

TEST_CASE("load_capture_photos: per-image exposure, mask file weights times clipping, clear errors") {
  test_folder dir;
  fs::create_directory(dir / "masks");
  // Two 4 x 1 8-bit photographs; image 0 has one clipped pixel (x = 3).
  const unsigned char a[] = {10, 10, 10, 20, 20, 20, 30, 30, 30, 255, 0, 0};
  const unsigned char b[] = {40, 40, 40, 50, 50, 50, 60, 60, 60, 70, 70, 70};
  REQUIRE(stbi_write_png((dir / "IMG_0000.png").c_str(), 4, 1, 3, a, 12));
  REQUIRE(stbi_write_jpg((dir / "IMG_0001.jpg").c_str(), 4, 1, 3, b, 100));
  const unsigned char mask[] = {0, 255, 51, 255};  // image 0: x = 0 masked by hand, x = 2 weighs 0.2
  REQUIRE(stbi_write_png((dir / "masks" / "m0.png").c_str(), 4, 1, 1, mask, 4));
  capture c;
  c.images = {entry("IMG_0000.png", "masks/m0.png"), entry("IMG_0001.jpg", "", 2.0f)};
  anisocap::write_capture(c, dir / "capture.json");
  const capture back = anisocap::read_capture(dir / "capture.json");
  auto photos = anisocap::load_capture_photos(back, dir.path());
  REQUIRE(photos.size() == 2);
  const float expected0[] = {0, 1, 0.2f, 0};  // mask file times clip mask
  for (int i = 0; i < 4; ++i) CHECK(photos[0].mask.plane(0)[i] == doctest::Approx(expected0[i]).epsilon(1e-4));
  CHECK(photos[0].clipped == 1);
  CHECK(photos[0].masked == 2);
  CHECK(photos[1].masked == 0);
  const image plain = anisocap::read_jpeg(dir / "IMG_0001.jpg");
  CHECK(photos[1].pixels.at(0, 2, 0) == plain.at(0, 2, 0) * 2.0f);
  CHECK(anisocap::photo_masks(photos).size() == 2);
  // load_capture_images: the pixels alone, exposure applied, nothing masked.
  const auto images = anisocap::load_capture_images(back, dir.path());
  CHECK(images[1].at(0, 2, 0) == photos[1].pixels.at(0, 2, 0));
  CHECK(images[0].at(0, 3, 0) == 1.0f);

  // A mask of the wrong size: one error naming the mask file and the image.
  const unsigned char small[] = {255, 255, 255};
  REQUIRE(stbi_write_png((dir / "masks" / "m0.png").c_str(), 3, 1, 1, small, 3));
  std::string e = error_of([&] { anisocap::load_capture_photos(back, dir.path()); });
  CHECK(contains(e, (dir / "masks" / "m0.png").string()));
  CHECK(contains(e, "the mask is 3x1 but its photograph is 4x1"));
  CHECK(contains(e, "capture image 0"));
  // A missing mask file.
  fs::remove(dir / "masks" / "m0.png");
  e = error_of([&] { anisocap::load_capture_photos(back, dir.path()); });
  CHECK(contains(e, "m0.png: file not found"));
  // Every pixel masked (the mask leaves out what clipping does not): a clear error naming the mask.
  const unsigned char only_clipped[] = {0, 0, 0, 255};
  REQUIRE(stbi_write_png((dir / "masks" / "m0.png").c_str(), 4, 1, 1, only_clipped, 4));
  e = error_of([&] { anisocap::load_capture_photos(back, dir.path()); });
  CHECK(contains(e, "m0.png"));
  CHECK(contains(e, "every pixel of IMG_0000.png is clipped or masked"));
  // Every pixel clipped, no mask file: the error names the photograph.
  const unsigned char white[] = {255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255};
  REQUIRE(stbi_write_png((dir / "IMG_0000.png").c_str(), 4, 1, 3, white, 12));
  capture no_mask = back;
  no_mask.images[0].mask.clear();
  e = error_of([&] { anisocap::load_capture_photos(no_mask, dir.path()); });
  CHECK(contains(e, (dir / "IMG_0000.png").string()));
  CHECK(contains(e, "clipped or masked"));
}
