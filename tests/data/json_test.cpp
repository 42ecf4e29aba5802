// Tests for core/json.hpp: strict parsing, error positions, and dump/parse round trips.
#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "anisocap/core/json.hpp"

namespace json = anisocap::json;

namespace {

/// Parses `text` expecting failure; returns the error so the test can check position and message.
json::parse_error parse_failure(std::string_view text) {
  try {
    json::parse(text, "file.json");
  } catch (const json::parse_error& e) {
    return e;
  }
  FAIL("expected a parse error for: " << text);
  return json::parse_error("", 0, 0, "");
}

}  // namespace

TEST_CASE("json: parses every type and keeps object order") {
  const json::value v = json::parse(R"( {"b": [1, -2.5e3, true, false, null], "a": "x\"y\\z\/\n\u00e9\ud83d\ude00", "c": {}} )");
  REQUIRE(v.is_object());
  const json::object& o = v.as_object();
  REQUIRE(o.size() == 3);
  auto it = o.begin();
  CHECK(it->first == "b");
  ++it;
  CHECK(it->first == "a");  // insertion order, not sorted
  const json::array& b = o.at("b").as_array();
  REQUIRE(b.size() == 5);
  CHECK(b[0].as_number() == 1.0);
  CHECK(b[1].as_number() == -2500.0);
  CHECK(b[2].as_bool());
  CHECK(!b[3].as_bool());
  CHECK(b[4].is_null());
  CHECK(o.at("a").as_string() == "x\"y\\z/\n\xc3\xa9\xf0\x9f\x98\x80");
  CHECK(o.at("c").as_object().empty());
  CHECK(o.find("missing") == nullptr);
  CHECK_THROWS_AS(o.at("missing"), std::out_of_range);
  CHECK_THROWS_AS(o.at("a").as_number(), json::type_error);
}

TEST_CASE("json: numbers read exactly and dump in shortest round-trip form") {
  CHECK(json::parse("0.1").as_number() == 0.1);
  CHECK(json::parse("-0").as_number() == 0.0);
  CHECK(std::signbit(json::parse("-0").as_number()));
  CHECK(json::parse("1E2").as_number() == 100.0);
  CHECK(json::parse("1e-400").as_number() == 0.0);  // underflow is harmless
  CHECK(json::value(3.0).dump() == "3");
  CHECK(json::value(-0.0).dump() == "-0");
  CHECK(json::value(0.1).dump() == "0.1");
  CHECK(json::value(1e300).dump() == "1e+300");
  CHECK_THROWS_AS(json::value(std::nan("")).dump(), json::type_error);
  CHECK_THROWS_AS(json::value(std::numeric_limits<double>::infinity()).dump(), json::type_error);
  // Random doubles survive dump -> parse bit-exactly.
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> exponent(-300, 300), mantissa(-1, 1);
  for (int i = 0; i < 2000; ++i) {
    const double d = mantissa(rng) * std::pow(10.0, exponent(rng));
    CHECK(json::parse(json::value(d).dump()).as_number() == d);
  }
}

TEST_CASE("json: dump then parse gives the same value, compact and indented") {
  json::object inner{{"x", 1}, {"y", json::array{1.5, "two", nullptr}}};
  json::value v(json::object{{"name", "tab\there \x01 \xe2\x82\xac"}, {"inner", inner}, {"flag", false},
                             {"empty_a", json::array{}}, {"empty_o", json::object{}}});
  const std::string compact = v.dump();
  CHECK(compact.find('\n') == std::string::npos);
  CHECK(compact.find("\\u0001") != std::string::npos);
  CHECK(json::parse(compact) == v);
  const std::string pretty = v.dump(2);
  CHECK(pretty.find("\n  \"inner\": {\n    \"x\": 1,") != std::string::npos);
  CHECK(json::parse(pretty) == v);
  CHECK(json::parse(pretty).dump() == compact);
}

TEST_CASE("json: errors name the source, line and column") {
  const auto e = parse_failure("{\n  \"a\": 1,\n  \"b\": tru\n}");
  CHECK(e.source() == "file.json");
  CHECK(e.line() == 3);
  CHECK(e.column() == 8);
  CHECK(std::string(e.what()).rfind("file.json:3:8:", 0) == 0);
}

TEST_CASE("json: strictness") {
  struct bad_case { const char* text; const char* keyword; };
  const bad_case cases[] = {
      {"", "end of input"},
      {"[1, 2,]", "trailing comma"},
      {"{\"a\": 1,}", "trailing comma"},
      {"{\"a\": 1, \"a\": 2}", "duplicate key"},
      {"[01]", "leading zeros"},
      {"[1.]", "decimal point"},
      {"[.5]", "expected a value"},
      {"[1e]", "exponent"},
      {"[+1]", "expected a value"},
      {"[NaN]", "NaN"},
      {"[Infinity]", "NaN and Infinity"},
      {"[1e999]", "out of range"},
      {"\"abc", "end of input"},
      {"\"a\tb\"", "control character"},
      {"\"\\x\"", "invalid escape"},
      {"\"\\u12G4\"", "hex digit"},
      {"\"\\ud800\"", "unpaired high surrogate"},
      {"\"\\udc00\"", "unpaired low surrogate"},
      {"\"\\ud800\\u0041\"", "low surrogate"},
      {"\"\xff\"", "UTF-8"},
      {"\"\xc0\xaf\"", "UTF-8"},
      {"\"\xed\xa0\x80\"", "UTF-8"},
      {"{a: 1}", "string key"},
      {"{\"a\" 1}", "':'"},
      {"[1 2]", "',' or ']'"},
      {"{} x", "after the JSON value"},
      {"// c\n{}", "expected a value"},
      {"nul", "literal"},
  };
  for (const auto& c : cases) {
    CAPTURE(c.text);
    const auto e = parse_failure(c.text);
    CHECK(std::string(e.what()).find(c.keyword) != std::string::npos);
    CHECK(std::string(e.what()).find("file.json") != std::string::npos);
  }
  // Deep nesting is refused rather than overflowing the stack.
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  CHECK(std::string(parse_failure(deep).what()).find("nesting") != std::string::npos);
  CHECK(json::parse(std::string(200, '[') + std::string(200, ']')).is_array());
}

TEST_CASE("json: a leading UTF-8 byte order mark is ignored, one elsewhere is not") {
  CHECK(json::parse("\xEF\xBB\xBF{\"a\": 1}").as_object().at("a").as_number() == 1);
  CHECK(std::string(parse_failure("[\xEF\xBB\xBF]").what()).find("expected a value") != std::string::npos);
}

TEST_CASE("json: object editing") {
  json::object o;
  o["b"] = 1;
  o["a"] = "x";
  o.insert_or_assign("b", 2);
  CHECK(o.size() == 2);
  CHECK(o.at("b").as_number() == 2);
  CHECK(json::value(o).dump() == "{\"b\":2,\"a\":\"x\"}");
}
