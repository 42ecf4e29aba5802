#pragma once
/// @file
/// The map auto-encoder of the paper (docs/method.md section 7, after Gao 2019), with compile-time
/// width presets `autoencoder_paper`, `autoencoder_compact` (latent (H/32) x (W/32) x 128; the
/// shipped weights in models/compact/) and the experimental `autoencoder_compact_wide` and
/// `autoencoder_compact_fine` (latent (H/16) x (W/16) x 128), `autoencoder_compact_fine_wide`
/// (latent (H/16) x (W/16) x 256), `autoencoder_compact_fine_wider` (the same latent, the levels
/// above it twice as wide), `autoencoder_compact_fine_widest` (compact-fine-wider with a 384-wide
/// latent) and `autoencoder_compact_fine_512` (a 512-wide latent).
#include <cstddef>
#include <string>
#include <tuple>
#include <utility>

#include "anisocap/networks/network_layers.hpp"

namespace anisocap {

/// The paper's auto-encoder widths: 5 stride-2 convolutions 64-128-256-512-1024 (docs/method.md section 7).
struct autoencoder_paper {
  static constexpr std::array<int, 5> encoder{64, 128, 256, 512, 1024};  ///< encoder widths; latent = last
  static constexpr const char* name = "paper";                            ///< preset name in files
};

/// The compact auto-encoder: latent (H/32) x (W/32) x 128.
struct autoencoder_compact {
  static constexpr std::array<int, 5> encoder{32, 64, 128, 128, 128};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact";                        ///< preset name in files
};

/// An experimental compact variant with twice the latent: (H/32) x (W/32) x 256, the last two
/// encoder layers (and the first two decoder layers) 256 wide. The compact latent holds 96 input
/// values per latent value, this one 48 (the paper's 12); 3.5 M parameters against 1.4 M
/// (docs/model-card.md, "Architecture").
struct autoencoder_compact_wide {
  static constexpr std::array<int, 5> encoder{32, 64, 128, 256, 256};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-wide";                   ///< preset name in files
};

/// An experimental compact variant with a four times finer latent: four levels instead of five,
/// latent (H/16) x (W/16) x 128, the compact widths without the last level. It holds 24 input values
/// per latent value (the compact preset 96, compact-wide 48, the paper's 12) with fewer parameters
/// (0.87 M against 1.4 M): the spatial detail of weaves and printed patterns that a cell of 32 x 32
/// texels loses (docs/method.md section 7).
struct autoencoder_compact_fine {
  static constexpr std::array<int, 4> encoder{32, 64, 128, 128};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-fine";              ///< preset name in files
};

/// An experimental compact variant with the paper's compression: compact-fine's four levels with
/// the deepest one 256 wide, latent (H/16) x (W/16) x 256, 12 input values per latent value as the
/// paper's auto-encoder (1.4 M parameters). studies/widen_latent.py starts it from a compact-fine
/// file with the same output (docs/method.md section 7).
struct autoencoder_compact_fine_wide {
  static constexpr std::array<int, 4> encoder{32, 64, 128, 256};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-fine-wide";         ///< preset name in files
};

/// An experimental variant of `compact-fine-wide` with the three levels above the latent twice as
/// wide, 64-128-256-256: the same latent and compression (12 map values per latent value), a decoder
/// whose last layers have twice the channels to draw the maps' detail from, and an encoder with twice
/// the filters to find the code (3.4 M parameters, 13.7 MB). studies/widen_latent.py starts it from a
/// compact-fine-wide (or compact-fine) file with the same output (docs/method.md section 7).
struct autoencoder_compact_fine_wider {
  static constexpr std::array<int, 4> encoder{64, 128, 256, 256};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-fine-wider";         ///< preset name in files
};

/// An experimental variant of `compact-fine-wider` with a 384-wide latent, 64-128-256-384: latent
/// (H/16) x (W/16) x 384, 8 map values per latent value instead of the paper's 12, for the normals'
/// and the diffuse albedo's detail that a code of the paper's size does not hold (studies/linear_codes.cpp;
/// 4.5 M parameters, 17.9 MB). studies/widen_latent.py starts it from a
/// compact-fine-wider (or narrower four-level) file with the same output.
struct autoencoder_compact_fine_widest {
  static constexpr std::array<int, 4> encoder{64, 128, 256, 384};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-fine-widest";        ///< preset name in files
};

/// An experimental variant of `compact-fine-widest` with a 512-wide latent, 64-128-256-512: 6 map
/// values per latent value, the compression at which the best linear code of a 16 x 16 cell comes
/// near 0.2x the estimator's a_d error (studies/linear_codes.cpp). 5.5 M parameters: 22.1 MB as
/// floats, over the repository's 20 MB a file, 11.1 MB with half-float kernels (`convert-weights
/// --half`). studies/widen_latent.py starts it from a narrower four-level file with the same output.
struct autoencoder_compact_fine_512 {
  static constexpr std::array<int, 4> encoder{64, 128, 256, 512};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-fine-512";           ///< preset name in files
};

/// The map auto-encoder (docs/method.md section 7, after Gao 2019): L = Preset::encoder.size()
/// 4x4 stride-2 convolutions with leaky ReLU between them and one batch normalisation at the end
/// give the latent code z (H/2^L x W/2^L x Preset::encoder[L-1]); L 4x4 stride-2 transposed
/// convolutions decode it back to 12 channels in network space (tanh). The paper's and the compact
/// presets have L = 5, `compact-fine`, `compact-fine-wide`, `compact-fine-wider`,
/// `compact-fine-widest` and `compact-fine-512` 4. encode() and decode() are separate so that the
/// pipeline can fine-tune the decoder with z fixed and the encoder frozen (docs/method.md section 8).
template <class Preset, class T = float>
class auto_encoder {
  static constexpr auto E = Preset::encoder;
  static constexpr std::size_t L = E.size();
  static_assert(L >= 2 && L <= 6, "auto_encoder: 2 to 6 levels");
  // Channels into encoder layer i, and out of decoder layer i.
  static constexpr int encoder_in(std::size_t i) { return i == 0 ? parameter_count : E[i - 1]; }
  static constexpr int decoder_out(std::size_t i) { return i + 1 == L ? parameter_count : E[L - 2 - i]; }
  template <std::size_t... I>
  static auto encoder_types(std::index_sequence<I...>) -> std::tuple<nn::conv2d<encoder_in(I), E[I], 4, 2, 1, T>...>;
  template <std::size_t... I>
  static auto decoder_types(std::index_sequence<I...>) -> std::tuple<nn::conv_transpose2d<E[L - 1 - I], decoder_out(I), T>...>;
  using encoder_layers = decltype(encoder_types(std::make_index_sequence<L>{}));
  using decoder_layers = decltype(decoder_types(std::make_index_sequence<L>{}));
  template <class Tuple, std::size_t... I>
  static Tuple named_layers(const std::string& prefix, std::index_sequence<I...>) {
    return Tuple(std::tuple_element_t<I, Tuple>(prefix + std::to_string(I))...);
  }

 public:
  using preset = Preset;  ///< the widths
  /// Stride-2 levels of the encoder (and of the decoder).
  static constexpr int levels = int(L);
  /// Latent channels.
  static constexpr int latent_channels = E[L - 1];
  /// Side lengths encode() accepts are multiples of this (2^levels); one latent cell covers
  /// size_multiple x size_multiple texels.
  static constexpr int size_multiple = 1 << L;

 private:
  encoder_layers encoder_;  // enc0 ... enc{L-1}: 4x4, stride 2
  decoder_layers decoder_;  // dec0 ... dec{L-1}: 4x4 transposed, stride 2

 public:
  nn::batch_norm<latent_channels, T> latent_norm;  ///< the batch norm that ends the encoder

  /// A network with seeded He-uniform weights (Xavier for the last, tanh-activated layer).
  explicit auto_encoder(std::uint64_t seed = 1)
      : encoder_(named_layers<encoder_layers>("enc", std::make_index_sequence<L>{})),
        decoder_(named_layers<decoder_layers>("dec", std::make_index_sequence<L>{})),
        latent_norm("latent_norm") {
    using network_detail::init_conv;
    [&]<std::size_t... I>(std::index_sequence<I...>) {
      (init_conv(std::get<I>(encoder_), 16 * encoder_in(I), seed), ...);
    }(std::make_index_sequence<L>{});
    [&]<std::size_t... I>(std::index_sequence<I...>) {  // all but the last, tanh-activated layer
      (init_conv(std::get<I>(decoder_), 4 * E[L - 1 - I], seed), ...);
    }(std::make_index_sequence<L - 1>{});
    auto& last = std::get<L - 1>(decoder_);
    nn::xavier_uniform(last.weight, 4 * E[0], 4 * parameter_count, seed);
    nn::constant_init(last.bias, T(0));
  }

  /// Encoder layer I ("enc<I>" in weight files).
  template <std::size_t I>
  auto& enc() noexcept { return std::get<I>(encoder_); }
  /// Decoder layer I ("dec<I>" in weight files; dec0 reads z).
  template <std::size_t I>
  auto& dec() noexcept { return std::get<I>(decoder_); }

  /// z from network-space maps (batch x H x W x 12, H and W multiples of size_multiple). Batch norm
  /// uses the batch's statistics while `training`, the running ones otherwise.
  ad::variable<latent_channels, T> encode(ad::tape& t, const ad::variable<parameter_count, T>& maps) {
    check_size(maps.value.height(), maps.value.width());
    return encode_from<0>(t, maps);
  }

  /// The encoder without its batch norm (latent_norm): the last convolution's output, from which
  /// a data-parallel step normalises with the statistics of a batch spread over several passes
  /// (training::autoencoder_gradient_parts). Same sizes as encode().
  ad::variable<latent_channels, T> encode_features(ad::tape& t, const ad::variable<parameter_count, T>& maps) {
    check_size(maps.value.height(), maps.value.width());
    return encode_from<0, parameter_count, false>(t, maps);
  }

  /// Network-space maps (batch x size_multiple h x size_multiple w x 12, in (-1, 1)) from z
  /// (batch x h x w x latent).
  ad::variable<parameter_count, T> decode(ad::tape& t, const ad::variable<latent_channels, T>& z) {
    return decode_from<0>(t, z);
  }

  /// Batch norm mode: batch statistics (training) or running statistics (inference).
  void set_training(bool training) noexcept { latent_norm.training = training; }

  /// Freezes (or unfreezes) the encoder and its batch norm: no gradients are computed for them.
  void freeze_encoder(bool frozen = true) {
    for_each_encoder_parameter([frozen](nn::basic_parameter<T>& p) { p.frozen = frozen; });
  }

  /// Freezes (or unfreezes) the decoder: no gradients are computed for its weights, while
  /// gradients still flow through it to z (training the encoder against a fixed decoder).
  void freeze_decoder(bool frozen = true) {
    for_each_decoder_parameter([frozen](nn::basic_parameter<T>& p) { p.frozen = frozen; });
  }

  /// Visits every trainable parameter: the encoder's, the batch norm's, the decoder's.
  template <class F>
  void for_each_parameter(F&& f) {
    for_each_encoder_parameter(f);
    for_each_decoder_parameter(f);
  }
  /// Visits the saved, untrained state (the batch norm's running statistics).
  template <class F>
  void for_each_buffer(F&& f) {
    latent_norm.for_each_buffer(f);
  }
  /// Visits the encoder's parameters and its batch norm's (what freeze_encoder freezes): calls
  /// f(basic_parameter<T>&).
  template <class F>
  void for_each_encoder_parameter(F&& f) {
    visit_encoder_parameters(network_detail::erase_visitor<T>(f));
  }
  /// Visits the decoder's parameters only (what the pipeline fine-tunes).
  template <class F>
  void for_each_decoder_parameter(F&& f) {
    visit_decoder_parameters(network_detail::erase_visitor<T>(f));
  }
  /// for_each_encoder_parameter with the visitor's type erased (the one listing of the layers).
  void visit_encoder_parameters(const network_detail::parameter_visitor<T>& f) {
    std::apply([&](auto&... layers) { network_detail::visit(f, layers..., latent_norm); }, encoder_);
  }
  /// for_each_decoder_parameter with the visitor's type erased.
  void visit_decoder_parameters(const network_detail::parameter_visitor<T>& f) {
    std::apply([&](auto&... layers) { network_detail::visit(f, layers...); }, decoder_);
  }

 private:
  static void check_size(int height, int width) {
    if (height % size_multiple != 0 || width % size_multiple != 0 || height == 0 || width == 0)
      throw std::invalid_argument("auto_encoder::encode: map size " + std::to_string(height) + "x" + std::to_string(width) +
                                  " is not a positive multiple of " + std::to_string(size_multiple) + " (pad it)");
  }
  template <std::size_t I, int C, bool Normalised = true>
  ad::variable<latent_channels, T> encode_from(ad::tape& t, const ad::variable<C, T>& h) {
    if constexpr (I + 1 == L) {
      auto y = std::get<I>(encoder_)(t, h);
      if constexpr (Normalised) return latent_norm(t, y);
      else return y;
    } else {
      return encode_from<I + 1, E[I], Normalised>(t, std::get<I>(encoder_)(t, h, nn::leaky_relu_activation<T>{T(network_detail::leaky_slope)}));
    }
  }
  template <std::size_t I, int C>
  ad::variable<parameter_count, T> decode_from(ad::tape& t, const ad::variable<C, T>& h) {
    // A plain chain: each layer's output gradient is written by the next layer (nn::chain_link).
    if constexpr (I + 1 == L) return std::get<I>(decoder_)(t, h, nn::tanh_activation<T>{}, nn::chain_link{I > 0, false});
    else
      return decode_from<I + 1>(
          t, std::get<I>(decoder_)(t, h, nn::leaky_relu_activation<T>{T(network_detail::leaky_slope)}, nn::chain_link{I > 0, true}));
  }
};

}  // namespace anisocap
