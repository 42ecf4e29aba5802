#pragma once
/// @file
/// The encode stage (docs/method.md section 8.2): the auto-encoder's latent code z of the estimate,
/// and the decoder's maps of z, which the fine-tune then improves.
#include "anisocap/ad/reverse/tape.hpp"
#include "anisocap/pipeline/estimate.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/networks/auto_encoder.hpp"
#include "anisocap/networks/estimator.hpp"
#include "anisocap/render/capture.hpp"

namespace anisocap {

/// `maps` mirrored out to `width` x `height` (at the right and bottom).
inline material_maps pad_maps(const material_maps& maps, int width, int height) {
  material_maps out(width, height);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < height; ++y) {
      const int sy = mirror_index(y, maps.height());
      for (int x = 0; x < width; ++x) out.at(k, x, y) = maps.at(k, mirror_index(x, maps.width()), sy);
    }
  return out;
}

/// The auto-encoder's latent code of `maps`: the maps mirrored out to a multiple of the network's
/// size multiple, taken to network space and encoded in inference mode without gradients. Leaves
/// the auto-encoder in inference mode.
template <class P>
tensor<auto_encoder<P>::latent_channels, float> encode(auto_encoder<P>& autoencoder, const material_maps& maps) {
  constexpr int M = auto_encoder<P>::size_multiple;
  const int Wp = (maps.width() + M - 1) / M * M, Hp = (maps.height() + M - 1) / M * M;
  tensor<parameter_count, float> u(1, Hp, Wp);
  network_space::maps_to_network(pad_maps(maps, Wp, Hp), u, 0);
  autoencoder.set_training(false);
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  return autoencoder.encode(t, t.leaf(u)).value.clone();
}

/// The decoder's maps of the latent code `z`, cropped to the `width` x `height` material, without
/// gradients; shifted by `residual` when given (network space, the material's size: what the
/// fine-tune with the residual start renders, finetune_options::residual).
template <class P>
material_maps decode(auto_encoder<P>& autoencoder, const tensor<auto_encoder<P>::latent_channels, float>& z, int width, int height,
                     const tensor<parameter_count, float>* residual = nullptr) {
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  const auto u = autoencoder.decode(t, t.leaf(z)).value.tile(0, 0, height, width);
  return network_space::network_to_maps(residual ? network_space::shifted(u, *residual) : u, 0);
}

/// The fine-tune's residual start (finetune_options::residual): the shift, in network space over the
/// material, that takes the decoder's maps of `z` to `estimate`. The decoder's maps plus it are
/// the estimate itself before the first step.
template <class P>
tensor<parameter_count, float> decoder_residual(auto_encoder<P>& autoencoder, const tensor<auto_encoder<P>::latent_channels, float>& z,
                                                const material_maps& estimate) {
  ad::tape t;
  ad::tape::no_grad_guard guard(t);
  return network_space::shift_to(autoencoder.decode(t, t.leaf(z)).value.tile(0, 0, estimate.height(), estimate.width()), estimate);
}

}  // namespace anisocap
