// Corrupted inputs: random byte changes, removed or repeated spans and truncations of valid
// capture.json, EXR, PNG and safetensors files must give a clean std::runtime_error (naming the
// file) or a valid result, never a crash. Seeded and a fixed number of tries: bounded in CI.
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <random>
#include <string>

#include "anisocap/data/capture_io.hpp"
#include "anisocap/data/image_io.hpp"
#include "anisocap/nn/safetensors.hpp"
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

namespace {

/// Mutates the header region (the first `header_end` bytes) of `bytes` more often than the data:
/// replaced bytes, an inserted or removed span, or a changed length prefix.
std::vector<unsigned char> mutate_structure(std::vector<unsigned char> bytes, std::size_t header_end, std::mt19937& rng) {
  const auto pick = [&](std::size_t n) { return std::size_t(rng() % std::max<std::size_t>(n, 1)); };
  switch (rng() % 5) {
    case 0:  // a few bytes of the header
      for (int k = 0, n = 1 + int(rng() % 4); k < n; ++k) bytes[pick(header_end)] = static_cast<unsigned char>(rng());
      break;
    case 1: {  // a span of the header removed
      const std::size_t at = pick(header_end), len = 1 + pick(16);
      bytes.erase(bytes.begin() + std::ptrdiff_t(at), bytes.begin() + std::ptrdiff_t(std::min(at + len, bytes.size())));
      break;
    }
    case 2: {  // a span of the header repeated
      const std::size_t at = pick(header_end), len = std::min<std::size_t>(1 + pick(24), bytes.size() - at);
      const std::vector<unsigned char> span(bytes.begin() + std::ptrdiff_t(at), bytes.begin() + std::ptrdiff_t(at + len));
      bytes.insert(bytes.begin() + std::ptrdiff_t(at), span.begin(), span.end());
      break;
    }
    case 3:  // the length prefix
      bytes[pick(8)] = static_cast<unsigned char>(rng());
      break;
    default:  // truncated anywhere
      bytes.resize(pick(bytes.size()));
  }
  return bytes;
}

void write_bytes(const fs::path& path, const std::vector<unsigned char>& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

}  // namespace

TEST_CASE("corrupted safetensors headers and capture.json structure give clean errors, in a bounded number of tries") {
  test_folder dir;
  namespace nn = anisocap::nn;
  nn::safetensors_file valid;
  const std::vector<float> a{1, 2, 3, 4, 5, 6};
  const std::vector<double> b{0.5, -0.25};
  const std::vector<std::int64_t> c{7};
  valid.add<float>("layer.weight", {2, 3}, a.data(), a.size());
  valid.add<double>("layer.bias", {2}, b.data(), b.size());
  valid.add<std::int64_t>("adam.steps.layer", {1}, c.data(), c.size());
  valid.metadata.emplace_back("step", "12");
  nn::write_safetensors(dir / "valid.safetensors", valid);
  const auto bytes = anisocap::read_file_bytes(dir / "valid.safetensors");
  std::uint64_t header = 0;
  for (int k = 7; k >= 0; --k) header = header << 8 | bytes[std::size_t(k)];
  REQUIRE(header + 8 < bytes.size());

  anisocap::capture cap;
  cap.images.push_back({"input_00.exr", {0.1f, 0.2f, 1.0f}, {0.3f, -0.4f, 2.0f}, {1, 2, 3}, "", 1.0f, 0.0f});
  cap.images.push_back({"input_01.png", {0.0f, 0.5f, 0.5f}, {0.0f, -0.5f, 0.5f}, {4, 4, 4}, "", 1.0f, 0.0f});
  anisocap::write_capture(cap, dir / "capture.json");
  const auto description = anisocap::read_file_bytes(dir / "capture.json");

  std::mt19937 rng(16);
  int tensor_errors = 0, capture_errors = 0;
  constexpr int tries = 1500;  // about a second: bounded for CI
  for (int it = 0; it < tries; ++it) {
    const fs::path bad = dir / "bad.safetensors";
    write_bytes(bad, mutate_structure(bytes, std::size_t(header) + 8, rng));
    try {
      const nn::safetensors_file f = nn::read_safetensors(bad);
      for (const auto& e : f.entries()) REQUIRE(f.bytes(e).size() == e.count() * nn::safetensors_dtype_size(e.dtype));
    } catch (const nn::safetensors_error& e) {
      ++tensor_errors;
      REQUIRE(std::string(e.what()).find(bad.string()) != std::string::npos);
    }
    const fs::path bad_json = dir / "bad.json";
    write_bytes(bad_json, mutate_structure(description, description.size(), rng));
    try {
      const anisocap::capture read = anisocap::read_capture(bad_json);
      REQUIRE_FALSE(read.images.empty());
    } catch (const std::runtime_error& e) {
      ++capture_errors;
      REQUIRE(std::string(e.what()).find(bad_json.string()) != std::string::npos);
    }
  }
  CHECK(tensor_errors > tries / 2);
  CHECK(capture_errors > tries / 2);
}
