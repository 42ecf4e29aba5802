#pragma once
/// @file
/// The materials training draws (docs/method.md section 6): seeds that are a pure function of (run
/// seed, step, batch entry), disjoint from the validation seeds, and one sample per seed: the
/// procedural maps, their network-space form, the training photographs and the render-loss targets.
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "anisocap/core/random.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/networks/network_space.hpp"
#include "anisocap/render/configurations.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap::training {

/// Material seeds of training samples are below 2^62, validation seeds at or above: disjoint.
inline constexpr std::uint64_t validation_seed_base = std::uint64_t(1) << 62;

/// Material seed of batch entry b at step `step` of a run seeded `seed` (below 2^62).
inline std::uint64_t training_seed(std::uint64_t seed, long step, int b) { return hash64(seed, step, b) >> 2; }
/// Material seed of validation material i (the same for every run).
inline std::uint64_t validation_seed(int i) { return validation_seed_base + std::uint64_t(i); }

/// One training example: true maps (and in network space), the 5 input photographs of the
/// training set (docs/method.md section 6) when asked for, and the render-loss targets under the 4 render-loss
/// configurations (eq. 8).
struct sample {
  material_maps truth;                 ///< the procedural material
  tensor<parameter_count> truth_net;   ///< truth in network space (1 x H x W x 12)
  std::vector<image> photos;           ///< the 5 training inputs (empty for the auto-encoder)
  capture loss_configurations;         ///< render_loss_set
  loss_targets targets;                ///< log renders of the truth under loss_configurations
};

/// The procedural options of training and validation materials drawn from `mix`: original (the
/// eight original kinds, what every earlier run used) or training (the extended mix without
/// held_out_kinds). Throws std::invalid_argument for the extended mix, which would train on the
/// held-out families.
inline procedural_options training_material_options(material_mix mix) {
  if (mix == material_mix::extended)
    throw std::invalid_argument(
        "training: the extended mix includes the held-out families (leather, printed); train on the training mix");
  procedural_options options;
  options.mix = mix;
  return options;
}

/// The sample of material seed `seed` at size x size drawn with `options` (configurations seeded
/// from the seed too). Evaluations use it to force a family, held-out ones included.
inline sample make_sample(std::uint64_t seed, int size, bool with_photos, const procedural_options& options) {
  sample s;
  s.truth = generate_material(seed, size, size, options);
  s.truth_net = tensor<parameter_count>(1, size, size);
  network_space::maps_to_network(s.truth, s.truth_net, 0);
  if (with_photos) s.photos = render(s.truth, training_set(hash64(seed ^ 0x696e70757473ULL), size, size));
  s.loss_configurations = render_loss_set(hash64(seed ^ 0x6c6f7373ULL), size, size);
  s.targets = make_loss_targets(render(s.truth, s.loss_configurations));
  return s;
}

/// The training or validation sample of material seed `seed`, its kind drawn from `mix`
/// (training_material_options: never a held-out family).
inline sample make_sample(std::uint64_t seed, int size, bool with_photos, material_mix mix = material_mix::original) {
  return make_sample(seed, size, with_photos, training_material_options(mix));
}

}  // namespace anisocap::training
