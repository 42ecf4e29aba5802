#pragma once
/// @file
/// What the process costs: peak resident memory and elapsed time, for reports and benchmarks.
#include <chrono>
#include <cstddef>
#include <fstream>
#include <string>

namespace anisocap {

/// Peak resident set size of this process in bytes (Linux: VmHWM of /proc/self/status); 0 where
/// unknown.
inline std::size_t peak_resident_bytes() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::size_t(std::stoull(line.substr(6))) * 1024;  // value in kB
  return 0;
}

/// Seconds elapsed on the steady clock since `start`.
inline double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace anisocap
