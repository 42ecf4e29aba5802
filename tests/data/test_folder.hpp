#pragma once
// A unique temporary folder per test, removed at the end of the test, plus small helpers.
#include <algorithm>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

namespace anisocap::testing {

/// Creates `<temp>/anisocap_test_<random>` and removes it (recursively) on destruction.
class test_folder {
 public:
  test_folder() {
    std::random_device rd;
    const auto base = std::filesystem::temp_directory_path();
    for (;;) {
      path_ = base / ("anisocap_test_" + std::to_string(rd()) + std::to_string(rd()));
      if (std::filesystem::create_directory(path_)) break;
    }
  }
  ~test_folder() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  test_folder(const test_folder&) = delete;
  test_folder& operator=(const test_folder&) = delete;

  const std::filesystem::path& path() const noexcept { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

  /// Names of all entries in the folder (including hidden ones), sorted.
  std::vector<std::string> entries() const {
    std::vector<std::string> names;
    for (const auto& e : std::filesystem::directory_iterator(path_)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

 private:
  std::filesystem::path path_;
};

}  // namespace anisocap::testing
