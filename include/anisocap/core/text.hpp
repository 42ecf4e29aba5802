#pragma once
/// @file
/// Lists as text: the names, paths and differences an error message or a log line enumerates.
#include <concepts>
#include <string>
#include <string_view>
#include <vector>

namespace anisocap {

/// `items` joined by `separator` ("compact, paper"). An item is anything a std::string can be
/// made from (std::string, std::string_view, const char*) or that has a `string()` member
/// (std::filesystem::path: its native text).
template <class Range>
std::string join_names(const Range& items, std::string_view separator) {
  std::string text;
  bool first = true;
  for (const auto& item : items) {
    if (!first) text += separator;
    first = false;
    if constexpr (requires { { item.string() } -> std::convertible_to<std::string>; })
      text += item.string();
    else
      text += std::string_view(item);
  }
  return text;
}

/// join_names of a braced list of names: `join_names({"compact", "paper"}, ", ")`.
inline std::string join_names(const std::vector<std::string>& names, std::string_view separator) {
  return join_names<std::vector<std::string>>(names, separator);
}

}  // namespace anisocap
