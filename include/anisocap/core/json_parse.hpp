#pragma once
/// @file
/// Reading JSON files (capture descriptions, check-point descriptions, safetensors headers) with
/// nlohmann-json, strictly: one error naming the source, line and column and the problem, and
/// repeated keys refused (nlohmann-json would keep the last one silently). Objects keep their
/// order (`ordered_json`), so written files read in the order they were built.
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <nlohmann/json.hpp>

namespace anisocap {

/// A JSON value whose objects keep their insertion order.
using json = nlohmann::ordered_json;

/// Malformed JSON: "source:line:column: problem".
class json_error : public std::runtime_error {
 public:
  json_error(const std::string& source, std::size_t line, std::size_t column, const std::string& problem)
      : std::runtime_error(source + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " + problem) {}
  /// An error without a position.
  json_error(const std::string& source, const std::string& problem) : std::runtime_error(source + ": " + problem) {}
};

/// The type of a value in words: null, boolean, number, string, array, object.
inline const char* json_kind_name(const json& v) noexcept {
  if (v.is_null()) return "null";
  if (v.is_boolean()) return "boolean";
  if (v.is_number()) return "number";
  if (v.is_string()) return "string";
  if (v.is_array()) return "array";
  if (v.is_object()) return "object";
  return "binary";
}

/// Parses `text`; `source` names it in errors (json_error). Refuses repeated keys in an object.
inline json parse_json(std::string_view text, const std::string& source) {
  // Line and column (both from 1) of byte `offset`.
  auto position = [&](std::size_t offset, std::size_t& line, std::size_t& column) {
    line = 1;
    column = 1;
    for (std::size_t i = 0; i < offset && i < text.size(); ++i) {
      if (text[i] == '\n') {
        ++line;
        column = 1;
      } else {
        ++column;
      }
    }
  };
  std::vector<std::set<std::string>> keys;  // per open object, the keys seen so far
  std::string repeated;
  const json::parser_callback_t check = [&](int, json::parse_event_t event, json& parsed) {
    if (event == json::parse_event_t::object_start) keys.emplace_back();
    else if (event == json::parse_event_t::object_end && !keys.empty()) keys.pop_back();
    else if (event == json::parse_event_t::key && !keys.empty() && !keys.back().insert(parsed.get<std::string>()).second && repeated.empty())
      repeated = parsed.get<std::string>();
    return true;
  };
  json root;
  try {
    root = json::parse(text.begin(), text.end(), check, true, false);
  } catch (const json::parse_error& e) {
    // e.byte is 1-based: the byte after the token that failed.
    const std::size_t at = e.byte > 0 ? e.byte - 1 : 0;
    std::size_t line, column;
    position(at, line, column);
    std::string problem = e.what();
    const auto colon = problem.find(": ", problem.find("column"));
    if (colon != std::string::npos) problem = problem.substr(colon + 2);
    if (text.find_first_not_of(" \t\r\n") == std::string_view::npos) problem = "unexpected end of input (no JSON value)";
    // Hints for the two mistakes of hand-written files that the message does not name.
    std::size_t before = at;
    while (before > 0 && std::string_view(" \t\r\n").find(text[before - 1]) != std::string_view::npos) --before;
    if (at < text.size() && (text[at] == ']' || text[at] == '}') && before > 0 && text[before - 1] == ',') problem += " (trailing comma)";
    const std::size_t window = at >= 8 ? at - 8 : 0;
    const std::string_view near = text.substr(window, 16);
    if (near.find("NaN") != std::string_view::npos || near.find("Inf") != std::string_view::npos)
      problem += " (NaN and Infinity are not JSON numbers)";
    throw json_error(source, line, column, problem);
  } catch (const json::exception& e) {  // a number beyond double's range
    std::string problem = e.what();
    const auto bracket = problem.find("] ");
    throw json_error(source, bracket == std::string::npos ? problem : problem.substr(bracket + 2));
  }
  if (!repeated.empty()) throw json_error(source, "repeated key \"" + repeated + "\" in an object");
  return root;
}

}  // namespace anisocap
