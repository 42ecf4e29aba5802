// Tests for core/json_parse.hpp (nlohmann-json, read strictly) and the JSON errors of capture
// descriptions: each names the file, the line and column where it can, and the problem.
#include <doctest/doctest.h>

#include <string>

#include "anisocap/core/json_parse.hpp"
#include "anisocap/data/capture_io.hpp"

using anisocap::json;

namespace {

/// The message of `read(text)`, which must fail.
template <class Read>
std::string failure(std::string_view text, Read read) {
  try {
    read(text);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  FAIL("expected an error for: " << text);
  return {};
}

/// The message of parsing `text` as "file.json".
std::string parse_failure(std::string_view text) {
  return failure(text, [](std::string_view t) { anisocap::parse_json(t, "file.json"); });
}

/// The message of parsing `text` as the capture description "capture.json".
std::string capture_failure(std::string_view text) {
  return failure(text, [](std::string_view t) { anisocap::parse_capture(t, "capture.json"); });
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace

TEST_CASE("json: objects keep their order and numbers round-trip") {
  const json v = anisocap::parse_json(R"({"b": [1, -2.5e3, true, false, null], "a": "x\"y", "c": {}})", "file.json");
  auto it = v.items().begin();
  CHECK(it.key() == "b");
  ++it;
  CHECK(it.key() == "a");  // insertion order, not sorted
  CHECK(v.at("b")[1].get<double>() == -2500.0);
  CHECK(v.at("a").get<std::string>() == "x\"y");
  CHECK(anisocap::json_kind_name(v.at("c")) == std::string("object"));
  CHECK(anisocap::json_kind_name(v.at("b")[4]) == std::string("null"));
  CHECK(anisocap::parse_json(json(0.1).dump(), "x").get<double>() == 0.1);
}

TEST_CASE("json: errors name the source, line and column") {
  const std::string e = parse_failure("{\n  \"a\": 1,\n  \"b\" 2\n}");
  CHECK(e.rfind("file.json:3:", 0) == 0);
  CHECK(contains(parse_failure(""), "file.json:1:1: unexpected end of input"));
  CHECK(contains(parse_failure("[1, 2,]"), "trailing comma"));
  CHECK(contains(parse_failure("{\"a\": 1,}"), "trailing comma"));
  CHECK(contains(parse_failure("[0, NaN]"), "NaN and Infinity"));
  CHECK(contains(parse_failure("[Infinity]"), "NaN and Infinity"));
  CHECK(contains(parse_failure("{\"a\": 1, \"a\": 2}"), "repeated key \"a\""));
  CHECK(contains(parse_failure("{\"o\": {\"a\": 1, \"a\": 2}}"), "repeated key \"a\""));
  CHECK(contains(parse_failure("[1e999]"), "file.json: "));
  for (const char* bad : {"[01]", "[1.]", "[.5]", "[+1]", "\"abc", "{a: 1}", "[1 2]", "{} x", "// c\n{}", "nul"})
    CHECK(contains(parse_failure(bad), "file.json:"));
  // The same key in two objects is not a repetition.
  CHECK(anisocap::parse_json(R"([{"a": 1}, {"a": 2}])", "x").size() == 2);
}

TEST_CASE("json: capture descriptions with bad JSON name the file, the position and the problem") {
  CHECK(contains(capture_failure("{\"images\": [1,]}"), "capture.json:1:"));
  CHECK(contains(capture_failure("{\"images\": [1,]}"), "trailing comma"));
  const std::string two = capture_failure("{\"images\": [{\"file\": \"a.exr\", \"file\": \"b.exr\"}]}");
  CHECK(contains(two, "capture.json"));
  CHECK(contains(two, "repeated key \"file\""));
  CHECK(contains(capture_failure("{\"images\": [{\"file\": \"a.exr\" \"camera\": [0, 0, 1]}]}"), "capture.json:1:"));
  CHECK(contains(capture_failure("{\"images\": [{\"camera\": [0, 0, NaN]}]}"), "NaN"));
  CHECK(contains(capture_failure("[]"), "expected a JSON object at the top, got array"));
}
