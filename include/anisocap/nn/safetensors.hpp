#pragma once
/// @file
/// Weight files in the safetensors format (Hugging Face), so PyTorch reads what anisocap writes and
/// the other way round: an 8-byte little-endian header length N, N bytes of JSON
/// `{"name": {"dtype": "F32", "shape": [...], "data_offsets": [begin, end]}, ...,
/// "__metadata__": {"key": "value"}}` (padded with spaces to a multiple of 8), then the raw
/// little-endian tensor data, offsets relative to its start.
///
/// Reading is strict, as the reference implementation is: the tensors must tile the data region
/// exactly (no gaps, no overlap, nothing after the last), each tensor's byte count must match its
/// dtype and shape, and any problem throws safetensors_error naming the file and the problem.
/// Writing goes to a temporary name and is renamed into place, so a crash never leaves half a file.
///
/// A network's weights may be stored as IEEE half floats ("F16", weight_storage::f16): the loaders
/// read F16 tensors into float parameters, and save_weights and convert_weights write them, which
/// halves a file (docs/model-card.md gives what it changes in the networks' outputs).
#include <algorithm>
#include <bit>
#include <cstddef>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>  // Eigen::half: IEEE binary16 with round-to-nearest-even conversions

#include "anisocap/core/json_parse.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

static_assert(std::endian::native == std::endian::little, "safetensors I/O assumes a little-endian machine");

/// A malformed, truncated or incompatible safetensors file; the message starts with the file name.
class safetensors_error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Size in bytes of one element of a safetensors dtype ("F32", "F64", "I64", ...); 0 if unknown.
inline std::size_t safetensors_dtype_size(std::string_view dtype) noexcept {
  static constexpr std::pair<std::string_view, std::size_t> sizes[] = {
      {"BOOL", 1}, {"U8", 1},  {"I8", 1},  {"F8_E5M2", 1}, {"F8_E4M3", 1}, {"I16", 2}, {"U16", 2}, {"F16", 2},
      {"BF16", 2}, {"I32", 4}, {"U32", 4}, {"F32", 4},     {"I64", 8},     {"U64", 8}, {"F64", 8}};
  for (const auto& [name, size] : sizes)
    if (name == dtype) return size;
  return 0;
}

/// The safetensors dtype of a C++ element type (float: "F32", double: "F64").
template <class T>
constexpr const char* safetensors_dtype() {
  if constexpr (std::is_same_v<T, float>) return "F32";
  else if constexpr (std::is_same_v<T, double>) return "F64";
  else if constexpr (std::is_same_v<T, std::int64_t>) return "I64";
  else if constexpr (std::is_same_v<T, std::int32_t>) return "I32";
  else static_assert(sizeof(T) == 0, "no safetensors dtype for this type");
}

/// How save_weights and convert_weights store a network's float tensors: all as "F32", or the
/// large ones (half_storage_min_elements or more elements: the convolution kernels) as "F16", the
/// biases and batch-norm statistics staying "F32" (a few kilobytes, and the statistics span a
/// range a half float does not).
enum class weight_storage { f32, f16 };

/// The smallest float tensor weight_storage::f16 stores as half floats.
inline constexpr std::size_t half_storage_min_elements = 1024;

/// The largest finite half float (65504).
inline constexpr float half_max = 65504.0f;

/// The contents of a safetensors file: named tensors (raw bytes, in file order) and metadata.
class safetensors_file {
 public:
  /// One tensor: dtype, shape (outermost first) and its bytes [begin, end) in the data region.
  struct entry {
    std::string name;
    std::string dtype;
    std::vector<std::int64_t> shape;
    std::size_t begin = 0, end = 0;
    /// Borrowed bytes (add_view), [view, view + end - begin); null: the bytes are the data
    /// region's [begin, end).
    const std::byte* view = nullptr;
    /// Number of elements (1 for a scalar of shape []).
    std::size_t count() const noexcept {
      std::size_t n = 1;
      for (auto d : shape) n *= std::size_t(d);
      return n;
    }
  };

  /// The `__metadata__` string pairs, in file order.
  std::vector<std::pair<std::string, std::string>> metadata;

  /// Appends a tensor (its bytes are copied). Throws std::invalid_argument for a repeated or
  /// reserved name, an unknown dtype, or a byte count that does not match dtype and shape.
  void add(std::string name, std::string dtype, std::vector<std::int64_t> shape, const void* data, std::size_t bytes) {
    entry e = checked(std::move(name), std::move(dtype), std::move(shape), bytes);
    e.begin = data_.size();
    e.end = e.begin + bytes;
    const auto* p = static_cast<const std::byte*>(data);
    data_.insert(data_.end(), p, p + bytes);
    entries_.push_back(std::move(e));
  }

  /// Appends a tensor without copying its bytes: the file borrows them, and they must stay alive
  /// and unchanged until it is written (write_safetensors) or read through bytes(). A writer that
  /// saves large buffers and writes at once (weights, optimiser moments) copies nothing. Throws
  /// as add.
  void add_view(std::string name, std::string dtype, std::vector<std::int64_t> shape, const void* data, std::size_t bytes) {
    entry e = checked(std::move(name), std::move(dtype), std::move(shape), bytes);
    e.end = bytes;
    e.view = static_cast<const std::byte*>(data);
    entries_.push_back(std::move(e));
  }

  /// Appends a tensor of float, double, int32 or int64 values (copied).
  template <class T>
  void add(std::string name, std::vector<std::int64_t> shape, const T* data, std::size_t count) {
    add(std::move(name), safetensors_dtype<T>(), std::move(shape), data, count * sizeof(T));
  }
  /// Appends a tensor of float, double, int32 or int64 values, borrowed (add_view).
  template <class T>
  void add_view(std::string name, std::vector<std::int64_t> shape, const T* data, std::size_t count) {
    add_view(std::move(name), safetensors_dtype<T>(), std::move(shape), data, count * sizeof(T));
  }

  /// The tensor called `name`, or nullptr.
  const entry* find(std::string_view name) const noexcept {
    for (const auto& e : entries_)
      if (e.name == name) return &e;
    return nullptr;
  }
  /// All tensors in file order.
  const std::vector<entry>& entries() const noexcept { return entries_; }
  /// The raw little-endian bytes of a tensor.
  std::span<const std::byte> bytes(const entry& e) const noexcept {
    return {e.view ? e.view : data_.data() + e.begin, e.end - e.begin};
  }
  /// The data region: the bytes of the tensors copied in (add) or read; borrowed ones are not in it.
  std::span<const std::byte> data() const noexcept { return data_; }
  /// The bytes of all tensors, copied and borrowed: the size of a written file's data region.
  std::size_t data_bytes() const noexcept {
    std::size_t n = 0;
    for (const auto& e : entries_) n += e.end - e.begin;
    return n;
  }

  /// Builds from parsed entries and the data region (used by read_safetensors).
  safetensors_file(std::vector<entry> entries, std::vector<std::byte> data,
                   std::vector<std::pair<std::string, std::string>> meta)
      : metadata(std::move(meta)), entries_(std::move(entries)), data_(std::move(data)) {}
  safetensors_file() = default;

 private:
  /// A new entry's name, dtype and shape checked against `bytes` (offsets not set).
  entry checked(std::string name, std::string dtype, std::vector<std::int64_t> shape, std::size_t bytes) const {
    if (name.empty() || name == "__metadata__") throw std::invalid_argument("safetensors: invalid tensor name '" + name + "'");
    if (find(name)) throw std::invalid_argument("safetensors: tensor '" + name + "' added twice");
    const std::size_t element = safetensors_dtype_size(dtype);
    if (!element) throw std::invalid_argument("safetensors: unknown dtype '" + dtype + "'");
    entry e{std::move(name), std::move(dtype), std::move(shape), 0, 0};
    for (auto d : e.shape)
      if (d < 0) throw std::invalid_argument("safetensors: negative dimension in tensor '" + e.name + "'");
    if (e.count() * element != bytes)
      throw std::invalid_argument("safetensors: tensor '" + e.name + "' has " + std::to_string(bytes) +
                                  " bytes, its dtype and shape need " + std::to_string(e.count() * element));
    return e;
  }

  std::vector<entry> entries_;
  std::vector<std::byte> data_;
};

namespace detail {

/// Header size above which a file is rejected before allocating (the reference library's limit).
inline constexpr std::uint64_t safetensors_max_header = 100'000'000;

[[noreturn]] inline void safetensors_fail(const std::filesystem::path& file, const std::string& problem) {
  throw safetensors_error(file.string() + ": " + problem);
}

/// A non-negative integer below 2^53 from a JSON number, or a clear error.
inline std::uint64_t safetensors_integer(const std::filesystem::path& file, const json& v, const std::string& what) {
  if (!v.is_number()) safetensors_fail(file, what + " is a " + json_kind_name(v) + ", expected an integer");
  if (v.is_number_unsigned()) {
    const std::uint64_t u = v.get<std::uint64_t>();
    if (u > (std::uint64_t(1) << 53)) safetensors_fail(file, what + " is not a non-negative integer below 2^53");
    return u;
  }
  const double d = v.get<double>();
  if (!(d >= 0) || d != double(std::uint64_t(d)) || d > 9007199254740992.0)
    safetensors_fail(file, what + " is not a non-negative integer");
  return std::uint64_t(d);
}

inline std::string shape_string(const std::vector<std::int64_t>& shape) {
  std::string s = "[";
  for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
  return s + "]";
}

/// Whether a tensor of `dtype` loads into parameters of type T: its own dtype, or F16 into float.
template <class T>
bool loadable_dtype(std::string_view dtype) {
  return dtype == safetensors_dtype<T>() || (std::is_same_v<T, float> && dtype == "F16");
}

/// The values of a tensor of a loadable_dtype<T> (`dtype`, its bytes) as T into `out` (one value per
/// element): its own type copied, half floats widened to float.
template <class T>
void decode_tensor(std::string_view dtype, std::span<const std::byte> bytes, std::span<T> out) {
  if constexpr (std::is_same_v<T, float>) {
    if (dtype == "F16") {
      for (std::size_t i = 0; i < out.size(); ++i) {
        std::uint16_t bits;
        std::memcpy(&bits, bytes.data() + i * 2, 2);
        out[i] = float(Eigen::numext::bit_cast<Eigen::half>(bits));
      }
      return;
    }
  }
  std::memcpy(static_cast<void*>(out.data()), bytes.data(), out.size() * sizeof(T));
}

/// A float tensor's values as half floats (round to nearest even); throws std::invalid_argument
/// naming the tensor when a value is beyond the half floats' range.
inline std::vector<std::uint16_t> to_half(const std::string& name, const float* values, std::size_t count) {
  std::vector<std::uint16_t> bits(count);
  for (std::size_t i = 0; i < count; ++i) {
    if (!(std::abs(values[i]) <= half_max))
      throw std::invalid_argument("tensor '" + name + "' holds " + std::to_string(values[i]) + " at element " + std::to_string(i) +
                                  ", beyond the half floats' range (65504): store it as F32");
    bits[i] = Eigen::numext::bit_cast<std::uint16_t>(Eigen::half(values[i]));
  }
  return bits;
}

}  // namespace detail

/// A safetensors file's header: its tensors (names, dtypes, shapes and offsets into the data
/// region), its metadata and the size of its data region, without the data.
struct safetensors_header {
  std::vector<safetensors_file::entry> entries;               ///< tensors in file order (by offset)
  std::vector<std::pair<std::string, std::string>> metadata;  ///< the `__metadata__` pairs, in file order
  std::uint64_t data_size = 0;                                ///< bytes in the data region
};

namespace detail {

/// The JSON text of a safetensors file's header from `in` (opened at its end, binary), checking
/// its length against the file's; sets `data_size` to the bytes after it.
inline std::string read_safetensors_header_text(const std::filesystem::path& file, std::ifstream& in, std::uint64_t& data_size) {
  if (!in) safetensors_fail(file, "cannot open the file");
  const std::uint64_t file_size = std::uint64_t(in.tellg());
  in.seekg(0);
  if (file_size < 8) safetensors_fail(file, "truncated: " + std::to_string(file_size) + " bytes, fewer than the 8-byte header length");
  unsigned char length_bytes[8];
  in.read(reinterpret_cast<char*>(length_bytes), 8);
  std::uint64_t header_length = 0;
  for (int i = 7; i >= 0; --i) header_length = header_length << 8 | length_bytes[i];
  if (header_length > detail::safetensors_max_header)
    safetensors_fail(file, "header length " + std::to_string(header_length) + " exceeds the 100 MB limit (not a safetensors file?)");
  if (header_length > file_size - 8)
    safetensors_fail(file, "header length " + std::to_string(header_length) + " exceeds the " +
                               std::to_string(file_size - 8) + " bytes after it (truncated?)");
  std::string header(header_length, '\0');
  in.read(header.data(), std::streamsize(header_length));
  if (!in) safetensors_fail(file, "read error");
  data_size = file_size - 8 - header_length;
  return header;
}

/// One tensor's header entry `v` named `name`, checked: its three keys, a known dtype, integer
/// dimensions, offsets in order and within the `data_size` bytes, and as many bytes as dtype and
/// shape need.
inline safetensors_file::entry parse_safetensors_entry(const std::filesystem::path& file, const std::string& name, const json& o,
                                                       std::uint64_t data_size) {
  const std::string where = "tensor '" + name + "'";
  if (!o.is_object()) safetensors_fail(file, where + " is not a JSON object");
  for (const char* key : {"dtype", "shape", "data_offsets"})
    if (!o.contains(key)) safetensors_fail(file, where + " has no \"" + key + "\"");
  if (o.size() != 3) safetensors_fail(file, where + " has keys other than dtype, shape and data_offsets");
  safetensors_file::entry e;
  e.name = name;
  if (!o.at("dtype").is_string()) safetensors_fail(file, where + ": dtype is not a string");
  e.dtype = o.at("dtype").get<std::string>();
  const std::size_t element = safetensors_dtype_size(e.dtype);
  if (!element) safetensors_fail(file, where + " has unknown dtype '" + e.dtype + "'");
  if (!o.at("shape").is_array()) safetensors_fail(file, where + ": shape is not an array");
  for (const auto& d : o.at("shape")) e.shape.push_back(std::int64_t(detail::safetensors_integer(file, d, where + ": a dimension")));
  if (!o.at("data_offsets").is_array() || o.at("data_offsets").size() != 2)
    safetensors_fail(file, where + ": data_offsets is not an array of two integers");
  e.begin = detail::safetensors_integer(file, o.at("data_offsets")[0], where + ": data_offsets[0]");
  e.end = detail::safetensors_integer(file, o.at("data_offsets")[1], where + ": data_offsets[1]");
  if (e.begin > e.end) safetensors_fail(file, where + ": data_offsets [" + std::to_string(e.begin) + ", " + std::to_string(e.end) + "] are reversed");
  if (e.end > data_size)
    safetensors_fail(file, where + ": data_offsets [" + std::to_string(e.begin) + ", " + std::to_string(e.end) +
                               "] out of range: the data region has " + std::to_string(data_size) + " bytes (truncated?)");
  // Overflow-safe count * element == end - begin.
  std::size_t count = 1;
  bool overflow = false;
  for (auto d : e.shape) {
    if (d != 0 && count > (std::size_t(-1) / element) / std::size_t(d)) overflow = true;
    count *= std::size_t(d);
  }
  if (overflow || count * element != e.end - e.begin)
    safetensors_fail(file, where + ": " + std::to_string(e.end - e.begin) + " bytes of data, but dtype " + e.dtype + " and shape " +
                               detail::shape_string(e.shape) + " need " + (overflow ? std::string("more than 2^64") : std::to_string(count * element)));
  return e;
}

/// Sorts the tensors into file order (by offset) and checks that they tile the data region of
/// `data_size` bytes: each starts where the previous ends, and the last ends at its end.
inline void sort_and_check_safetensors_tiling(const std::filesystem::path& file, std::vector<safetensors_file::entry>& entries,
                                              std::uint64_t data_size) {
  std::sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) { return a.begin != b.begin ? a.begin < b.begin : a.end < b.end; });
  std::size_t position = 0;
  for (const auto& e : entries) {
    if (e.begin != position)
      safetensors_fail(file, "tensor '" + e.name + "' starts at data byte " + std::to_string(e.begin) + ", expected " +
                                 std::to_string(position) + (e.begin < position ? " (overlapping tensors)" : " (a gap)"));
    position = e.end;
  }
  if (position != data_size) safetensors_fail(file, std::to_string(data_size - position) + " bytes of data after the last tensor");
}

/// Reads and validates the header of a safetensors file from `in` (opened at its end, binary).
inline safetensors_header read_safetensors_header(const std::filesystem::path& file, std::ifstream& in) {
  std::uint64_t data_size = 0;
  const std::string header = read_safetensors_header_text(file, in, data_size);
  json root;
  try {
    root = parse_json(header, file.string() + " (header)");
  } catch (const json_error& e) {
    safetensors_fail(file, std::string("bad JSON header: ") + e.what());
  }
  if (!root.is_object()) safetensors_fail(file, std::string("the header is a JSON ") + json_kind_name(root) + ", expected an object");
  std::vector<safetensors_file::entry> entries;
  std::vector<std::pair<std::string, std::string>> metadata;
  for (const auto& [name, v] : root.items()) {
    if (name != "__metadata__") {
      entries.push_back(parse_safetensors_entry(file, name, v, data_size));
      continue;
    }
    if (!v.is_object()) safetensors_fail(file, "__metadata__ is not an object");
    for (const auto& [key, text] : v.items()) {
      if (!text.is_string()) safetensors_fail(file, "__metadata__ value '" + key + "' is not a string");
      metadata.emplace_back(key, text.get<std::string>());
    }
  }
  sort_and_check_safetensors_tiling(file, entries, data_size);
  return {std::move(entries), std::move(metadata), data_size};
}

}  // namespace detail

/// Reads and validates a safetensors file's header only (the tensors' names, dtypes, shapes and
/// offsets, and the metadata), checking the offsets against the file's size: what
/// read_safetensors checks, without reading the data. Throws safetensors_error as it does.
inline safetensors_header read_safetensors_header(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary | std::ios::ate);
  return detail::read_safetensors_header(file, in);
}

/// Reads and validates a safetensors file. Throws safetensors_error "file: problem" for a missing
/// or unreadable file, truncation, a header length beyond the file, bad JSON, an unknown dtype,
/// offsets out of range or not tiling the data, or a byte count that disagrees with dtype and shape.
inline safetensors_file read_safetensors(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary | std::ios::ate);
  safetensors_header header = detail::read_safetensors_header(file, in);
  std::vector<std::byte> data(header.data_size);
  in.read(reinterpret_cast<char*>(data.data()), std::streamsize(data.size()));
  if (!in) detail::safetensors_fail(file, "read error");
  return safetensors_file(std::move(header.entries), std::move(data), std::move(header.metadata));
}

/// Writes a safetensors file (metadata first, then the tensors in their order, at offsets following
/// one another), through a temporary file renamed into place. Throws safetensors_error naming the
/// file when it cannot be written.
inline void write_safetensors(const std::filesystem::path& file, const safetensors_file& contents) {
  json header = json::object();
  if (!contents.metadata.empty()) {
    json meta = json::object();
    for (const auto& [k, v] : contents.metadata) meta[k] = v;
    header["__metadata__"] = std::move(meta);
  }
  std::uint64_t offset = 0;  // the tensors follow one another in entry order, copied or borrowed alike
  for (const auto& e : contents.entries()) {
    json entry = json::object();
    entry["dtype"] = e.dtype;
    entry["shape"] = e.shape;
    entry["data_offsets"] = json::array({offset, offset + (e.end - e.begin)});
    offset += e.end - e.begin;
    header[e.name] = std::move(entry);
  }
  std::string text = header.dump();
  text.resize((text.size() + 7) / 8 * 8, ' ');  // the data region starts 8-byte aligned, as the reference writer does
  unsigned char length_bytes[8];
  for (int i = 0; i < 8; ++i) length_bytes[i] = static_cast<unsigned char>(std::uint64_t(text.size()) >> (8 * i));

  std::filesystem::path temporary = file;
  temporary += ".tmp";
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    if (!out) detail::safetensors_fail(file, "cannot create " + temporary.string());
    out.write(reinterpret_cast<const char*>(length_bytes), 8);
    out.write(text.data(), std::streamsize(text.size()));
    for (const auto& e : contents.entries()) {  // straight from each tensor's bytes: nothing gathered first
      const auto bytes = contents.bytes(e);
      out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
    }
    out.flush();
    if (!out) {
      out.close();
      std::error_code ignored;
      std::filesystem::remove(temporary, ignored);
      detail::safetensors_fail(file, "write error");
    }
  }
  std::error_code ec;
  std::filesystem::rename(temporary, file, ec);
  if (ec) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    detail::safetensors_fail(file, "cannot rename the temporary file into place: " + ec.message());
  }
}

namespace detail {
template <class Network, class F>
void visit_weights(Network& net, F&& f) {
  net.for_each_parameter(f);
  if constexpr (requires { net.for_each_buffer(f); }) net.for_each_buffer(f);
}

/// Throws safetensors_error naming `file` and the tensor when a value of tensor `e` (a
/// loadable_dtype of T) is not finite: a NaN weight would only show as NaN maps much later.
/// Float and half-float tensors are checked on their bits where they lie (an exponent of all ones is
/// an infinity or a NaN), without decoding a copy: the paper preset's networks load 390 MB.
template <class T>
void check_finite(const std::filesystem::path& file, const safetensors_file& contents, const safetensors_file::entry& e) {
  const auto fail = [&](std::size_t i) {
    safetensors_fail(file, "tensor '" + e.name + "' holds a value that is not finite at element " + std::to_string(i));
  };
  const std::span<const std::byte> bytes = contents.bytes(e);
  const auto first_with_exponent = [&]<class Bits>(Bits mask) {  // index of the first value whose exponent bits are all set
    const std::size_t n = bytes.size() / sizeof(Bits);
    for (std::size_t start = 0; start < n; start += 4096) {  // blocks: a vectorisable test, then the exact index
      const std::size_t end = std::min(n, start + 4096);
      bool any = false;
      for (std::size_t i = start; i < end; ++i) {
        Bits v;
        std::memcpy(&v, bytes.data() + i * sizeof(Bits), sizeof(Bits));
        any |= (v & mask) == mask;
      }
      if (!any) continue;
      for (std::size_t i = start; i < end; ++i) {
        Bits v;
        std::memcpy(&v, bytes.data() + i * sizeof(Bits), sizeof(Bits));
        if ((v & mask) == mask) return i;
      }
    }
    return n;
  };
  if (e.dtype == "F32" || e.dtype == "F16") {
    const std::size_t i = e.dtype == "F32" ? first_with_exponent(std::uint32_t(0x7F800000u)) : first_with_exponent(std::uint16_t(0x7C00u));
    if (i < e.count()) fail(i);
    return;
  }
  std::vector<T> values(e.count());
  decode_tensor<T>(e.dtype, bytes, values);
  for (std::size_t i = 0; i < values.size(); ++i)
    if (!std::isfinite(double(values[i]))) fail(i);
}

/// Copies a checked tensor (a loadable_dtype of the parameter's type, its shape) into parameter p.
template <class Parameter>
void copy_tensor(const safetensors_file& contents, const safetensors_file::entry& e, Parameter& p) {
  using T = std::remove_cvref_t<decltype(p.value[0])>;
  detail::decode_tensor<T>(e.dtype, contents.bytes(e), std::span<T>(p.value.data(), e.count()));
}
}  // namespace detail

/// Saves every parameter of a layer or network (for_each_parameter, then for_each_buffer where the
/// network has one, e.g. batch-norm running statistics) under its name, with its logical shape.
///
/// With weight_storage::f16 the float tensors of half_storage_min_elements or more elements are
/// stored as half floats (a value beyond their range is refused, naming the tensor, and nothing is
/// written).
template <class Network>
void save_weights(const std::filesystem::path& file, Network& net, std::vector<std::pair<std::string, std::string>> metadata = {},
                  weight_storage storage = weight_storage::f32) {
  safetensors_file contents;  // the parameters' own bytes, borrowed; only half floats are made
  contents.metadata = std::move(metadata);
  detail::visit_weights(net, [&](auto& p) {
    using T = std::remove_cvref_t<decltype(p.value[0])>;
    std::vector<std::int64_t> shape(p.shape.begin(), p.shape.end());
    try {
      if constexpr (std::is_same_v<T, float>) {
        if (storage == weight_storage::f16 && p.size() >= half_storage_min_elements) {
          const auto bits = detail::to_half(p.name, p.value.data(), p.size());
          contents.add(p.name, "F16", std::move(shape), bits.data(), bits.size() * 2);
          return;
        }
      }
      contents.add_view<T>(p.name, std::move(shape), p.value.data(), p.size());
    } catch (const std::invalid_argument& e) {
      detail::safetensors_fail(file, e.what());
    }
  });
  write_safetensors(file, contents);
}

/// Loads every parameter (and buffer) of a network from a file by name. All tensors are checked
/// first (present, dtype matching the parameter's type, same shape), so a failed load changes
/// nothing; tensors in the file that the network does not have are ignored.
template <class Network>
void load_weights(const std::filesystem::path& file, Network& net) {
  const safetensors_file contents = read_safetensors(file);
  detail::visit_weights(net, [&](auto& p) {
    using T = std::remove_cvref_t<decltype(p.value[0])>;
    const auto* e = contents.find(p.name);
    if (!e) detail::safetensors_fail(file, "missing tensor '" + p.name + "'");
    if (!detail::loadable_dtype<T>(e->dtype))
      detail::safetensors_fail(file, "tensor '" + p.name + "' has dtype " + e->dtype + ", expected " + safetensors_dtype<T>() +
                                         (std::is_same_v<T, float> ? " or F16" : ""));
    const std::vector<std::int64_t> expected(p.shape.begin(), p.shape.end());
    if (e->shape != expected)
      detail::safetensors_fail(file, "tensor '" + p.name + "' has shape " + detail::shape_string(e->shape) + ", expected " +
                                         detail::shape_string(expected));
    detail::check_finite<T>(file, contents, *e);
  });
  detail::visit_weights(net, [&](auto& p) { detail::copy_tensor(contents, *contents.find(p.name), p); });
}

/// Loads the parameters (and buffers) whose tensor the file has with the same name, dtype and
/// shape, and returns the names of the others, which keep their values: a fresh training run of a
/// variant network (another output head) starts from a related network's weights this way. Every
/// tensor that loads is checked first, as load_weights does. Throws when no tensor matches (the
/// file is not of this kind of network at all).
template <class Network>
std::vector<std::string> load_matching_weights(const std::filesystem::path& file, Network& net) {
  const safetensors_file contents = read_safetensors(file);
  std::vector<std::string> skipped;
  std::size_t matched = 0;
  auto matches = [&](auto& p) {
    using T = std::remove_cvref_t<decltype(p.value[0])>;
    const auto* e = contents.find(p.name);
    return e && detail::loadable_dtype<T>(e->dtype) && e->shape == std::vector<std::int64_t>(p.shape.begin(), p.shape.end());
  };
  detail::visit_weights(net, [&](auto& p) {
    if (!matches(p)) {
      skipped.push_back(p.name);
      return;
    }
    ++matched;
    using T = std::remove_cvref_t<decltype(p.value[0])>;
    detail::check_finite<T>(file, contents, *contents.find(p.name));
  });
  if (matched == 0) detail::safetensors_fail(file, "no tensor matches this network's parameters by name and shape");
  detail::visit_weights(net, [&](auto& p) {
    if (matches(p)) detail::copy_tensor(contents, *contents.find(p.name), p);
  });
  return skipped;
}

/// Rewrites a weight file with its float tensors stored as `storage` says (weight_storage): F32
/// tensors of half_storage_min_elements or more elements to F16 for f16, F16 tensors back to F32 for
/// f32 (exactly: every half float is a float); other tensors and the metadata as they are. Writes
/// through a temporary name; throws safetensors_error naming `in` for an unreadable file or a value
/// beyond the half floats' range, and `out` when it cannot be written (nothing written then).
inline void convert_weights(const std::filesystem::path& in, const std::filesystem::path& out, weight_storage storage) {
  const safetensors_file source = read_safetensors(in);
  safetensors_file result;
  result.metadata = source.metadata;
  for (const auto& e : source.entries()) {
    const auto bytes = source.bytes(e);
    try {
      if (storage == weight_storage::f16 && e.dtype == "F32" && e.count() >= half_storage_min_elements) {
        std::vector<float> values(e.count());
        std::memcpy(values.data(), bytes.data(), bytes.size());
        const auto bits = detail::to_half(e.name, values.data(), values.size());
        result.add(e.name, "F16", e.shape, bits.data(), bits.size() * 2);
      } else if (storage == weight_storage::f32 && e.dtype == "F16") {
        std::vector<float> values(e.count());
        detail::decode_tensor<float>("F16", bytes, values);
        result.add<float>(e.name, e.shape, values.data(), values.size());
      } else {
        result.add(e.name, e.dtype, e.shape, bytes.data(), bytes.size());
      }
    } catch (const std::invalid_argument& error) {
      detail::safetensors_fail(in, error.what());
    }
  }
  write_safetensors(out, result);
}

}  // namespace anisocap::nn
