// Weight files (nn/safetensors.hpp): bit-identical round trips, strict validation with errors that
// name the file and the problem, and an exchange with PyTorch in both directions when
// /usr/bin/python3 has torch (tests/nn/safetensors_torch_check.py; skipped otherwise).
#include <doctest/doctest.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <sys/wait.h>
#include <unistd.h>
#include <vector>

#include "anisocap/nn/layers.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "layer_check.hpp"

using namespace anisocap;
namespace fs = std::filesystem;

namespace {

fs::path scratch_directory() { return fs::temp_directory_path() / ("anisocap_safetensors_test_" + std::to_string(::getpid())); }

/// Removes this process's scratch files when the test program exits.
struct scratch_cleanup {
  ~scratch_cleanup() {
    std::error_code ignored;
    fs::remove_all(scratch_directory(), ignored);
  }
} cleanup_at_exit;

fs::path scratch(const std::string& name) {
  fs::create_directories(scratch_directory());
  return scratch_directory() / name;
}

std::string read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_all(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

/// A file with the given header text and `data_bytes` zero bytes of data.
std::string raw_file(const std::string& header, std::size_t data_bytes, std::uint64_t length_override = 0) {
  std::uint64_t n = length_override ? length_override : header.size();
  std::string s(8, '\0');
  for (int i = 0; i < 8; ++i) s[i] = char((n >> (8 * i)) & 0xff);
  return s + header + std::string(data_bytes, '\0');
}

/// The message of the safetensors_error that reading `bytes` as a file throws ("" if none). Reading
/// the header alone (read_safetensors_header) must fail with the same message: every check but the
/// read of the data itself is the header's.
std::string read_error(const std::string& bytes) {
  const fs::path p = scratch("corrupt.safetensors");
  write_all(p, bytes);
  auto message = [&](auto read) {
    try {
      read(p);
    } catch (const nn::safetensors_error& e) {
      std::string m = e.what();
      CHECK(m.find(p.string()) == 0);  // every message starts with the file's name
      return m;
    }
    return std::string();
  };
  const std::string whole = message([](const fs::path& f) { nn::read_safetensors(f); });
  CHECK(message([](const fs::path& f) { nn::read_safetensors_header(f); }) == whole);
  return whole;
}

struct small_network {
  nn::linear<5, 3> fc{"fc", 1};
  nn::batch_norm<3> bn{"bn"};
  template <class F> void for_each_parameter(F&& f) { fc.for_each_parameter(f); bn.for_each_parameter(f); }
  template <class F> void for_each_buffer(F&& f) { bn.for_each_buffer(f); }
};

bool contains(const std::string& haystack, const std::string& needle) { return haystack.find(needle) != std::string::npos; }

}  // namespace

TEST_CASE("safetensors: round trip is bit-identical") {
  nn::random_generator g(51);
  small_network a;
  nn::uniform_init(a.bn.running_mean, 1.0, 5);
  nn::uniform_init(a.bn.bias, 1.0, 6);
  const fs::path p = scratch("net.safetensors");
  nn::save_weights(p, a, {{"format", "pt"}, {"note", "quote \" and ü"}});
  small_network b{nn::linear<5, 3>{"fc", 99}, nn::batch_norm<3>{"bn"}};
  CHECK(b.fc.weight.value[0] != a.fc.weight.value[0]);
  nn::load_weights(p, b);
  auto same = [](const nn::parameter& x, const nn::parameter& y) {
    return x.size() == y.size() && std::memcmp(x.value.data(), y.value.data(), x.size() * sizeof(float)) == 0;
  };
  CHECK(same(a.fc.weight, b.fc.weight));
  CHECK(same(a.fc.bias, b.fc.bias));
  CHECK(same(a.bn.bias, b.bn.bias));
  CHECK(same(a.bn.running_mean, b.bn.running_mean));
  CHECK(same(a.bn.running_var, b.bn.running_var));

  auto file = nn::read_safetensors(p);
  REQUIRE(file.metadata.size() == 2);
  CHECK(file.metadata[1].second == "quote \" and ü");
  const auto* w = file.find("fc.weight");
  REQUIRE(w != nullptr);
  CHECK(w->dtype == "F32");
  CHECK(w->shape == std::vector<std::int64_t>{3, 5});
  // Layout: 8-byte length, header padded to 8 bytes, data; writing what was read gives the same bytes.
  const std::string bytes = read_all(p);
  std::uint64_t n = 0;
  for (int i = 7; i >= 0; --i) n = n << 8 | (unsigned char)bytes[i];
  CHECK(n % 8 == 0);
  CHECK(8 + n + file.data().size() == bytes.size());
  // The header alone says what the whole read says about the tensors and the metadata.
  const nn::safetensors_header header = nn::read_safetensors_header(p);
  CHECK(header.metadata == file.metadata);
  CHECK(header.data_size == file.data().size());
  REQUIRE(header.entries.size() == file.entries().size());
  for (std::size_t i = 0; i < header.entries.size(); ++i) {
    CHECK(header.entries[i].name == file.entries()[i].name);
    CHECK(header.entries[i].shape == file.entries()[i].shape);
    CHECK(header.entries[i].begin == file.entries()[i].begin);
    CHECK(header.entries[i].end == file.entries()[i].end);
  }
  const fs::path q = scratch("copy.safetensors");
  nn::write_safetensors(q, file);
  CHECK(read_all(q) == bytes);

  // Other dtypes and a scalar survive too.
  nn::safetensors_file f;
  const double d[3] = {1.0 / 3, -2.5e-300, 7};
  const std::int64_t steps = 12345678901234;
  f.add<double>("d", {3}, d, 3);
  f.add<std::int64_t>("steps", {}, &steps, 1);
  nn::write_safetensors(q, f);
  auto r = nn::read_safetensors(q);
  REQUIRE(r.find("steps") != nullptr);
  CHECK(r.find("steps")->shape.empty());
  CHECK(std::memcmp(r.bytes(*r.find("d")).data(), d, sizeof d) == 0);
  CHECK(std::memcmp(r.bytes(*r.find("steps")).data(), &steps, 8) == 0);
  CHECK_THROWS_AS(f.add<double>("d", {3}, d, 3), std::invalid_argument);
  CHECK_THROWS_AS(f.add<double>("e", {4}, d, 3), std::invalid_argument);
}

TEST_CASE("safetensors: borrowed tensors are written as copied ones, in the order added") {
  // The same tensors added as copies, and as views mixed with copies, in an order that is not
  // alphabetical: the two files are byte for byte the same, and read back in the order added.
  std::vector<float> big(3000), small = {1.5f, -2.0f};
  for (std::size_t i = 0; i < big.size(); ++i) big[i] = float(i) * 0.25f - 7.0f;
  const std::int64_t count = 42;
  nn::safetensors_file copied, borrowed;
  copied.add<float>("z.big", {3, 1000}, big.data(), big.size());
  copied.add<std::int64_t>("m.count", {1}, &count, 1);
  copied.add<float>("a.small", {2}, small.data(), small.size());
  borrowed.add_view<float>("z.big", {3, 1000}, big.data(), big.size());
  borrowed.add<std::int64_t>("m.count", {1}, &count, 1);
  borrowed.add_view<float>("a.small", {2}, small.data(), small.size());
  CHECK(borrowed.data().size() == sizeof count);  // only the copied tensor is in the data region
  CHECK(borrowed.data_bytes() == copied.data_bytes());
  CHECK(borrowed.bytes(*borrowed.find("z.big")).data() == reinterpret_cast<const std::byte*>(big.data()));
  const fs::path pc = scratch("copied.safetensors"), pb = scratch("borrowed.safetensors");
  nn::write_safetensors(pc, copied);
  nn::write_safetensors(pb, borrowed);
  CHECK(read_all(pc) == read_all(pb));
  const auto r = nn::read_safetensors(pb);
  REQUIRE(r.entries().size() == 3);
  CHECK(r.entries()[0].name == "z.big");
  CHECK(r.entries()[1].name == "m.count");
  CHECK(r.entries()[2].name == "a.small");
  CHECK(std::memcmp(r.bytes(r.entries()[0]).data(), big.data(), big.size() * sizeof(float)) == 0);
  CHECK(std::memcmp(r.bytes(r.entries()[2]).data(), small.data(), small.size() * sizeof(float)) == 0);
  CHECK_THROWS_AS(borrowed.add_view<float>("z.big", {2}, small.data(), 2), std::invalid_argument);
  CHECK_THROWS_AS(borrowed.add_view<float>("q", {3}, small.data(), 2), std::invalid_argument);
}

TEST_CASE("safetensors: corrupted and truncated files give clear errors") {
  const std::string good_header = R"({"w":{"dtype":"F32","shape":[2,2],"data_offsets":[0,16]}})";
  CHECK(read_error(raw_file(good_header, 16)) == "");  // the reference for the cases below

  CHECK(contains(read_error(raw_file(good_header, 12)), "out of range"));                   // truncated data
  CHECK(contains(read_error(raw_file(good_header, 12)), "truncated"));
  CHECK(contains(read_error(std::string("\x10\0\0", 3)), "fewer than the 8-byte header length"));
  CHECK(contains(read_error(raw_file(good_header, 16, 5000)), "exceeds"));                   // length beyond the file
  CHECK(contains(read_error(raw_file(good_header, 16, std::uint64_t(1) << 40)), "100 MB"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,2],)", 16)), "bad JSON"));
  CHECK(contains(read_error(raw_file(R"([1, 2])", 0)), "expected an object"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F33","shape":[2,2],"data_offsets":[0,16]}})", 16)), "unknown dtype 'F33'"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,2],"data_offsets":[0,400]}})", 16)), "out of range"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,3],"data_offsets":[0,16]}})", 16)), "need 24"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,-2],"data_offsets":[0,16]}})", 16)), "non-negative"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,2]}})", 16)), "no \"data_offsets\""));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,2],"data_offsets":[16,0]}})", 16)), "reversed"));
  CHECK(contains(read_error(raw_file(good_header, 20)), "4 bytes of data after the last tensor"));
  CHECK(contains(read_error(raw_file(R"({"a":{"dtype":"F32","shape":[2],"data_offsets":[0,8]},"b":{"dtype":"F32","shape":[2],"data_offsets":[4,12]}})", 12)), "overlapping"));
  CHECK(contains(read_error(raw_file(R"({"a":{"dtype":"F32","shape":[1],"data_offsets":[4,8]}})", 8)), "a gap"));
  CHECK(contains(read_error(raw_file(R"({"w":{"dtype":"F32","shape":[2,2],"data_offsets":[0,16]},"__metadata__":{"k":1}})", 16)), "not a string"));

  // A real file cut short, and one that does not exist.
  small_network net;
  const fs::path p = scratch("cut.safetensors");
  nn::save_weights(p, net);
  std::string bytes = read_all(p);
  CHECK(contains(read_error(bytes.substr(0, bytes.size() - 1)), "truncated"));
  CHECK(contains(read_error(bytes.substr(0, 40)), "exceeds"));
  CHECK_THROWS_WITH_AS(nn::read_safetensors(scratch("absent.safetensors")),
                       doctest::Contains("cannot open"), nn::safetensors_error);
}

TEST_CASE("safetensors: loading checks names, dtypes and shapes, and changes nothing on failure") {
  small_network net;
  const float original = net.fc.weight.value[0];
  const fs::path p = scratch("partial.safetensors");
  auto expect_load_error = [&](const nn::safetensors_file& f, const std::string& problem) {
    nn::write_safetensors(p, f);
    CHECK_THROWS_WITH_AS(nn::load_weights(p, net), doctest::Contains(problem.c_str()), nn::safetensors_error);
    CHECK(net.fc.weight.value[0] == original);
  };
  std::vector<float> w(15, 0.5f), b(3, 0.5f);
  std::vector<double> wd(15, 0.5);
  nn::safetensors_file f;
  f.add<float>("fc.weight", {3, 5}, w.data(), 15);
  f.add<float>("fc.bias", {3}, b.data(), 3);
  f.add<float>("bn.weight", {3}, b.data(), 3);
  f.add<float>("bn.bias", {3}, b.data(), 3);
  f.add<float>("bn.running_mean", {3}, b.data(), 3);
  expect_load_error(f, "missing tensor 'bn.running_var'");

  nn::safetensors_file wrong_dtype;
  wrong_dtype.add<double>("fc.weight", {3, 5}, wd.data(), 15);
  expect_load_error(wrong_dtype, "tensor 'fc.weight' has dtype F64, expected F32");

  nn::safetensors_file wrong_shape;
  wrong_shape.add<float>("fc.weight", {5, 3}, w.data(), 15);
  expect_load_error(wrong_shape, "tensor 'fc.weight' has shape [5, 3], expected [3, 5]");

  f.add<float>("bn.running_var", {3}, b.data(), 3);
  f.add<float>("extra", {3}, b.data(), 3);  // ignored
  nn::write_safetensors(p, f);
  nn::load_weights(p, net);
  CHECK(net.fc.weight.value[0] == 0.5f);
}

namespace {
struct wide_network {
  nn::linear<64, 32> fc{"fc", 7};  // 2048 weights: stored as half floats; the bias stays F32
  nn::batch_norm<32> bn{"bn"};
  template <class F> void for_each_parameter(F&& f) { fc.for_each_parameter(f); bn.for_each_parameter(f); }
  template <class F> void for_each_buffer(F&& f) { bn.for_each_buffer(f); }
};
}  // namespace

TEST_CASE("safetensors: half-float storage rounds the large tensors to the nearest half, keeps the rest, and loads as float") {
  wide_network a;
  nn::uniform_init(a.bn.running_mean, 1.0, 5);
  a.fc.weight.value[0] = 1.0f;
  a.fc.weight.value[1] = 1e-6f;  // a half subnormal
  a.fc.weight.value[2] = -65504.0f;
  const fs::path full = scratch("full.safetensors"), half = scratch("half.safetensors");
  nn::save_weights(full, a, {{"preset", "test"}});
  nn::save_weights(half, a, {{"preset", "test"}}, nn::weight_storage::f16);
  const auto file = nn::read_safetensors(half);
  CHECK(file.find("fc.weight")->dtype == "F16");
  CHECK(file.find("fc.bias")->dtype == "F32");
  CHECK(file.find("bn.running_var")->dtype == "F32");
  CHECK(file.metadata == nn::read_safetensors(full).metadata);
  CHECK(fs::file_size(half) + 2048 * 2 <= fs::file_size(full) + 8);  // the weights' 8 kB become 4 kB (header padding aside)
  std::uint16_t bits;
  std::memcpy(&bits, file.bytes(*file.find("fc.weight")).data(), 2);
  CHECK(bits == 0x3C00);  // 1.0 in IEEE binary16
  // Loaded: each weight is within half a unit in the last place of a half float of the original
  // (relative 2^-11; absolute 2^-25 for the subnormals), the small tensors exactly the same.
  wide_network b;
  b.fc.weight.value[0] = 5;
  nn::load_weights(half, b);
  for (std::size_t i = 0; i < a.fc.weight.size(); ++i) {
    const float x = a.fc.weight.value[i], y = b.fc.weight.value[i];
    CHECK(std::abs(y - x) <= std::max(std::abs(x) * 0x1p-11f, 0x1p-25f));
  }
  CHECK(b.fc.weight.value[0] == 1.0f);
  CHECK(b.fc.weight.value[2] == -65504.0f);
  CHECK(b.fc.weight.value[1] != 1e-6f);
  CHECK(std::abs(b.fc.weight.value[1] - 1e-6f) <= 0x1p-25f);
  CHECK(std::memcmp(a.fc.bias.value.data(), b.fc.bias.value.data(), a.fc.bias.size() * 4) == 0);
  CHECK(std::memcmp(a.bn.running_mean.value.data(), b.bn.running_mean.value.data(), a.bn.running_mean.size() * 4) == 0);
  // load_matching_weights reads half floats too.
  wide_network c;
  CHECK(nn::load_matching_weights(half, c).empty());
  CHECK(c.fc.weight.value[0] == 1.0f);
  // convert_weights: F32 to F16 gives save_weights' half file byte for byte; back to F32 gives the
  // half floats' values exactly, as F32.
  const fs::path converted = scratch("converted.safetensors"), back = scratch("back.safetensors");
  nn::convert_weights(full, converted, nn::weight_storage::f16);
  CHECK(read_all(converted) == read_all(half));
  nn::convert_weights(half, back, nn::weight_storage::f32);
  CHECK(nn::read_safetensors(back).find("fc.weight")->dtype == "F32");
  wide_network d;
  nn::load_weights(back, d);
  CHECK(std::memcmp(d.fc.weight.value.data(), b.fc.weight.value.data(), b.fc.weight.size() * 4) == 0);
  // A weight beyond the half floats' range is refused, naming the tensor, and nothing is written.
  a.fc.weight.value[3] = 65520.0f;  // rounds to infinity
  const fs::path refused = scratch("refused.safetensors");
  CHECK_THROWS_WITH_AS(nn::save_weights(refused, a, {}, nn::weight_storage::f16), doctest::Contains("'fc.weight'"), nn::safetensors_error);
  CHECK_FALSE(fs::exists(refused));
  nn::save_weights(full, a);
  CHECK_THROWS_WITH_AS(nn::convert_weights(full, refused, nn::weight_storage::f16), doctest::Contains(full.string().c_str()),
                       nn::safetensors_error);
  CHECK_FALSE(fs::exists(refused));
  // A half float that is not finite is refused at load, as a float one is.
  nn::safetensors_file with_inf = nn::read_safetensors(half);
  nn::safetensors_file broken;
  for (const auto& e : with_inf.entries()) {
    std::vector<std::byte> bytes(with_inf.bytes(e).begin(), with_inf.bytes(e).end());
    if (e.name == "fc.weight") bytes[9] = std::byte{0x7C}, bytes[8] = std::byte{0};  // element 4: +infinity
    broken.add(e.name, e.dtype, e.shape, bytes.data(), bytes.size());
  }
  nn::write_safetensors(refused, broken);
  CHECK_THROWS_WITH_AS(nn::load_weights(refused, d), doctest::Contains("not finite at element 4"), nn::safetensors_error);
  // And a float NaN at the last element, found on the bits where they lie; nothing is loaded.
  a.fc.weight.value[3] = 1.0f;
  nn::save_weights(full, a);
  nn::safetensors_file with_nan = nn::read_safetensors(full), broken_f32;
  for (const auto& e : with_nan.entries()) {
    std::vector<std::byte> bytes(with_nan.bytes(e).begin(), with_nan.bytes(e).end());
    if (e.name == "fc.weight") {
      const float nan = std::numeric_limits<float>::quiet_NaN();
      std::memcpy(bytes.data() + 2047 * 4, &nan, 4);
    }
    broken_f32.add(e.name, e.dtype, e.shape, bytes.data(), bytes.size());
  }
  nn::write_safetensors(refused, broken_f32);
  const std::vector<float> before(d.fc.weight.value.begin(), d.fc.weight.value.end());
  CHECK_THROWS_WITH_AS(nn::load_weights(refused, d), doctest::Contains("not finite at element 2047"), nn::safetensors_error);
  CHECK(std::equal(before.begin(), before.end(), d.fc.weight.value.begin()));
}

TEST_CASE("safetensors: exchange with PyTorch") {
  const std::string script = std::string(ANISOCAP_SOURCE_DIR) + "/tests/nn/safetensors_torch_check.py";
  const fs::path from_torch = scratch("from_torch.safetensors"), to_torch = scratch("to_torch.safetensors");
  const std::string python = "/usr/bin/python3";
  if (!fs::exists(python)) {
    MESSAGE("skipped: no " << python);
    return;
  }
  // anisocap -> PyTorch: the script loads our linear and batch-norm weights into torch modules and
  // compares torch's outputs with ours (NHWC here, NCHW there).
  small_network net;
  nn::uniform_init(net.bn.weight, 1.0, 3);
  nn::uniform_init(net.bn.bias, 1.0, 4);
  nn::uniform_init(net.bn.running_mean, 1.0, 5);
  for (auto& v : net.bn.running_var.value) v = 2.0f;
  net.bn.training = false;
  nn::random_generator g(52);
  auto xin = test_nn::random_tensor<5, float>(g, 2, 3, 4);
  ad::tape t2;
  auto h = net.fc(t2, t2.leaf(xin));
  auto z = net.bn(t2, h);
  nn::safetensors_file f;
  net.for_each_parameter([&](nn::parameter& p) { f.add<float>(p.name, {p.shape.begin(), p.shape.end()}, p.value.data(), p.size()); });
  net.for_each_buffer([&](nn::parameter& p) { f.add<float>(p.name, {p.shape.begin(), p.shape.end()}, p.value.data(), p.size()); });
  f.add<float>("input_nhwc", {2, 3, 4, 5}, xin.data(), xin.size());
  f.add<float>("fc_output_nhwc", {2, 3, 4, 3}, h.value.data(), h.value.size());
  f.add<float>("bn_output_nhwc", {2, 3, 4, 3}, z.value.data(), z.value.size());
  nn::write_safetensors(to_torch, f);
  const int status = std::system((python + " " + script + " " + to_torch.string() + " " + from_torch.string()).c_str());
  REQUIRE(WIFEXITED(status));
  if (WEXITSTATUS(status) == 77) {
    MESSAGE("skipped: torch is not available to " << python);
    return;
  }
  REQUIRE(WEXITSTATUS(status) == 0);  // 1: torch's outputs differ from ours

  // PyTorch -> anisocap: the values the script wrote are fixed formulas.
  auto file = nn::read_safetensors(from_torch);
  const auto* a = file.find("a");
  REQUIRE(a != nullptr);
  CHECK(a->dtype == "F32");
  CHECK(a->shape == std::vector<std::int64_t>{3, 4});
  std::vector<float> av(12);
  std::memcpy(av.data(), file.bytes(*a).data(), 48);
  for (int i = 0; i < 12; ++i) CHECK(av[i] == float(i) * 0.5f - 1.0f);
  const auto* steps = file.find("bn.num_batches_tracked");
  REQUIRE(steps != nullptr);
  CHECK(steps->dtype == "I64");
  CHECK(steps->shape.empty());
  // A torch.nn.Linear(5, 3) state loads into nn::linear<5, 3> (same weight layout) and gives the
  // output torch computed.
  nn::linear<5, 3> fc("fc");
  nn::load_weights(from_torch, fc);
  const auto* in = file.find("fc.input");
  const auto* out = file.find("fc.output");
  REQUIRE(in != nullptr);
  REQUIRE(out != nullptr);
  tensor<5> x(2, 1, 1);
  std::memcpy(x.data(), file.bytes(*in).data(), 40);
  ad::tape t;
  auto y = fc(t, t.leaf(x));
  std::vector<float> expected(6);
  std::memcpy(expected.data(), file.bytes(*out).data(), 24);
  for (int i = 0; i < 6; ++i) CHECK(y.value.data()[i] == doctest::Approx(expected[i]).epsilon(1e-5));
}
