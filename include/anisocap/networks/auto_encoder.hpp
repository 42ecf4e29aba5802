#pragma once
/// @file
/// The map auto-encoder of the paper (docs/method.md section 7, after Gao 2019), with compile-time
/// width presets `autoencoder_paper`, `autoencoder_compact` (latent (H/32) x (W/32) x 128; the
/// shipped weights in models/compact/) and the experimental `autoencoder_compact_wide`.
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
/// encoder layers (and the first two decoder layers) 256 wide. The compact latent holds 80 input
/// values per latent value, this one 40 (the paper's 10); 3.5 M parameters against 1.4 M
/// (models/README.md, "A wider latent").
struct autoencoder_compact_wide {
  static constexpr std::array<int, 5> encoder{32, 64, 128, 256, 256};  ///< encoder widths; latent = last
  static constexpr const char* name = "compact-wide";                   ///< preset name in files
};

/// The map auto-encoder (docs/method.md section 7, after Gao 2019): five 4x4 stride-2 convolutions with leaky
/// ReLU between them and one batch normalisation at the end give the latent code z
/// (H/32 x W/32 x Preset::encoder[4]); five 4x4 stride-2 transposed convolutions decode it back to
/// 12 channels in network space (tanh). encode() and decode() are separate so that the pipeline
/// can fine-tune the decoder with z fixed and the encoder frozen (docs/method.md section 8).
template <class Preset, class T = float>
class auto_encoder {
  static constexpr auto E = Preset::encoder;

 public:
  using preset = Preset;  ///< the widths
  /// Latent channels.
  static constexpr int latent_channels = E[4];
  /// Side lengths encode() accepts are multiples of this.
  static constexpr int size_multiple = 32;

  nn::conv2d<parameter_count, E[0], 4, 2, 1, T> enc0;  ///< encoder layer 0 (4x4, stride 2)
  nn::conv2d<E[0], E[1], 4, 2, 1, T> enc1;  ///< encoder layer 1 (4x4, stride 2)
  nn::conv2d<E[1], E[2], 4, 2, 1, T> enc2;  ///< encoder layer 2 (4x4, stride 2)
  nn::conv2d<E[2], E[3], 4, 2, 1, T> enc3;  ///< encoder layer 3 (4x4, stride 2)
  nn::conv2d<E[3], E[4], 4, 2, 1, T> enc4;  ///< encoder layer 4 (4x4, stride 2)
  nn::batch_norm<E[4], T> latent_norm;  ///< the batch norm that ends the encoder
  nn::conv_transpose2d<E[4], E[3], T> dec0;  ///< decoder layer 0 (4x4 transposed, stride 2)
  nn::conv_transpose2d<E[3], E[2], T> dec1;  ///< decoder layer 1 (4x4 transposed, stride 2)
  nn::conv_transpose2d<E[2], E[1], T> dec2;  ///< decoder layer 2 (4x4 transposed, stride 2)
  nn::conv_transpose2d<E[1], E[0], T> dec3;  ///< decoder layer 3 (4x4 transposed, stride 2)
  nn::conv_transpose2d<E[0], parameter_count, T> dec4;  ///< decoder layer 4 (4x4 transposed, stride 2)

  /// A network with seeded He-uniform weights.
  explicit auto_encoder(std::uint64_t seed = 1)
      : enc0("enc0"), enc1("enc1"), enc2("enc2"), enc3("enc3"), enc4("enc4"), latent_norm("latent_norm"),
        dec0("dec0"), dec1("dec1"), dec2("dec2"), dec3("dec3"), dec4("dec4") {
    using network_detail::init_conv;
    init_conv(enc0, 16 * parameter_count, seed);
    init_conv(enc1, 16 * E[0], seed);
    init_conv(enc2, 16 * E[1], seed);
    init_conv(enc3, 16 * E[2], seed);
    init_conv(enc4, 16 * E[3], seed);
    init_conv(dec0, 4 * E[4], seed);
    init_conv(dec1, 4 * E[3], seed);
    init_conv(dec2, 4 * E[2], seed);
    init_conv(dec3, 4 * E[1], seed);
    nn::xavier_uniform(dec4.weight, 4 * E[0], 4 * parameter_count, seed);
    nn::constant_init(dec4.bias, T(0));
  }

  /// z from network-space maps (batch x H x W x 12, H and W multiples of 32). Batch norm uses the
  /// batch's statistics while `training`, the running ones otherwise.
  ad::variable<latent_channels, T> encode(ad::tape& t, const ad::variable<parameter_count, T>& maps) {
    if (maps.value.height() % size_multiple != 0 || maps.value.width() % size_multiple != 0 || maps.value.height() == 0 ||
        maps.value.width() == 0)
      throw std::invalid_argument("auto_encoder::encode: map size " + std::to_string(maps.value.height()) + "x" +
                                  std::to_string(maps.value.width()) + " is not a positive multiple of 32 (pad it)");
    const T s = T(network_detail::leaky_slope);
    auto h = nn::leaky_relu(t, enc0(t, maps), s);
    auto h1 = nn::leaky_relu(t, enc1(t, h), s);
    auto h2 = nn::leaky_relu(t, enc2(t, h1), s);
    auto h3 = nn::leaky_relu(t, enc3(t, h2), s);
    return latent_norm(t, enc4(t, h3));
  }

  /// Network-space maps (batch x 32 h x 32 w x 12, in (-1, 1)) from z (batch x h x w x latent).
  ad::variable<parameter_count, T> decode(ad::tape& t, const ad::variable<latent_channels, T>& z) {
    const T s = T(network_detail::leaky_slope);
    auto h = nn::leaky_relu(t, dec0(t, z), s);
    auto h1 = nn::leaky_relu(t, dec1(t, h), s);
    auto h2 = nn::leaky_relu(t, dec2(t, h1), s);
    auto h3 = nn::leaky_relu(t, dec3(t, h2), s);
    return nn::tanh(t, dec4(t, h3));
  }

  /// Batch norm mode: batch statistics (training) or running statistics (inference).
  void set_training(bool training) noexcept { latent_norm.training = training; }

  /// Freezes (or unfreezes) the encoder and its batch norm: no gradients are computed for them.
  void freeze_encoder(bool frozen = true) {
    auto f = [frozen](nn::basic_parameter<T>& p) { p.frozen = frozen; };
    network_detail::visit(f, enc0, enc1, enc2, enc3, enc4, latent_norm);
  }

  /// Freezes (or unfreezes) the decoder: no gradients are computed for its weights, while
  /// gradients still flow through it to z (training the encoder against a fixed decoder).
  void freeze_decoder(bool frozen = true) {
    for_each_decoder_parameter([frozen](nn::basic_parameter<T>& p) { p.frozen = frozen; });
  }

  /// Visits every trainable parameter.
  template <class F>
  void for_each_parameter(F&& f) {
    network_detail::visit(f, enc0, enc1, enc2, enc3, enc4, latent_norm, dec0, dec1, dec2, dec3, dec4);
  }
  /// Visits the saved, untrained state (the batch norm's running statistics).
  template <class F>
  void for_each_buffer(F&& f) {
    latent_norm.for_each_buffer(f);
  }
  /// Visits the decoder's parameters only (what the pipeline fine-tunes).
  template <class F>
  void for_each_decoder_parameter(F&& f) {
    network_detail::visit(f, dec0, dec1, dec2, dec3, dec4);
  }
};

}  // namespace anisocap
