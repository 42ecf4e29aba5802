#pragma once
/// @file
/// A minimal, strict JSON value type and parser (RFC 8259), for `capture.json`, `report.json` and
/// safetensors headers. The library's headers may not depend on nlohmann-json (examples only), and
/// these files are small, so a few hundred lines suffice. Strict means: no comments, no trailing
/// commas, no NaN/Infinity, no duplicate object keys, no control characters in strings, valid
/// UTF-8 and surrogate pairs only; a bad file is reported with its name, line and column.
#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <initializer_list>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <variant>
#include <vector>

namespace anisocap::json {

/// Syntax error in a JSON text: the message reads `source:line:column: problem`.
class parse_error : public std::runtime_error {
 public:
  parse_error(std::string source, std::size_t line, std::size_t column, const std::string& problem)
      : std::runtime_error(source + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " + problem),
        source_(std::move(source)), line_(line), column_(column) {}
  /// Name of the file (or other source) that failed to parse.
  const std::string& source() const noexcept { return source_; }
  /// 1-based line of the problem.
  std::size_t line() const noexcept { return line_; }
  /// 1-based column (in bytes) of the problem.
  std::size_t column() const noexcept { return column_; }

 private:
  std::string source_;
  std::size_t line_, column_;
};

/// A value of the wrong JSON type was asked for (e.g. `as_string()` on a number).
class type_error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// The six JSON types.
enum class kind { null, boolean, number, string, array, object };

/// Human-readable name of a kind ("null", "boolean", "number", "string", "array", "object"),
/// for error messages such as "expected an array, got a string".
inline const char* kind_name(kind k) noexcept {
  switch (k) {
    case kind::null: return "null";
    case kind::boolean: return "boolean";
    case kind::number: return "number";
    case kind::string: return "string";
    case kind::array: return "array";
    case kind::object: return "object";
  }
  return "?";
}

class value;

/// A JSON array.
using array = std::vector<value>;

/// A JSON object; keeps members in insertion (file) order so that dumps are stable and readable.
/// Lookup is linear, which is faster than a map for the handful of keys our files have.
class object {
 public:
  /// One key/value pair.
  using member = std::pair<std::string, value>;

  object() = default;
  /// Builds from pairs, e.g. `object{{"a", 1.0}, {"b", "x"}}`; a repeated key keeps the last value.
  object(std::initializer_list<member> members);

  /// Pointer to the value of `key`, or nullptr when absent.
  value* find(std::string_view key) noexcept;
  /// Pointer to the value of `key`, or nullptr when absent.
  const value* find(std::string_view key) const noexcept;
  /// True when `key` is present.
  bool contains(std::string_view key) const noexcept { return find(key) != nullptr; }
  /// Value of `key`; throws std::out_of_range naming the key when absent.
  const value& at(std::string_view key) const;
  /// Value of `key`, inserted as null at the end when absent.
  value& operator[](std::string_view key);
  /// Sets `key` to `v` (replaces an existing value in place, otherwise appends).
  void insert_or_assign(std::string key, value v);

  std::size_t size() const noexcept { return members_.size(); }   ///< number of members
  bool empty() const noexcept { return members_.empty(); }        ///< true without members
  auto begin() noexcept { return members_.begin(); }              ///< members in insertion order
  auto end() noexcept { return members_.end(); }                  ///< end of members
  auto begin() const noexcept { return members_.begin(); }        ///< members in insertion order
  auto end() const noexcept { return members_.end(); }            ///< end of members

  /// Structural equality (same keys in the same order with equal values).
  friend bool operator==(const object& a, const object& b);

 private:
  std::vector<member> members_;
};

/// A JSON value: null, boolean, number (double), string, array or object.
class value {
 public:
  value() noexcept = default;                                        ///< null
  value(std::nullptr_t) noexcept {}                                  ///< null
  value(bool b) noexcept : v_(b) {}                                  ///< boolean
  value(double d) noexcept : v_(d) {}                                ///< number
  value(float d) noexcept : v_(double(d)) {}                         ///< number
  value(int d) noexcept : v_(double(d)) {}                           ///< number
  value(long d) noexcept : v_(double(d)) {}                          ///< number (exact below 2^53)
  value(long long d) noexcept : v_(double(d)) {}                     ///< number (exact below 2^53)
  value(unsigned d) noexcept : v_(double(d)) {}                      ///< number
  value(unsigned long d) noexcept : v_(double(d)) {}                 ///< number (exact below 2^53)
  value(unsigned long long d) noexcept : v_(double(d)) {}            ///< number (exact below 2^53)
  value(std::string s) noexcept : v_(std::move(s)) {}                ///< string (UTF-8)
  value(std::string_view s) : v_(std::string(s)) {}                  ///< string (UTF-8)
  value(const char* s) : v_(std::string(s)) {}                       ///< string (UTF-8)
  value(array a) noexcept : v_(std::move(a)) {}                      ///< array
  value(object o) noexcept : v_(std::move(o)) {}                     ///< object

  /// Which of the six types this value holds.
  json::kind kind() const noexcept { return json::kind(v_.index()); }
  bool is_null() const noexcept { return kind() == kind::null; }        ///< holds null
  bool is_bool() const noexcept { return kind() == kind::boolean; }     ///< holds a boolean
  bool is_number() const noexcept { return kind() == kind::number; }    ///< holds a number
  bool is_string() const noexcept { return kind() == kind::string; }    ///< holds a string
  bool is_array() const noexcept { return kind() == kind::array; }      ///< holds an array
  bool is_object() const noexcept { return kind() == kind::object; }    ///< holds an object

  /// The boolean; throws type_error otherwise.
  bool as_bool() const { return get<bool>(kind::boolean); }
  /// The number; throws type_error otherwise.
  double as_number() const { return get<double>(kind::number); }
  /// The string; throws type_error otherwise.
  const std::string& as_string() const { return get<std::string>(kind::string); }
  /// The array; throws type_error otherwise.
  const array& as_array() const { return get<array>(kind::array); }
  /// The array; throws type_error otherwise.
  array& as_array() { return get<array>(kind::array); }
  /// The object; throws type_error otherwise.
  const object& as_object() const { return get<object>(kind::object); }
  /// The object; throws type_error otherwise.
  object& as_object() { return get<object>(kind::object); }

  /// Serialises: `indent < 0` gives one line without spaces, otherwise members and elements go on
  /// their own lines indented by `indent` spaces per level. Numbers use the shortest form that
  /// reads back to the same double; non-finite numbers (not representable in JSON) throw type_error.
  std::string dump(int indent = -1) const;

  /// Structural equality.
  friend bool operator==(const value& a, const value& b) { return a.v_ == b.v_; }

 private:
  template <class T>
  const T& get(json::kind k) const {
    if (kind() != k) throw type_error(std::string("json: expected ") + kind_name(k) + ", got " + kind_name(kind()));
    return std::get<T>(v_);
  }
  template <class T>
  T& get(json::kind k) {
    if (kind() != k) throw type_error(std::string("json: expected ") + kind_name(k) + ", got " + kind_name(kind()));
    return std::get<T>(v_);
  }
  void dump_to(std::string& out, int indent, int depth) const;

  std::variant<std::nullptr_t, bool, double, std::string, array, object> v_{nullptr};
};

// ---- object ------------------------------------------------------------------------------------

inline object::object(std::initializer_list<member> members) {
  for (const auto& m : members) insert_or_assign(m.first, m.second);
}
inline value* object::find(std::string_view key) noexcept {
  for (auto& m : members_) if (m.first == key) return &m.second;
  return nullptr;
}
inline const value* object::find(std::string_view key) const noexcept {
  for (const auto& m : members_) if (m.first == key) return &m.second;
  return nullptr;
}
inline const value& object::at(std::string_view key) const {
  if (const value* v = find(key)) return *v;
  throw std::out_of_range("json: object has no member \"" + std::string(key) + "\"");
}
inline value& object::operator[](std::string_view key) {
  if (value* v = find(key)) return *v;
  members_.emplace_back(std::string(key), value());
  return members_.back().second;
}
inline void object::insert_or_assign(std::string key, value v) {
  if (value* old = find(key)) *old = std::move(v);
  else members_.emplace_back(std::move(key), std::move(v));
}
inline bool operator==(const object& a, const object& b) { return a.members_ == b.members_; }

// ---- dump --------------------------------------------------------------------------------------

namespace detail {

/// Appends `s` as a quoted JSON string (escapes quotes, backslashes and control characters;
/// other bytes, i.e. UTF-8, pass through).
inline void dump_string(std::string& out, std::string_view s) {
  static constexpr char hex[] = "0123456789abcdef";
  out += '"';
  for (char ch : s) {
    const unsigned char c = static_cast<unsigned char>(ch);
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\b': out += "\\b"; break;
      case '\f': out += "\\f"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (c < 0x20) {
          out += "\\u00";
          out += hex[c >> 4];
          out += hex[c & 15];
        } else {
          out += ch;
        }
    }
  }
  out += '"';
}

/// Appends a number: integers below 2^53 without a fraction, others in the shortest round-trip form.
inline void dump_number(std::string& out, double d) {
  if (!std::isfinite(d)) throw type_error("json: cannot write a non-finite number (" + std::to_string(d) + ")");
  char buf[32];
  std::to_chars_result r;
  if (d == std::trunc(d) && std::fabs(d) < 9007199254740992.0) {
    r = std::to_chars(buf, buf + sizeof buf, static_cast<long long>(d));
    if (d == 0 && std::signbit(d)) out += '-';  // keep -0 distinct: it reads back as -0.0
  } else {
    r = std::to_chars(buf, buf + sizeof buf, d);
  }
  out.append(buf, r.ptr);
}

inline void newline(std::string& out, int indent, int depth) {
  out += '\n';
  out.append(std::size_t(indent) * std::size_t(depth), ' ');
}

}  // namespace detail

inline void value::dump_to(std::string& out, int indent, int depth) const {
  switch (kind()) {
    case kind::null: out += "null"; break;
    case kind::boolean: out += std::get<bool>(v_) ? "true" : "false"; break;
    case kind::number: detail::dump_number(out, std::get<double>(v_)); break;
    case kind::string: detail::dump_string(out, std::get<std::string>(v_)); break;
    case kind::array: {
      const array& a = std::get<array>(v_);
      out += '[';
      for (std::size_t i = 0; i < a.size(); ++i) {
        if (i) out += ',';
        if (indent >= 0) detail::newline(out, indent, depth + 1);
        a[i].dump_to(out, indent, depth + 1);
      }
      if (indent >= 0 && !a.empty()) detail::newline(out, indent, depth);
      out += ']';
      break;
    }
    case kind::object: {
      const object& o = std::get<object>(v_);
      out += '{';
      bool first = true;
      for (const auto& [k, v] : o) {
        if (!first) out += ',';
        first = false;
        if (indent >= 0) detail::newline(out, indent, depth + 1);
        detail::dump_string(out, k);
        out += indent >= 0 ? ": " : ":";
        v.dump_to(out, indent, depth + 1);
      }
      if (indent >= 0 && !o.empty()) detail::newline(out, indent, depth);
      out += '}';
      break;
    }
  }
}

inline std::string value::dump(int indent) const {
  std::string out;
  dump_to(out, indent, 0);
  return out;
}

// ---- parse -------------------------------------------------------------------------------------

namespace detail {

/// Recursive-descent parser over one text; every error names the source, line and column.
class parser {
 public:
  /// Nesting deeper than this is rejected, so a hostile file cannot overflow the stack.
  static constexpr int max_depth = 256;

  parser(std::string_view text, std::string_view source) : text_(text), source_(source) {}

  value parse_document() {
    // RFC 8259 lets parsers ignore a UTF-8 byte order mark, which some editors write.
    if (text_.substr(0, 3) == "\xEF\xBB\xBF") pos_ = 3;
    skip_whitespace();
    value v = parse_value(0);
    skip_whitespace();
    if (pos_ != text_.size()) fail("unexpected text after the JSON value");
    return v;
  }

 private:
  [[noreturn]] void fail(const std::string& problem) const { fail_at(pos_, problem); }
  [[noreturn]] void fail_at(std::size_t at, const std::string& problem) const {
    std::size_t line = 1, column = 1;
    for (std::size_t i = 0; i < at && i < text_.size(); ++i) {
      if (text_[i] == '\n') { ++line; column = 1; } else { ++column; }
    }
    throw parse_error(std::string(source_), line, column, problem);
  }
  static std::string describe(char c) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (u >= 0x20 && u < 0x7f) return std::string("'") + c + "'";
    char buf[8];
    static constexpr char hex[] = "0123456789abcdef";
    buf[0] = '0'; buf[1] = 'x'; buf[2] = hex[u >> 4]; buf[3] = hex[u & 15]; buf[4] = 0;
    return std::string("byte ") + buf;
  }

  bool at_end() const noexcept { return pos_ >= text_.size(); }
  char peek() const noexcept { return at_end() ? '\0' : text_[pos_]; }

  void skip_whitespace() noexcept {
    while (!at_end() && (text_[pos_] == ' ' || text_[pos_] == '\t' || text_[pos_] == '\n' || text_[pos_] == '\r')) ++pos_;
  }

  void expect_literal(std::string_view word) {
    if (text_.substr(pos_, word.size()) != word) fail("invalid literal (expected '" + std::string(word) + "')");
    pos_ += word.size();
  }

  value parse_value(int depth) {
    if (at_end()) fail("unexpected end of input, expected a value");
    switch (peek()) {
      case '{': return parse_object(depth + 1);
      case '[': return parse_array(depth + 1);
      case '"': return value(parse_string());
      case 't': expect_literal("true"); return value(true);
      case 'f': expect_literal("false"); return value(false);
      case 'n': expect_literal("null"); return value(nullptr);
      default:
        if (peek() == '-' || (peek() >= '0' && peek() <= '9')) return value(parse_number());
        if (peek() == 'N' || peek() == 'I') fail("NaN and Infinity are not valid JSON numbers");
        fail("unexpected " + describe(peek()) + ", expected a value");
    }
  }

  value parse_object(int depth) {
    if (depth > max_depth) fail("nesting deeper than " + std::to_string(max_depth));
    ++pos_;  // '{'
    object o;
    skip_whitespace();
    if (peek() == '}') { ++pos_; return value(std::move(o)); }
    for (;;) {
      skip_whitespace();
      if (peek() != '"') fail(at_end() ? "unexpected end of input in an object" : "expected a string key, got " + describe(peek()));
      const std::size_t key_pos = pos_;
      std::string key = parse_string();
      if (o.contains(key)) fail_at(key_pos, "duplicate key \"" + key + "\"");
      skip_whitespace();
      if (peek() != ':') fail(at_end() ? "unexpected end of input in an object" : "expected ':' after key, got " + describe(peek()));
      ++pos_;
      skip_whitespace();
      value v = parse_value(depth);
      o.insert_or_assign(std::move(key), std::move(v));
      skip_whitespace();
      if (peek() == ',') { ++pos_; skip_whitespace(); if (peek() == '}') fail("trailing comma in an object"); continue; }
      if (peek() == '}') { ++pos_; return value(std::move(o)); }
      fail(at_end() ? "unexpected end of input in an object" : "expected ',' or '}', got " + describe(peek()));
    }
  }

  value parse_array(int depth) {
    if (depth > max_depth) fail("nesting deeper than " + std::to_string(max_depth));
    ++pos_;  // '['
    array a;
    skip_whitespace();
    if (peek() == ']') { ++pos_; return value(std::move(a)); }
    for (;;) {
      skip_whitespace();
      a.push_back(parse_value(depth));
      skip_whitespace();
      if (peek() == ',') { ++pos_; skip_whitespace(); if (peek() == ']') fail("trailing comma in an array"); continue; }
      if (peek() == ']') { ++pos_; return value(std::move(a)); }
      fail(at_end() ? "unexpected end of input in an array" : "expected ',' or ']', got " + describe(peek()));
    }
  }

  double parse_number() {
    const std::size_t start = pos_;
    auto digit = [&] { return !at_end() && text_[pos_] >= '0' && text_[pos_] <= '9'; };
    if (peek() == '-') ++pos_;
    if (!digit()) fail("expected a digit");
    if (peek() == '0') {
      ++pos_;
      if (digit()) fail_at(start, "leading zeros are not allowed in JSON numbers");
    } else {
      while (digit()) ++pos_;
    }
    if (peek() == '.') {
      ++pos_;
      if (!digit()) fail("expected a digit after the decimal point");
      while (digit()) ++pos_;
    }
    if (peek() == 'e' || peek() == 'E') {
      ++pos_;
      if (peek() == '+' || peek() == '-') ++pos_;
      if (!digit()) fail("expected a digit in the exponent");
      while (digit()) ++pos_;
    }
    double d = 0;
    const char* first = text_.data() + start;
    const char* last = text_.data() + pos_;
    const auto r = std::from_chars(first, last, d);
    if (r.ec == std::errc::result_out_of_range) {
      // Underflow to (signed) zero is harmless; overflow would be infinite, which JSON cannot mean.
      const std::string digits(first, last);
      const double approx = std::strtod(digits.c_str(), nullptr);
      if (std::isinf(approx)) fail_at(start, "number " + digits + " is out of range");
      d = approx;
    } else if (r.ec != std::errc() || r.ptr != last) {
      fail_at(start, "invalid number");
    }
    return d;
  }

  unsigned parse_hex4() {
    if (pos_ + 4 > text_.size()) fail("unexpected end of input in a \\u escape");
    unsigned v = 0;
    for (int i = 0; i < 4; ++i) {
      const char c = text_[pos_++];
      v <<= 4;
      if (c >= '0' && c <= '9') v |= unsigned(c - '0');
      else if (c >= 'a' && c <= 'f') v |= unsigned(c - 'a' + 10);
      else if (c >= 'A' && c <= 'F') v |= unsigned(c - 'A' + 10);
      else { --pos_; fail("invalid hex digit " + describe(c) + " in a \\u escape"); }
    }
    return v;
  }

  static void append_utf8(std::string& out, std::uint32_t cp) {
    if (cp < 0x80) {
      out += char(cp);
    } else if (cp < 0x800) {
      out += char(0xC0 | (cp >> 6));
      out += char(0x80 | (cp & 0x3F));
    } else if (cp < 0x10000) {
      out += char(0xE0 | (cp >> 12));
      out += char(0x80 | ((cp >> 6) & 0x3F));
      out += char(0x80 | (cp & 0x3F));
    } else {
      out += char(0xF0 | (cp >> 18));
      out += char(0x80 | ((cp >> 12) & 0x3F));
      out += char(0x80 | ((cp >> 6) & 0x3F));
      out += char(0x80 | (cp & 0x3F));
    }
  }

  /// Length of the valid UTF-8 sequence starting at pos_ (lead byte >= 0x80), or 0 when invalid
  /// (overlong forms, surrogates and code points above U+10FFFF are invalid).
  std::size_t utf8_length() const noexcept {
    auto byte = [&](std::size_t i) -> unsigned { return pos_ + i < text_.size() ? static_cast<unsigned char>(text_[pos_ + i]) : 0u; };
    auto cont = [&](std::size_t i) { return (byte(i) & 0xC0) == 0x80; };
    const unsigned b0 = byte(0);
    if (b0 >= 0xC2 && b0 <= 0xDF) return cont(1) ? 2 : 0;
    if (b0 >= 0xE0 && b0 <= 0xEF) {
      const unsigned b1 = byte(1);
      if (!cont(1) || !cont(2)) return 0;
      if (b0 == 0xE0 && b1 < 0xA0) return 0;   // overlong
      if (b0 == 0xED && b1 >= 0xA0) return 0;  // UTF-16 surrogate
      return 3;
    }
    if (b0 >= 0xF0 && b0 <= 0xF4) {
      const unsigned b1 = byte(1);
      if (!cont(1) || !cont(2) || !cont(3)) return 0;
      if (b0 == 0xF0 && b1 < 0x90) return 0;   // overlong
      if (b0 == 0xF4 && b1 >= 0x90) return 0;  // above U+10FFFF
      return 4;
    }
    return 0;
  }

  std::string parse_string() {
    ++pos_;  // opening quote
    std::string out;
    for (;;) {
      if (at_end()) fail("unexpected end of input in a string");
      const char c = text_[pos_];
      const unsigned char u = static_cast<unsigned char>(c);
      if (c == '"') { ++pos_; return out; }
      if (u < 0x20) fail("control character " + describe(c) + " in a string (escape it)");
      if (u >= 0x80) {
        const std::size_t n = utf8_length();
        if (n == 0) fail("invalid UTF-8 in a string");
        out.append(text_.substr(pos_, n));
        pos_ += n;
        continue;
      }
      if (c != '\\') { out += c; ++pos_; continue; }
      ++pos_;
      if (at_end()) fail("unexpected end of input in a string");
      const char e = text_[pos_++];
      switch (e) {
        case '"': out += '"'; break;
        case '\\': out += '\\'; break;
        case '/': out += '/'; break;
        case 'b': out += '\b'; break;
        case 'f': out += '\f'; break;
        case 'n': out += '\n'; break;
        case 'r': out += '\r'; break;
        case 't': out += '\t'; break;
        case 'u': {
          const std::size_t escape_pos = pos_ - 2;
          std::uint32_t cp = parse_hex4();
          if (cp >= 0xDC00 && cp <= 0xDFFF) fail_at(escape_pos, "unpaired low surrogate in a \\u escape");
          if (cp >= 0xD800 && cp <= 0xDBFF) {
            if (text_.substr(pos_, 2) != "\\u") fail_at(escape_pos, "unpaired high surrogate in a \\u escape");
            pos_ += 2;
            const std::uint32_t low = parse_hex4();
            if (low < 0xDC00 || low > 0xDFFF) fail_at(escape_pos, "high surrogate not followed by a low surrogate");
            cp = 0x10000 + ((cp - 0xD800) << 10) + (low - 0xDC00);
          }
          append_utf8(out, cp);
          break;
        }
        default: --pos_; fail("invalid escape \\" + std::string(1, e));
      }
    }
  }

  std::string_view text_;
  std::string_view source_;
  std::size_t pos_ = 0;
};

}  // namespace detail

/// Parses one JSON text (the whole of `text`, surrounding whitespace allowed). `source_name`
/// (usually the file's path) prefixes every error: throws parse_error `source:line:column: problem`.
/// A leading UTF-8 byte order mark is skipped (columns still count it).
inline value parse(std::string_view text, std::string_view source_name = "<json>") {
  return detail::parser(text, source_name).parse_document();
}

}  // namespace anisocap::json
