#pragma once
/// @file
/// Fingerprints of check-points: what a check-point's contents depend on (the photographs, the
/// capture description, the networks' weights and the options of the check-pointed stages), one
/// named line each, so that resuming from a check-point left by another capture is refused with
/// the names of what differs instead of silently continuing from a stale state.
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace anisocap {

/// FNV-1a, 64 bits, over bytes: a fast content hash (not a cryptographic one; it tells captures
/// apart, it does not guard against forgery).
class content_hash {
 public:
  /// Adds `n` bytes.
  content_hash& bytes(const void* data, std::size_t n) noexcept {
    const auto* p = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) state_ = (state_ ^ p[i]) * 0x100000001b3ULL;
    return *this;
  }
  /// Adds the bytes of a trivially copyable value.
  template <class T>
  content_hash& value(const T& v) noexcept {
    return bytes(&v, sizeof v);
  }
  /// The hash as 16 hexadecimal digits.
  std::string hex() const {
    char text[17];
    std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(state_));
    return text;
  }

 private:
  std::uint64_t state_ = 0xcbf29ce484222325ULL;
};

/// Named parts of a fingerprint, in order; written one "name value" line each.
struct fingerprint {
  std::vector<std::pair<std::string, std::string>> parts;

  /// Adds a part.
  fingerprint& add(std::string name, std::string value) {
    parts.emplace_back(std::move(name), std::move(value));
    return *this;
  }
  /// Adds a number written exactly (17 significant digits).
  fingerprint& add(std::string name, double v) {
    char text[40];
    std::snprintf(text, sizeof text, "%.17g", v);
    return add(std::move(name), std::string(text));
  }
  /// The text form: one "name value" line per part.
  std::string text() const {
    std::string s;
    for (const auto& [name, value] : parts) s += name + " " + value + "\n";
    return s;
  }
  /// Reads text(); lines without a space are skipped.
  static fingerprint parse(std::string_view text) {
    fingerprint f;
    std::istringstream in{std::string(text)};
    std::string line;
    while (std::getline(in, line)) {
      const auto space = line.find(' ');
      if (space != std::string::npos) f.add(line.substr(0, space), line.substr(space + 1));
    }
    return f;
  }
  /// What differs between `saved` (a check-point's) and this one, as "name (check-point: a, now:
  /// b)", one entry per part that differs or is missing on either side; empty when they agree.
  std::vector<std::string> differences_from(const fingerprint& saved) const {
    std::vector<std::string> out;
    auto find = [](const fingerprint& f, const std::string& name) -> const std::string* {
      for (const auto& [n, v] : f.parts)
        if (n == name) return &v;
      return nullptr;
    };
    for (const auto& [name, value] : parts) {
      const std::string* old = find(saved, name);
      if (!old) out.push_back(name + " (not in the check-point)");
      else if (*old != value) out.push_back(name + " (check-point: " + *old + ", now: " + value + ")");
    }
    for (const auto& [name, value] : saved.parts)
      if (!find(*this, name)) out.push_back(name + " (only in the check-point)");
    return out;
  }
};

}  // namespace anisocap
