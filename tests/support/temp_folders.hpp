#pragma once
// Scratch folders and weight snapshots shared by the training and resume tests.
#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "anisocap/nn/nn.hpp"

namespace anisocap::testing {

/// An empty path under the system's temporary folder, unique to this process: anisocap_<name>_<pid>
/// (removed first if a run before left it).
inline std::filesystem::path fresh_folder(const std::string& name) {
  const std::filesystem::path p = std::filesystem::temp_directory_path() / ("anisocap_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
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
