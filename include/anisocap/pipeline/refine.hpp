#pragma once
/// @file
/// The per-texel optimisation (the paper's "refine" stage, docs/method.md section 8.4, eq. 5): Adam on the maps
/// against the image loss, usable on its own.
///
/// Parameters stay in their valid ranges by construction: Adam works on unconstrained variables u
/// and the maps are a smooth function of them:
///   albedos, F0:   p = sigmoid(u)                                   in (0, 1)
///   lobe widths:   sigma = exp(log(s0) * (1 - sigmoid(u)))          in (s0, 1), s0 = min_lobe_width (log-space)
///   normal x, y:   (nx, ny) = (ux, uy) / sqrt(1 + ux^2 + uy^2)       open unit disc, n_z > 0
///   rotation:      alpha = u, wrapped into [-pi/2, pi/2) on output  (alpha is pi-periodic)
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <numbers>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "anisocap/brdf/material_maps.hpp"
#include "anisocap/core/distributed.hpp"
#include "anisocap/core/option_names.hpp"
#include "anisocap/core/system.hpp"
#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/early_stopping.hpp"
#include "anisocap/nn/progress.hpp"
#include "anisocap/render/renderer.hpp"

namespace anisocap {

/// Options of `refine`.
/// The defaults refine a first guess from the photographs (far from the answer);
/// `after_networks()` refines the networks' estimate.
struct refine_options {
  int steps = 1000;                ///< Adam steps
  float learning_rate = 0.03f;     ///< in the unconstrained space u (see file comment)
  float beta1 = 0.9f, beta2 = 0.999f, epsilon = 1e-8f;
  render_options render{};         ///< culling etc. for the fused loss
  tile_placement placement{};      ///< where the maps lie in a larger material
  int progress_every = 0;          ///< 0: no progress callbacks
  std::function<void(const optimisation_progress&)> progress;
  /// Stop early when the loss improved by less than this fraction over the last `patience` steps (0: never).
  double min_relative_improvement = 0.0;
  int patience = 50;
  int min_steps = 0;  ///< early stopping applies from this many steps on
  /// Refine only texels whose loss still moves: every `freeze_every` steps, each group of
  /// `texel_group_size` texels whose loss fell by less than this fraction since the previous check
  /// is frozen for the rest of the run (neither evaluated nor updated; its loss term is exact, the
  /// texels just stop moving). 0: never freeze.
  double freeze_tolerance = 0.0;
  int freeze_every = 25;
  /// The ranks that share the refine (core/distributed.hpp): each refines a contiguous share of the
  /// texel groups (part_range over the groups) and the groups' losses and the final maps are
  /// gathered, so every rank ends with the same maps, those of one process, bit for bit. Null (or
  /// one rank): this process alone. Every rank calls refine with the same maps and options. Not
  /// owned: it must outlive the call.
  const communicator* ranks = nullptr;

  /// After the networks the maps start near the answer: 500 steps (the paper's count) at 3e-3
  /// (docs/results.md "Run time against error").
  static refine_options after_networks() {
    refine_options o;
    o.steps = 500;
    o.learning_rate = 3e-3f;
    return o;
  }
  /// The paper's refine (section 5): 500 steps at 1e-4. Its rate is for its own parameterisation;
  /// in ours (the unconstrained u of the file comment) it moves the maps far less than 3e-3.
  static refine_options paper() {
    refine_options o;
    o.steps = 500;
    o.learning_rate = 1e-4f;
    return o;
  }
  /// Calls `f(name, field)` for each number that decides what the refine computes, named as the
  /// library's messages and the program's report name them: the one list of them (`o` a
  /// refine_options, const or not). The render options and the ranks are apart.
  template <class Self, class F>
  static void visit_fields(Self& o, F&& f) {
    f("steps", o.steps);
    f("learning_rate", o.learning_rate), f("beta1", o.beta1), f("beta2", o.beta2), f("epsilon", o.epsilon);  // Adam
    f("min_relative_improvement", o.min_relative_improvement), f("patience", o.patience), f("min_steps", o.min_steps);  // early stopping
    f("freeze_tolerance", o.freeze_tolerance), f("freeze_every", o.freeze_every);
  }
  /// Throws std::invalid_argument for impossible values.
  void validate() const {
    check_counts_not_negative(*this, "refine_options");
    if (!(learning_rate > 0) || !std::isfinite(learning_rate)) throw std::invalid_argument("refine_options::learning_rate (the refine's) must be positive and finite");
    if (!(min_relative_improvement >= 0 && min_relative_improvement < 1)) throw std::invalid_argument("refine_options::min_relative_improvement (the refine's early stopping) must be in [0, 1)");
    if (!(freeze_tolerance >= 0 && freeze_tolerance < 1)) throw std::invalid_argument("refine_options::freeze_tolerance (the refine's) must be in [0, 1)");
  }
};

/// What `refine` did.
struct refine_result {
  std::vector<double> losses;  ///< loss before each step
  double final_loss = 0;       ///< loss of the returned maps
  int steps = 0;               ///< steps run
  double seconds = 0;
  /// Fraction of the texel-steps that were evaluated (1 without freezing).
  double evaluated_fraction = 1.0;
};

namespace detail {

inline float logit(float p) {
  p = std::min(std::max(p, 1e-5f), 1.0f - 1e-5f);
  return std::log(p / (1.0f - p));
}
inline const float log_min_lobe = float(log_min_lobe_width);

/// Per rank, the values its share of `groups` groups (part_range) holds at `unit` values a group,
/// the last group cut at `total` values: the counts of a gather over the refine's groups.
inline std::vector<std::size_t> group_share_counts(const communicator& ranks, std::size_t groups, std::size_t unit, std::size_t total) {
  std::vector<std::size_t> counts(std::size_t(ranks.size()));
  for (int r = 0; r < ranks.size(); ++r) {
    const auto [a, b] = part_range(int(groups), ranks.size(), r);
    counts[std::size_t(r)] = std::min(total, std::size_t(b) * unit) - std::min(total, std::size_t(a) * unit);
  }
  return counts;
}

/// Every rank's groups' losses, `losses[first, last)` on this rank, to every rank (refine over
/// several ranks).
inline void gather_groups(const communicator& ranks, std::vector<double>& losses, std::size_t first, std::size_t last) {
  const std::vector<std::size_t> counts = group_share_counts(ranks, losses.size(), 1, losses.size());
  std::vector<double> all;
  ranks.all_gather(std::span<const double>(losses.data() + first, last - first), all, counts);
  std::copy(all.begin(), all.end(), losses.begin());  // in place: texel_groups points at it
}

/// The logistic function 1 / (1 + e^-x) of the refine parameterisation.
template <class V>
V logistic(const V& x) {
  return V(1) / (V(1) + simd::exp(-x));
}

/// The maps of the SIMD block of texels starting at i from the unconstrained variables, every plane.
/// Planes are padded to a multiple of 16, so whole registers are always in bounds.
inline void block_maps_from_unconstrained(const material_maps& u, material_maps& maps, std::size_t i) {
  using V = simd::batch<float>;
  for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0})
    simd::store<V>(maps.plane(k) + i, logistic(simd::load<V>(u.plane(k) + i)));
  for (int k : {lobe_x, lobe_y})
    simd::store<V>(maps.plane(k) + i, simd::exp(V(log_min_lobe) * (V(1) - logistic(simd::load<V>(u.plane(k) + i)))));
  const V ux = simd::load<V>(u.plane(normal_x) + i), uy = simd::load<V>(u.plane(normal_y) + i);
  const V k = V(1) / simd::sqrt(V(1) + ux * ux + uy * uy);
  simd::store<V>(maps.plane(normal_x) + i, ux * k);
  simd::store<V>(maps.plane(normal_y) + i, uy * k);
  const V a = simd::load<V>(u.plane(rotation) + i);
  const V pi(std::numbers::pi_v<float>);
  simd::store<V>(maps.plane(rotation) + i, a - pi * xsimd::nearbyint(a / pi));
}

/// d map / d u of plane k (any plane but the normal's, whose 2x2 Jacobian the Adam step
/// recomputes) for the SIMD block at i, from u and the maps block_maps_from_unconstrained wrote
/// from it: a logistic plane's s (1 - s) from its map s, a lobe width's from its map and its u.
inline simd::batch<float> block_elementwise_jacobian(int k, const material_maps& u, const material_maps& maps, std::size_t i) {
  using V = simd::batch<float>;
  if (k == rotation) return V(1);
  const V m = simd::load<V>(maps.plane(k) + i);
  if (k != lobe_x && k != lobe_y) return m * (V(1) - m);
  const V s = logistic(simd::load<V>(u.plane(k) + i));
  return m * V(-log_min_lobe) * s * (V(1) - s);
}

/// Maps from unconstrained variables (block_maps_from_unconstrained), and when `jacobian` is not
/// null the elementwise d map / d u (block_elementwise_jacobian; the normal's planes left as they
/// are). With `first` and `last` (multiples of the SIMD width, or the texel count): texels
/// [first, last) only (a rank's share of the refine).
inline void maps_from_unconstrained(const material_maps& u, material_maps& maps, material_maps* jacobian = nullptr, std::size_t first = 0,
                                    std::size_t last = std::size_t(-1)) {
  using V = simd::batch<float>;
  constexpr std::size_t L = simd::lanes_v<V>;
  const std::size_t n = std::min(last, maps.texel_count());
  const std::ptrdiff_t blocks = std::ptrdiff_t((n + L - 1) / L);
#pragma omp parallel for schedule(static)
  for (std::ptrdiff_t b = std::ptrdiff_t(first / L); b < blocks; ++b) {
    const std::size_t i = std::size_t(b) * L;
    block_maps_from_unconstrained(u, maps, i);
    if (jacobian)
      for (int k = 0; k < parameter_count; ++k)
        if (k != normal_x && k != normal_y) simd::store<V>(jacobian->plane(k) + i, block_elementwise_jacobian(k, u, maps, i));
  }
}

/// The refine's freezing check: each active group whose loss fell by less than `tolerance` (a
/// fraction) since its last check (none at step 0) stops; the others keep this loss for the next.
/// Returns the number of groups frozen.
inline std::size_t freeze_converged_groups(std::vector<std::uint8_t>& active, const std::vector<double>& loss,
                                           std::vector<double>& loss_checked, int step, double tolerance) {
  std::size_t frozen = 0;
  for (std::size_t g = 0; g < active.size(); ++g) {
    if (!active[g]) continue;
    if (step > 0 && loss_checked[g] - loss[g] < tolerance * loss_checked[g]) {
      active[g] = 0;
      ++frozen;
    } else {
      loss_checked[g] = loss[g];
    }
  }
  return frozen;
}

/// One Adam step (nn/adam.hpp's kernel) on the unconstrained variables u, SIMD over texels, from the
/// maps' gradient through the parameterisation: elementwise Jacobians for the `active` planes
/// (block_elementwise_jacobian, from u and `maps`, which must be the maps of u), the normal's 2x2
/// Jacobian recomputed here; then each updated block's maps from its new u, in the same pass (one
/// stream over the planes fewer than a separate pass, and no Jacobian planes). Only texel groups
/// in [first_group, last_group) that `group_active` (when not null) marks active move.
template <brdf_features F>
void adam_step_and_maps(material_maps& u, material_maps& m1, material_maps& m2, const material_maps& grad, material_maps& maps,
                        const std::vector<int>& active, const nn::adam_coefficients<float>& coefficients,
                        const std::uint8_t* group_active, std::size_t first_group, std::size_t last_group) {
  using V = simd::batch<float>;
  constexpr std::size_t L = simd::lanes_v<V>;
  auto adam = [&](int k, std::size_t i, const V& g) { nn::adam_update(u.plane(k) + i, g, m1.plane(k) + i, m2.plane(k) + i, coefficients); };
  const std::ptrdiff_t blocks = std::ptrdiff_t((u.texel_count() + L - 1) / L);
  constexpr std::size_t prefetch_ahead = L < 16 ? 16 : L;  // the next block, at least a cache line on
#pragma omp parallel for schedule(static)
  for (std::ptrdiff_t bi = 0; bi < blocks; ++bi) {
    const std::size_t i = std::size_t(bi) * L;
    const std::size_t g = i / texel_group_size;
    if ((group_active && !group_active[g]) || g < first_group || g >= last_group) continue;  // frozen, or another rank's
    // Up to five arrays of twelve planes are more streams than the hardware prefetchers follow:
    // the next block's lines are asked for while this one is computed.
    if (i + prefetch_ahead < u.texel_count()) {
      for (int k = 0; k < parameter_count; ++k)
        for (const material_maps* a : {&u, &maps}) simd::prefetch(a->plane(k) + i + prefetch_ahead);
      for (int k : active) {
        simd::prefetch(m1.plane(k) + i + prefetch_ahead);
        simd::prefetch(m2.plane(k) + i + prefetch_ahead);
        simd::prefetch(grad.plane(k) + i + prefetch_ahead);
      }
    }
    // Every gradient is taken at the old u before any plane of the block moves.
    V gu[parameter_count];
    for (int k : active) gu[k] = simd::load<V>(grad.plane(k) + i) * block_elementwise_jacobian(k, u, maps, i);
    for (int k : active) adam(k, i, gu[k]);
    if constexpr (F.normal_map) {
      const V ux = simd::load<V>(u.plane(normal_x) + i), uy = simd::load<V>(u.plane(normal_y) + i);
      const V kk = V(1) / simd::sqrt(V(1) + ux * ux + uy * uy), k3 = kk * kk * kk;
      const V gx = simd::load<V>(grad.plane(normal_x) + i), gy = simd::load<V>(grad.plane(normal_y) + i);
      adam(normal_x, i, gx * k3 * (V(1) + uy * uy) - gy * ux * uy * k3);
      adam(normal_y, i, -gx * ux * uy * k3 + gy * k3 * (V(1) + ux * ux));
    }
    block_maps_from_unconstrained(u, maps, i);
  }
}

/// Every rank's texels [first_texel, last_texel) of every plane of u to every rank (the refine's
/// share over ranks, put together at its end).
inline void gather_texels(const communicator& ranks, material_maps& u, std::size_t first_texel, std::size_t last_texel) {
  std::vector<float> all;
  const std::size_t group_count = texel_groups::count(u);
  const std::vector<std::size_t> counts = group_share_counts(ranks, group_count, texel_group_size, u.texel_count());
  for (int k = 0; k < parameter_count; ++k) {
    ranks.all_gather(std::span<const float>(u.plane(k) + first_texel, last_texel - first_texel), all, counts);
    std::copy(all.begin(), all.end(), u.plane(k));
  }
}

}  // namespace detail

/// Unconstrained variables whose image under the refine parameterisation is (close to) `maps`.
inline material_maps unconstrained_from_maps(const material_maps& maps) {
  material_maps u(maps.width(), maps.height());
  for (std::size_t i = 0; i < maps.texel_count(); ++i) {
    for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0})
      u.plane(k)[i] = detail::logit(maps.plane(k)[i]);
    for (int k : {lobe_x, lobe_y}) {
      const float sigma = std::min(std::max(maps.plane(k)[i], 1.0001f * min_lobe_width), 0.9999f);
      u.plane(k)[i] = detail::logit(1.0f - std::log(sigma) / detail::log_min_lobe);
    }
    float nx = maps.plane(normal_x)[i], ny = maps.plane(normal_y)[i];
    const float r2 = nx * nx + ny * ny;
    if (r2 > 0.998f) { const float s = std::sqrt(0.998f / r2); nx *= s; ny *= s; }
    const float nz = std::sqrt(1.0f - nx * nx - ny * ny);
    u.plane(normal_x)[i] = nx / nz;
    u.plane(normal_y)[i] = ny / nz;
    u.plane(rotation)[i] = maps.plane(rotation)[i];
  }
  return u;
}

/// Refines `maps` in place so that their renderings under `cap` match the photographs behind
/// `targets` (docs/method.md section 5, eq. 5). F picks the kernel: with `anisotropic` off, sy follows sx and
/// alpha stays 0; with `normal_map` off, normals stay flat; with `fresnel` off, F0 is not optimised.
template <brdf_features F = all_features>
refine_result refine(material_maps& maps, const capture& cap, const loss_targets& targets, const refine_options& options = {}) {
  const auto start = std::chrono::steady_clock::now();
  const int w = maps.width(), h = maps.height();
  material_maps u = unconstrained_from_maps(maps);
  material_maps grad(w, h), m1(w, h), m2(w, h);
  refine_result result;
  const std::size_t n = maps.texel_count();
  std::vector<int> active = {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, lobe_x};
  if (F.anisotropic) { active.push_back(lobe_y); active.push_back(rotation); }
  if (F.fresnel) active.push_back(fresnel_f0);
  nn::early_stopping stopper(options.min_relative_improvement, options.patience);
  // Texel groups (freezing): which are still optimised, their loss now and at the last check.
  const bool freezing = options.freeze_tolerance > 0 && options.freeze_every > 0;
  const std::size_t group_count = texel_groups::count(maps);
  std::vector<std::uint8_t> group_active(group_count, 1);
  std::vector<double> group_loss(group_count, 0.0), group_loss_checked(group_count, 0.0);
  // Over several ranks: this rank's groups [first_group, last_group), evaluated where also active.
  const bool shared = options.ranks && options.ranks->distributed();
  const auto share = shared ? part_range(int(group_count), options.ranks->size(), options.ranks->rank()) : std::pair{0, int(group_count)};
  const std::size_t first_group = std::size_t(share.first), last_group = std::size_t(share.second);
  std::vector<std::uint8_t> evaluated(shared ? group_count : 0, 0);
  const texel_groups groups{shared ? evaluated.data() : freezing ? group_active.data() : nullptr, group_loss.data()};
  std::size_t evaluated_groups = 0, active_count = group_count;
  const std::size_t first_texel = first_group * texel_group_size, last_texel = std::min(n, last_group * texel_group_size);
  // The maps of u (a reduced kernel F ignores the planes it lacks; over ranks, this rank's texels
  // alone); from then on each Adam step writes the maps of the texels it moves.
  detail::maps_from_unconstrained(u, maps, nullptr, first_texel, last_texel);
  for (int step = 0; step < options.steps; ++step) {
    if (shared)
      for (std::size_t g = first_group; g < last_group; ++g) evaluated[g] = group_active[g];
    loss_and_gradient<F>(maps, cap, targets, &grad, options.placement, options.render, &groups);
    if (shared) detail::gather_groups(*options.ranks, group_loss, first_group, last_group);
    // The sum of the groups' losses in group order: the same bits on any rank and thread count.
    double loss = 0;
    for (double l : group_loss) loss += l;
    result.losses.push_back(loss);
    evaluated_groups += active_count;
    // Freeze before this step's update, so a frozen group's maps are those its cached loss belongs to.
    if (freezing && step % options.freeze_every == 0)
      active_count -= detail::freeze_converged_groups(group_active, group_loss, group_loss_checked, step, options.freeze_tolerance);
    const nn::adam_coefficients<float> coefficients(options.beta1, options.beta2, options.epsilon, options.learning_rate, step + 1);
    detail::adam_step_and_maps<F>(u, m1, m2, grad, maps, active, coefficients, freezing ? group_active.data() : nullptr, first_group, last_group);
    result.steps = step + 1;
    if (options.progress && options.progress_every > 0 && (step + 1) % options.progress_every == 0)
      options.progress(optimisation_progress::at(step + 1, options.steps, loss, seconds_since(start)));
    if (stopper.stop_after(step, loss) && step + 1 >= options.min_steps) break;
  }
  if (shared) detail::gather_texels(*options.ranks, u, first_texel, last_texel);  // every rank's texels to every rank
  detail::maps_from_unconstrained(u, maps);
  restrict_to_features(maps, F);
  if (result.steps > 0) result.evaluated_fraction = double(evaluated_groups) / (double(group_count) * result.steps);
  result.final_loss = loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, options.render);
  result.seconds = seconds_since(start);
  return result;
}

/// `maps` with both lobe widths raised to at least `width` (every other plane unchanged): refine's
/// wide-lobe second start (refine_two_starts). A narrow lobe whose highlight falls where no
/// photograph looks gets no gradient towards it; a wide one sees it.
inline material_maps with_lobes_at_least(const material_maps& maps, float width) {
  if (!(width > 0 && width <= 1)) throw std::invalid_argument("with_lobes_at_least: the lobe width must be in (0, 1]");
  material_maps wide = maps;
  for (int k : {lobe_x, lobe_y})
    for (std::size_t i = 0; i < wide.texel_count(); ++i) wide.plane(k)[i] = std::max(wide.plane(k)[i], width);
  return wide;
}

/// Replaces `kept`'s texels by `candidate`'s in every texel group (texel_groups, 64 texels in
/// row-major order) where the candidate's image loss is lower. The loss is a sum of independent
/// per-texel terms, so the result's loss is exactly the sum of the two sets' per-group minima: never
/// above either set's. Returns the number of groups replaced. Both sets must have the same size.
template <brdf_features F = all_features>
std::size_t keep_lower_loss_groups(material_maps& kept, const material_maps& candidate, const capture& cap, const loss_targets& targets,
                                   const tile_placement& placement = {}, const render_options& render = {}) {
  if (kept.width() != candidate.width() || kept.height() != candidate.height())
    throw std::invalid_argument("keep_lower_loss_groups: the two map sets differ in size");
  const std::size_t groups = texel_groups::count(kept);
  std::vector<double> kept_loss(groups), candidate_loss(groups);
  const texel_groups kept_groups{nullptr, kept_loss.data()}, candidate_groups{nullptr, candidate_loss.data()};
  loss_and_gradient<F>(kept, cap, targets, nullptr, placement, render, &kept_groups);
  loss_and_gradient<F>(candidate, cap, targets, nullptr, placement, render, &candidate_groups);
  std::size_t replaced = 0;
  for (std::size_t g = 0; g < groups; ++g) {
    if (!(candidate_loss[g] < kept_loss[g])) continue;
    const std::size_t begin = g * texel_group_size, end = std::min(kept.texel_count(), begin + texel_group_size);
    for (int k = 0; k < parameter_count; ++k) std::copy(candidate.plane(k) + begin, candidate.plane(k) + end, kept.plane(k) + begin);
    ++replaced;
  }
  return replaced;
}

/// What `refine_two_starts` did.
struct two_start_result {
  refine_result first;             ///< refine from the given maps
  refine_result second;            ///< refine from the same maps with wide lobes
  double replaced_fraction = 0;    ///< share of texel groups taken from the second start
  double final_loss = 0;           ///< loss of the returned maps (at most min(first, second))
  double seconds = 0;
};

/// Refines `maps` from two starts, the maps as given and the same with both lobe widths at least
/// `lobe_width` (with_lobes_at_least), with the same options, and keeps per texel group whichever
/// fit has the lower loss (keep_lower_loss_groups). Costs two refines; the answer's loss is never
/// above the single start's. docs/method.md section 8.4 says when the second start pays.
template <brdf_features F = all_features>
two_start_result refine_two_starts(material_maps& maps, const capture& cap, const loss_targets& targets, float lobe_width,
                                   const refine_options& options = {}) {
  const auto start = std::chrono::steady_clock::now();
  two_start_result result;
  material_maps wide = with_lobes_at_least(maps, lobe_width);
  result.first = refine<F>(maps, cap, targets, options);
  result.second = refine<F>(wide, cap, targets, options);
  const std::size_t replaced = keep_lower_loss_groups<F>(maps, wide, cap, targets, options.placement, options.render);
  result.replaced_fraction = double(replaced) / double(texel_groups::count(maps));
  result.final_loss = loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, options.render);
  result.seconds = seconds_since(start);
  return result;
}

/// Mean of `plane` (n = width * height values, row-major) over the (2 radius + 1)^2 window around
/// each texel, the window clipped at the borders; `weights` (optional, same size) weighs each value.
/// Texels whose window holds no weight keep `fallback`'s value. Two running-sum passes: O(n)
/// whatever the radius.
inline void window_mean(const float* plane, const float* weights, const float* fallback, int width, int height, int radius, float* out) {
  const std::size_t n = std::size_t(width) * std::size_t(height);
  std::vector<double> value_rows(n), weight_rows(n);
  // Horizontal pass: window sums along each row.
#pragma omp parallel for schedule(static)
  for (int y = 0; y < height; ++y) {
    const std::size_t row = std::size_t(y) * std::size_t(width);
    double v = 0, w = 0;
    auto add = [&](int x, double sign) {
      const double wx = weights ? double(weights[row + x]) : 1.0;
      v += sign * wx * double(plane[row + x]);
      w += sign * wx;
    };
    for (int x = 0; x < std::min(radius, width); ++x) add(x, 1);
    for (int x = 0; x < width; ++x) {
      if (x + radius < width) add(x + radius, 1);
      if (x - radius - 1 >= 0) add(x - radius - 1, -1);
      value_rows[row + x] = v;
      weight_rows[row + x] = w;
    }
  }
  // Vertical pass over the row sums, one column at a time.
#pragma omp parallel for schedule(static)
  for (int x = 0; x < width; ++x) {
    double v = 0, w = 0;
    auto add = [&](int y, double sign) {
      v += sign * value_rows[std::size_t(y) * std::size_t(width) + x];
      w += sign * weight_rows[std::size_t(y) * std::size_t(width) + x];
    };
    for (int y = 0; y < std::min(radius, height); ++y) add(y, 1);
    for (int y = 0; y < height; ++y) {
      if (y + radius < height) add(y + radius, 1);
      if (y - radius - 1 >= 0) add(y - radius - 1, -1);
      const std::size_t i = std::size_t(y) * std::size_t(width) + x;
      // Running sums of positive weights: below 1e-9 of one texel's weight the window is empty
      // up to rounding.
      out[i] = w > 1e-9 ? float(v / w) : fallback[i];
    }
  }
}

/// `maps` with every plane replaced by its mean over the (2 radius + 1)^2 window around each texel
/// (window_mean): refine's neighbourhood start (refine_neighbour_restarts). Albedos, F0 and the
/// normal's x, y are averaged as they are (the mean of points in the unit disc stays in it), lobe
/// widths in log space (their scale), and alpha as its doubled-angle vector (cos 2 alpha,
/// sin 2 alpha) weighted by the texel's anisotropy |log(sigma_x / sigma_y)|: that vector is
/// continuous where alpha wraps from pi/2 to -pi/2, and an isotropic texel's alpha, which means
/// nothing, counts for nothing. A window without anisotropic texels keeps the texel's alpha.
inline material_maps neighbourhood_mean(const material_maps& maps, int radius) {
  if (radius < 1) throw std::invalid_argument("neighbourhood_mean: the radius must be at least 1 (got " + std::to_string(radius) + ")");
  const int w = maps.width(), h = maps.height();
  const std::size_t n = maps.texel_count();
  material_maps out(w, h);
  for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0, normal_x, normal_y})
    window_mean(maps.plane(k), nullptr, maps.plane(k), w, h, radius, out.plane(k));
  std::vector<float> log_lobe(n), mean(n);
  for (int k : {lobe_x, lobe_y}) {
    for (std::size_t i = 0; i < n; ++i) log_lobe[i] = std::log(std::max(maps.plane(k)[i], min_lobe_width));
    window_mean(log_lobe.data(), nullptr, log_lobe.data(), w, h, radius, mean.data());
    for (std::size_t i = 0; i < n; ++i) out.plane(k)[i] = std::exp(mean[i]);
  }
  std::vector<float> anisotropy(n), c(n), s(n), zero(n, 0.0f), mean_c(n), mean_s(n);
  for (std::size_t i = 0; i < n; ++i) {
    anisotropy[i] = std::abs(std::log(std::max(maps.plane(lobe_x)[i], min_lobe_width) / std::max(maps.plane(lobe_y)[i], min_lobe_width)));
    c[i] = std::cos(2 * maps.plane(rotation)[i]);
    s[i] = std::sin(2 * maps.plane(rotation)[i]);
  }
  window_mean(c.data(), anisotropy.data(), zero.data(), w, h, radius, mean_c.data());
  window_mean(s.data(), anisotropy.data(), zero.data(), w, h, radius, mean_s.data());
  for (std::size_t i = 0; i < n; ++i)
    out.plane(rotation)[i] = (mean_c[i] == 0 && mean_s[i] == 0) ? maps.plane(rotation)[i] : 0.5f * std::atan2(mean_s[i], mean_c[i]);
  return out;
}

/// What `refine_neighbour_restarts` did.
struct neighbour_restart_result {
  std::vector<int> radii;                 ///< the rounds' window radii, in order
  std::vector<double> replaced_fraction;  ///< per round: share of texel groups taken from its start
  std::vector<double> losses;             ///< per round: loss of the kept maps after it
  int steps = 0;                          ///< refine steps of all rounds
  double final_loss = 0;                  ///< loss of the returned maps (never above the given maps')
  double seconds = 0;
};

/// Neighbourhood restarts of a refined map set: for each radius r in turn, refine a start made of
/// the current maps' neighbourhood means (neighbourhood_mean, radius r) with `options`, and keep in
/// every texel group whichever of the current and the new fit has the lower loss
/// (keep_lower_loss_groups). The per-texel refine cannot leave a basin that needs several
/// parameters to move at once (on spun metal, where alpha turns through its wrap, texels fitted
/// with a rotation a quarter turn off and lobes narrowed to match); a start taken from the
/// neighbours, which fit, puts such texels in the right basin. Each round costs one refine; the
/// loss never rises. docs/method.md section 8.4 says what the rounds buy.
template <brdf_features F = all_features>
neighbour_restart_result refine_neighbour_restarts(material_maps& maps, const capture& cap, const loss_targets& targets,
                                                   const std::vector<int>& radii, const refine_options& options = {}) {
  const auto start = std::chrono::steady_clock::now();
  neighbour_restart_result result;
  const double groups = double(texel_groups::count(maps));
  for (int r : radii) {
    material_maps candidate = neighbourhood_mean(maps, r);  // refine restricts it to F's planes
    const refine_result round = refine<F>(candidate, cap, targets, options);
    result.steps += round.steps;
    const std::size_t replaced = keep_lower_loss_groups<F>(maps, candidate, cap, targets, options.placement, options.render);
    result.radii.push_back(r);
    result.replaced_fraction.push_back(double(replaced) / groups);
    result.losses.push_back(loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, options.render));
  }
  result.final_loss = result.losses.empty() ? loss_and_gradient<F>(maps, cap, targets, nullptr, options.placement, options.render)
                                            : result.losses.back();
  result.seconds = seconds_since(start);
  return result;
}

}  // namespace anisocap
