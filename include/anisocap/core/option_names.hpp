#pragma once
// The library's messages name the option fields they refuse as a host's C++ code sets them
// (refine_options::learning_rate, train_options::steps). A binding that sets them under other
// names (the anisocap program's flags, the Python module's arguments) lists its names once and
// passes its errors through with_option_names, so that its users read the names they typed.
#include <cctype>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>

namespace anisocap {

/// A field as the library's messages name it ("refine_options::learning_rate") and the name a
/// binding gives it ("--lr").
struct option_name {
  std::string_view field;
  std::string_view name;
};

/// `message` with every field of `names` it names replaced by the binding's name. A field is
/// matched whole: train_options::lr_end is not train_options::lr followed by "_end".
inline std::string with_option_names(std::string_view message, std::span<const option_name> names) {
  const auto part_of_name = [&](std::size_t i) {
    const unsigned char c = static_cast<unsigned char>(message[i]);
    const bool next = i + 1 < message.size();
    return std::isalnum(c) || c == '_' || (c == ':' && ((next && message[i + 1] == ':') || (i > 0 && message[i - 1] == ':'))) ||
           (c == '.' && next && std::isalnum(static_cast<unsigned char>(message[i + 1])));
  };
  std::string out;
  std::size_t at = 0;
  while (at < message.size()) {
    const option_name* hit = nullptr;
    if (at == 0 || !part_of_name(at - 1))
      for (const option_name& e : names)
        if (message.substr(at, e.field.size()) == e.field && (at + e.field.size() == message.size() || !part_of_name(at + e.field.size()))) {
          hit = &e;
          break;
        }
    if (hit) {
      out += hit->name;
      at += hit->field.size();
    } else {
      out += message[at++];
    }
  }
  return out;
}

/// Returns `run()`; an std::invalid_argument or std::runtime_error whose message names a field of
/// `names` is thrown again as the same standard type with the binding's names in the fields' place
/// (any other exception passes unchanged).
template <class Run>
decltype(auto) naming_options(std::span<const option_name> names, Run&& run) {
  try {
    return run();
  } catch (const std::invalid_argument& e) {
    if (std::string named = with_option_names(e.what(), names); named != e.what()) throw std::invalid_argument(named);
    throw;
  } catch (const std::runtime_error& e) {
    if (std::string named = with_option_names(e.what(), names); named != e.what()) throw std::runtime_error(named);
    throw;
  }
}

/// Throws std::invalid_argument "TYPE::FIELD must not be negative" for the first int field that
/// `Options::visit_fields` lists with a negative value: the counts check of every options struct
/// with a field visitor (finetune_options, refine_options).
template <class Options>
void check_counts_not_negative(const Options& o, std::string_view type) {
  Options::visit_fields(o, [&](const char* field, const auto& value) {
    if constexpr (std::is_same_v<std::decay_t<decltype(value)>, int>)
      if (value < 0) throw std::invalid_argument(std::string(type) + "::" + field + " must not be negative");
  });
}

}  // namespace anisocap
