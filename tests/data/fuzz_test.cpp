// Corrupted inputs: random byte changes and truncations of valid capture.json, EXR and PNG files
// must give a clean std::runtime_error (naming the file) or a valid result, never a crash.
#include <doctest/doctest.h>

#include <fstream>
#include <random>
#include <string>

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"
#include "data/test_folder.hpp"

using anisocap::testing::test_folder;
namespace fs = std::filesystem;

namespace {

/// Mutates `bytes` (1-8 random bytes replaced, sometimes truncated) and writes it to `path`.
void write_mutated(std::vector<unsigned char> bytes, const fs::path& path, std::mt19937& rng) {
  const int changes = 1 + int(rng() % 8);
  for (int k = 0; k < changes; ++k) bytes[rng() % bytes.size()] = static_cast<unsigned char>(rng());
  if (rng() % 4 == 0) bytes.resize(rng() % bytes.size());
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

}  // namespace

TEST_CASE("corrupted capture.json, EXR and PNG files give clean errors naming the file") {
  test_folder dir;
  anisocap::capture c;
  c.images.push_back({"input_00.exr", {0.1f, 0.2f, 1.0f}, {0.3f, -0.4f, 2.0f}, {1, 2, 3}, "", 1.0f});
  c.images.push_back({"input_01.png", {0.0f, 0.5f, 0.5f}, {0.0f, -0.5f, 0.5f}, {4, 4, 4}, "", 1.0f});
  anisocap::write_capture(c, dir / "capture.json");
  anisocap::image img(24, 17, 3);
  for (int ch = 0; ch < 3; ++ch)
    for (std::size_t i = 0; i < img.pixel_count(); ++i) img.plane(ch)[i] = float((i * 7 + std::size_t(ch)) % 13) / 13.0f;
  anisocap::write_exr(img, dir / "image.exr");
  anisocap::write_png(img, dir / "image.png");
  const std::string names[] = {"capture.json", "image.exr", "image.png"};
  std::mt19937 rng(2024);
  int errors = 0, successes = 0;
  for (int it = 0; it < 600; ++it) {
    const std::string& name = names[it % 3];
    const fs::path bad = dir / ("bad_" + name);
    write_mutated(anisocap::read_file_bytes(dir / name), bad, rng);
    try {
      if (it % 3 == 0) anisocap::read_capture(bad);
      else anisocap::read_image(bad);
      ++successes;  // a change in pixel data or in a number can leave a valid file
    } catch (const std::runtime_error& e) {
      ++errors;
      CHECK(std::string(e.what()).find(bad.string()) != std::string::npos);
    }
  }
  CHECK(errors > 300);  // most mutations break the file; every failure was a clean error
  CHECK(errors + successes == 600);
}
