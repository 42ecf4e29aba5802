#pragma once
// Scratch folders and weight snapshots shared by the training and resume tests.
#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "anisocap/nn/nn.hpp"

namespace anisocap::testing {

/// The folders fresh_folder handed out; they are removed when the test program exits, so a test
/// that fails part-way (or a run that should have created nothing but did) leaves nothing behind.
class scratch_folders {
 public:
  scratch_folders() = default;
  scratch_folders(const scratch_folders&) = delete;
  scratch_folders& operator=(const scratch_folders&) = delete;
  ~scratch_folders() {
    std::error_code ec;
    for (const auto& p : paths_) std::filesystem::remove_all(p, ec);
  }
  /// Remembers `p` for removal at exit.
  void add(const std::filesystem::path& p) { paths_.push_back(p); }

 private:
  std::vector<std::filesystem::path> paths_;
};

/// An empty path under the system's temporary folder, unique to this process: anisocap_<name>_<pid>
/// (removed first if a run before left it, and again when the test program exits).
inline std::filesystem::path fresh_folder(const std::string& name) {
  static scratch_folders folders;
  const std::filesystem::path p = std::filesystem::temp_directory_path() / ("anisocap_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  folders.add(p);
  return p;
}

/// Every weight of a network, in visiting order (compare two networks bit for bit).
template <class Net>
std::vector<float> all_weights(Net& net) {
  std::vector<float> w;
  nn::detail::visit_weights(net, [&](auto& p) { w.insert(w.end(), p.value.begin(), p.value.end()); });
  return w;
}

}  // namespace anisocap::testing
