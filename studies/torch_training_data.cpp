// Training data and reference outputs for studies/train_torch.py, which trains the compact
// networks with PyTorch on a GPU and writes weight files that this library loads
// (models/README.md, "Training on a GPU").
//
//   anisocap_study_torch_training_data materials --out FILE --seed S --first K --count N
//       [--size 128] [--materials training] [--emphasis brushed,spun --emphasis-share P] [--validation | --evaluation]
//     N procedural materials drawn as training::make_batch draws them: material m is
//     training_seed(S, K + m, 0) (with --validation: validation_seed(K + m)) and its kind follows
//     training::material_options_for_seed (with --evaluation: validation_seed(K + m) and the kind
//     eval-networks gives its m-th material, evaluation_kind, so --materials original --first 0
//     writes eval-networks' materials). Per material the file holds its maps in network space
//     (size x size x 12, float16) and the 9 configurations make_sample renders (5 training inputs,
//     training_set; 4 render-loss images, render_loss_set), each camera, light and intensity as 9
//     floats. With --reference it also writes, for each material, the C++ renders of those 9
//     configurations (float32, 9 x 3 x size x size) so the PyTorch renderer can be checked.
//
//   anisocap_study_torch_training_data forward --network estimator|autoencoder --weights FILE
//       --input FILE --out FILE
//     Runs a weight file's network on the input tensor of FILE (float32 NHWC: the estimator's
//     images of one set, batch x H x W x inputs; the auto-encoder's maps, batch x H x W x 12; the
//     header is 4 int32: batch, height, width, channels) and writes the output the same way
//     (auto-encoder: running batch-norm statistics). The PyTorch port is checked against it.
//
// File layout of `materials`: int32 magic 0x41435444, version 1, count, size, flags (1: with
// reference renders), then per material: uint64 seed, int32 kind, 12 x size x size float16 (NHWC:
// texel-major, 12 values per texel), 9 x 9 float32, [9 x 3 x size x size float32].
#include <omp.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/networks/presets.hpp"
#include "anisocap/training/training.hpp"

using namespace anisocap;

namespace {

std::uint16_t to_half(float f) {
  // Round-to-nearest-even float -> IEEE half (values here are in [-1, 1]).
  std::uint32_t x;
  std::memcpy(&x, &f, 4);
  const std::uint32_t sign = (x >> 16) & 0x8000u;
  std::int32_t exponent = std::int32_t((x >> 23) & 0xff) - 127 + 15;
  std::uint32_t mantissa = x & 0x7fffffu;
  if (((x >> 23) & 0xff) == 0xff) return std::uint16_t(sign | 0x7c00u | (mantissa ? 0x200u : 0));
  if (exponent >= 31) return std::uint16_t(sign | 0x7c00u);
  if (exponent <= 0) {
    if (exponent < -10) return std::uint16_t(sign);
    mantissa |= 0x800000u;
    const int shift = 14 - exponent;
    std::uint32_t half = mantissa >> shift;
    const std::uint32_t rest = mantissa & ((1u << shift) - 1), midpoint = 1u << (shift - 1);
    if (rest > midpoint || (rest == midpoint && (half & 1))) ++half;
    return std::uint16_t(sign | half);
  }
  std::uint32_t half = sign | (std::uint32_t(exponent) << 10) | (mantissa >> 13);
  const std::uint32_t rest = mantissa & 0x1fffu;
  if (rest > 0x1000u || (rest == 0x1000u && (half & 1))) ++half;
  return std::uint16_t(half);
}

std::string option(int argc, char** argv, const std::string& name, const std::string& fallback) {
  for (int i = 2; i + 1 < argc; ++i)
    if (argv[i] == name) return argv[i + 1];
  return fallback;
}
bool flag(int argc, char** argv, const std::string& name) {
  for (int i = 2; i < argc; ++i)
    if (argv[i] == name) return true;
  return false;
}

void append_configurations(std::vector<float>& out, const capture& c) {
  for (const auto& im : c.images)
    for (const vec3f* v : {&im.camera, &im.light, &im.intensity})
      for (int k = 0; k < 3; ++k) out.push_back((*v)[k]);
}

int materials(int argc, char** argv) {
  const std::string out = option(argc, argv, "--out", "");
  if (out.empty()) throw std::invalid_argument("materials: --out FILE is required");
  training::train_options o;
  o.seed = std::stoull(option(argc, argv, "--seed", "1"));
  o.size = std::stoi(option(argc, argv, "--size", "128"));
  const long first = std::stol(option(argc, argv, "--first", "0"));
  const int count = std::stoi(option(argc, argv, "--count", "16"));
  const auto mix = material_mix_from_name(option(argc, argv, "--materials", "training"));
  if (!mix) throw std::invalid_argument("materials: --materials must be original or training");
  o.mix = *mix;
  const std::string emphasis = option(argc, argv, "--emphasis", "");
  for (std::size_t start = 0; start < emphasis.size();) {
    const std::size_t end = std::min(emphasis.find(',', start), emphasis.size());
    const auto kind = material_kind_from_name(emphasis.substr(start, end - start));
    if (!kind) throw std::invalid_argument("materials: unknown family in --emphasis: " + emphasis.substr(start, end - start));
    o.emphasis.push_back(*kind);
    start = end + 1;
  }
  o.emphasis_share = std::stod(option(argc, argv, "--emphasis-share", "0.5"));
  o.validate();
  const bool evaluation = flag(argc, argv, "--evaluation");
  const bool validation = evaluation || flag(argc, argv, "--validation"), reference = flag(argc, argv, "--reference");
  const int S = o.size;
  const std::size_t map_values = std::size_t(S) * S * parameter_count;
  struct record {
    std::uint64_t seed;
    std::int32_t kind;
    std::vector<std::uint16_t> maps;
    std::vector<float> configurations, renders;
  };
  std::vector<record> records(count);
#pragma omp parallel for schedule(dynamic)
  for (int m = 0; m < count; ++m) {
    const std::uint64_t seed = validation ? training::validation_seed(int(first + m)) : training::training_seed(o.seed, first + m, 0);
    procedural_options options;
    if (evaluation) {
      options.mix = o.mix;
      options.kind = evaluation_kind(int(first + m), seed, {}, o.mix);
    } else {
      options = training::material_options_for_seed(o, seed);
    }
    const material_maps truth = generate_material(seed, S, S, options);
    tensor<parameter_count> net(1, S, S);
    network_space::maps_to_network(truth, net, 0);
    record& r = records[m];
    r.seed = seed;
    r.kind = std::int32_t(draw_procedural_parameters(seed, options).kind);
    r.maps.resize(map_values);
    for (std::size_t i = 0; i < map_values; ++i) r.maps[i] = to_half(net.data()[i]);
    // The configurations of training::make_sample.
    const capture inputs = training_set(hash64(seed ^ 0x696e70757473ULL), S, S);
    const capture loss = render_loss_set(hash64(seed ^ 0x6c6f7373ULL), S, S);
    append_configurations(r.configurations, inputs);
    append_configurations(r.configurations, loss);
    if (reference) {
      for (const capture* c : {&inputs, &loss})
        for (const image& im : render(truth, *c))
          for (int ch = 0; ch < 3; ++ch) r.renders.insert(r.renders.end(), im.plane(ch), im.plane(ch) + im.pixel_count());
    }
  }
  const std::string temporary = out + ".tmp";
  {
    std::ofstream f(temporary, std::ios::binary);
    const std::int32_t header[5] = {0x41435444, 1, count, S, reference ? 1 : 0};
    f.write(reinterpret_cast<const char*>(header), sizeof header);
    for (const record& r : records) {
      f.write(reinterpret_cast<const char*>(&r.seed), 8);
      f.write(reinterpret_cast<const char*>(&r.kind), 4);
      f.write(reinterpret_cast<const char*>(r.maps.data()), std::streamsize(r.maps.size() * 2));
      if (r.configurations.size() != 81) throw std::logic_error("materials: expected 9 configurations");
      f.write(reinterpret_cast<const char*>(r.configurations.data()), std::streamsize(r.configurations.size() * 4));
      if (reference) f.write(reinterpret_cast<const char*>(r.renders.data()), std::streamsize(r.renders.size() * 4));
    }
    if (!f) throw std::runtime_error(out + ": cannot write");
  }
  std::rename(temporary.c_str(), out.c_str());
  return 0;
}

template <int C>
tensor<C> read_tensor(const std::string& file) {
  std::ifstream f(file, std::ios::binary);
  std::int32_t header[4];
  if (!f.read(reinterpret_cast<char*>(header), sizeof header)) throw std::runtime_error(file + ": cannot read the header");
  if (header[3] != C) throw std::runtime_error(file + ": " + std::to_string(header[3]) + " channels, expected " + std::to_string(C));
  tensor<C> t(header[0], header[1], header[2]);
  if (!f.read(reinterpret_cast<char*>(t.data()), std::streamsize(t.size() * 4))) throw std::runtime_error(file + ": truncated");
  return t;
}

template <int C>
void write_tensor(const std::string& file, const tensor<C>& t) {
  std::ofstream f(file, std::ios::binary);
  const std::int32_t header[4] = {t.batch(), t.height(), t.width(), C};
  f.write(reinterpret_cast<const char*>(header), sizeof header);
  f.write(reinterpret_cast<const char*>(t.data()), std::streamsize(t.size() * 4));
}

template <class Net>
void forward_estimator(const std::string& weights, const std::string& input, const std::string& out) {
  Net net;
  nn::load_weights(weights, net);
  const auto x_value = read_tensor<Net::inputs>(input);
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  auto x = t.make_variable<Net::inputs>(x_value.batch(), x_value.height(), x_value.width(), false);
  std::copy_n(x_value.data(), x_value.size(), x.value.data());
  if constexpr (Net::inputs == 6) {
    // The orientation channels as the library computes them from the file's channels 0-2.
    tensor<6> recomputed = x_value;
    double worst = 0;
    for (int b = 0; b < recomputed.batch(); ++b) network_space::orientation_channels(recomputed, b);
    for (std::size_t i = 0; i < recomputed.size(); ++i) worst = std::max(worst, double(std::abs(recomputed.data()[i] - x_value.data()[i])));
    std::printf("orientation channels: max |file - library| %.2e\n", worst);
  }
  auto y = net.forward(t, x, x_value.batch());
  write_tensor(out, y.value);
}

template <class Net>
void forward_autoencoder(const std::string& weights, const std::string& input, const std::string& out) {
  Net net;
  nn::load_weights(weights, net);
  net.set_training(false);
  const auto x_value = read_tensor<parameter_count>(input);
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  auto x = t.leaf(x_value);
  auto y = net.decode(t, net.encode(t, x));
  write_tensor(out, y.value);
}

int forward(int argc, char** argv) {
  const std::string network = option(argc, argv, "--network", ""), weights = option(argc, argv, "--weights", "");
  const std::string input = option(argc, argv, "--input", ""), out = option(argc, argv, "--out", "");
  if (network == "estimator")
    with_compact_estimator_preset(weights, [&]<class P>() { forward_estimator<estimation_network<P>>(weights, input, out); });
  else if (network == "autoencoder")
    with_compact_autoencoder_preset(weights, [&]<class P>() { forward_autoencoder<auto_encoder<P>>(weights, input, out); });
  else throw std::invalid_argument("forward: --network must be estimator or autoencoder, not \"" + network + "\"");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const std::string mode = argc > 1 ? argv[1] : "";
    if (mode == "materials") return materials(argc, argv);
    if (mode == "forward") return forward(argc, argv);
    std::fprintf(stderr, "usage: %s materials ... | forward ... (see the comment at the top of studies/torch_training_data.cpp)\n", argv[0]);
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 1;
  }
}
