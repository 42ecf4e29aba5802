#pragma once
/// @file
/// The training losses (docs/method.md section 7): L1 in network space with the lobe widths' and
/// rotation's symmetric form, the lobe widths' and the maps' squared errors in their original
/// ranges, and the render loss, with their gradients and weights (map_losses).
#include <algorithm>
#include <cmath>
#include <span>
#include <stdexcept>

#include "anisocap/data/family_errors.hpp"
#include "anisocap/training/samples.hpp"

namespace anisocap::training {

/// The parts of a loss, each averaged over the batch.
struct loss_terms {
  double total = 0;       ///< what is minimised
  double l1 = 0;          ///< mean |u - u_true| in network space (unweighted)
  double lobe = 0;        ///< the lobe widths' and rotation's part of l1 (lobe_l1's, unweighted)
  double sigma = 0;       ///< mean squared error of the lobe widths in the original range (lobe_width_squared_error; unweighted)
  double mse = 0;         ///< squared error of a_d, a'_s, F0 and the normal's x, y in the original ranges (map_squared_error; unweighted)
  double diffuse = 0;     ///< a_d's part of l1 (unweighted)
  double normal = 0;      ///< the normal's part of l1 (unweighted)
  double mse_diffuse = 0; ///< a_d's part of mse (unweighted)
  double mse_normal = 0;  ///< the normal's part of mse (unweighted)
  double render = 0;      ///< render loss (sum over the 4 configurations of the mean log-image difference)
  double smoothness = 0;  ///< auto-encoder only: mean |D(z) - D(z + delta)| (unweighted)
};

/// Network-space width of the rotation weight's ramp: |u_x - u_y| (log lobe widths in network
/// space) at which the truth's lobe ratio sigma_x / sigma_y reaches 1.25, the threshold at which
/// compare_maps counts a texel as anisotropic.
inline const double rotation_ramp = 2 * std::log(1.25) / (-network_space::log_min_lobe);

/// The L1 distance of one texel's lobe parameters (network space: p predicted, q true, each indexed
/// by parameter_index) that respects the lobe's symmetries (docs/method.md section 1): the
/// rotation difference is taken modulo pi (2 in network space), (sigma_x, sigma_y, alpha) is
/// compared with both of the truth's equivalent forms and the nearer one counts, and the rotation
/// term is weighted by the truth's anisotropy, min(1, |q_x - q_y| / rotation_ramp): an isotropic
/// lobe has no rotation to learn. When g is given, adds `step` times the gradient with respect to
/// p[lobe_x], p[lobe_y] and p[rotation] into g (indexed the same way). When `form` is given, it
/// receives the truth's form that counted: 0 as is, 1 swapped.
inline double lobe_l1(const float* p, const float* q, float* g, float step, int* form = nullptr) {
  auto wrap = [](double d) { return d - 2 * std::nearbyint(d / 2); };  // into [-1, 1]: alpha modulo pi
  auto sign = [](double d) { return d > 0 ? 1.0 : (d < 0 ? -1.0 : 0.0); };
  const double w = std::min(1.0, std::abs(double(q[lobe_x]) - q[lobe_y]) / rotation_ramp);
  // Form 0: (q_x, q_y, q_a); form 1: (q_y, q_x, q_a + 1), the same lobe.
  const double dx[2] = {double(p[lobe_x]) - q[lobe_x], double(p[lobe_x]) - q[lobe_y]};
  const double dy[2] = {double(p[lobe_y]) - q[lobe_y], double(p[lobe_y]) - q[lobe_x]};
  const double da[2] = {wrap(double(p[rotation]) - q[rotation]), wrap(double(p[rotation]) - q[rotation] - 1)};
  double cost[2];
  for (int f = 0; f < 2; ++f) cost[f] = std::abs(dx[f]) + std::abs(dy[f]) + w * std::abs(da[f]);
  const int f = cost[1] < cost[0] ? 1 : 0;
  if (form) *form = f;
  if (g) {
    g[lobe_x] += float(step * sign(dx[f]));
    g[lobe_y] += float(step * sign(dy[f]));
    g[rotation] += float(step * w * sign(da[f]));
  }
  return cost[f];
}

/// The squared error of one texel's lobe widths in the original range, (sigma_x - s_x)^2 +
/// (sigma_y - s_y)^2 with sigma = network_space::from_network of p's lobe channels and s the truth's
/// form `form` (lobe_l1's: 0 as is, 1 swapped). This is what compare_maps measures (there the form
/// is chosen by the squared errors of the widths and the rotation), unlike the L1 of log widths,
/// which lets broad lobes be far off. When g is given, adds `step` times the gradient with respect
/// to p[lobe_x] and p[lobe_y] into g.
inline double lobe_width_squared_error(const float* p, const float* q, int form, float* g, float step) {
  const double sx = network_space::from_network(lobe_x, p[lobe_x]), sy = network_space::from_network(lobe_y, p[lobe_y]);
  const double tx = network_space::from_network(lobe_x, q[form == 0 ? lobe_x : lobe_y]);
  const double ty = network_space::from_network(lobe_y, q[form == 0 ? lobe_y : lobe_x]);
  if (g) {  // d sigma / du = sigma (-log_min_lobe) / 2
    const double c = -network_space::log_min_lobe;
    g[lobe_x] += float(step * 2 * (sx - tx) * sx * c / 2);
    g[lobe_y] += float(step * 2 * (sy - ty) * sy * c / 2);
  }
  return (sx - tx) * (sx - tx) + (sy - ty) * (sy - ty);
}

/// Whether parameter k is one of a_d's channels (loss_weights::diffuse weighs them).
constexpr bool is_diffuse_channel(int k) { return k == diffuse_r || k == diffuse_g || k == diffuse_b; }
/// Whether parameter k is one of the shading normal's channels (loss_weights::normal weighs them).
constexpr bool is_normal_channel(int k) { return k == normal_x || k == normal_y; }

/// map_squared_error's result: the total and the parts of it that a_d's and the normal's planes make
/// (all unscaled).
struct map_squared_errors {
  double total = 0;    ///< a_d, a'_s, F0 and the normal's x, y
  double diffuse = 0;  ///< a_d's part of total (compare_maps' diffuse error)
  double normal = 0;   ///< the normal's part of total (compare_maps' normal error without its z term)
};

/// The squared error of a_d, a'_s, F0 and the shading normal's x and y in the original ranges,
/// each map's mean as compare_maps takes it: compare_maps' diffuse + specular + fresnel errors plus
/// its normal error without the z component's term (what evaluations measure of these maps, the
/// lobe widths having lobe_width_squared_error and the rotation lobe_l1), with a_d's and the
/// normal's parts. When g is given (the maps' size), adds `scale` times the gradient with respect to
/// `estimate` into g, a_d's planes' part times `diffuse_scale` and the normal's times `normal_scale`.
inline map_squared_errors map_squared_error(const material_maps& estimate, const material_maps& truth, material_maps* g,
                                            double scale, double diffuse_scale = 1, double normal_scale = 1) {
  const std::size_t n = truth.texel_count();
  // Each plane's weight in the sum: 1 / (3n) for the RGB albedos and the normal (compare_maps
  // averages over 3 components), 1 / n for F0.
  static constexpr int planes[] = {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, normal_x, normal_y, fresnel_f0};
  map_squared_errors errors;
  for (int k : planes) {
    const bool is_diffuse = is_diffuse_channel(k), is_normal = is_normal_channel(k);
    const double weight = (k == fresnel_f0 ? 1.0 : 1.0 / 3) / double(n);
    const double step = scale * weight * 2 * (is_diffuse ? diffuse_scale : is_normal ? normal_scale : 1.0);
    const float *e = estimate.plane(k), *t = truth.plane(k);
    float* gk = g ? g->plane(k) : nullptr;
    double sum = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double d = double(e[i]) - t[i];
      sum += d * d;
      if (gk) gk[i] += float(step * d);
    }
    errors.total += weight * sum;
    if (is_diffuse) errors.diffuse += weight * sum;
    if (is_normal) errors.normal += weight * sum;
  }
  return errors;
}

/// The weights of map_losses' terms in the training loss (train_options::loss()).
struct loss_weights {
  double render = 1.0;  ///< the render loss, against the L1 term (docs/method.md section 5: 1)
  double lobe = 1.0;    ///< the lobe widths' and rotation's L1 (lobe_l1) against the other channels'
  double sigma = 0.0;   ///< the lobe widths' squared error in the original range (lobe_width_squared_error)
  double mse = 0.0;     ///< the other maps' squared error in the original ranges (map_squared_error)
  double diffuse = 1.0; ///< a_d's terms (its L1 and its part of the squared error) against the other maps'
  double normal = 1.0;  ///< the normal's terms (its L1 and its part of the squared error) against the other maps'
};

/// L1 in network space plus `w.render` times the render loss (docs/method.md section 5: equal
/// weights, w.render 1), of network outputs u (one entry per sample); when grad is given, adds
/// d(loss)/du (the loss is the batch mean). The L1 of the lobe widths and the rotation is
/// lobe_l1's, which respects the lobe's symmetries, weighted by `w.lobe` in the total and the
/// gradient; the other channels take |u - u_true|, a_d's weighted by `w.diffuse` and the normal's by
/// `w.normal`. With w.sigma > 0 the total adds w.sigma times the mean over texels and the two widths
/// of lobe_width_squared_error (terms.sigma), with w.mse > 0 w.mse times map_squared_error
/// (terms.mse), its a_d and normal parts weighted by w.diffuse and w.normal. The terms are
/// unweighted; terms.total = l1 + (w.lobe - 1) lobe + (w.diffuse - 1) diffuse + (w.normal - 1)
/// normal + w.sigma sigma + w.mse (mse + (w.diffuse - 1) mse_diffuse + (w.normal - 1) mse_normal) +
/// w.render render.
///
/// `batch_size` > 0: the loss and gradient are this entry's share of a mean over `batch_size`
/// materials (data-parallel training computes each material of a batch alone, train_options::
/// data_parallel); 0: the mean over u's batch.
inline loss_terms map_losses(const tensor<parameter_count>& u, std::span<const sample> samples, tensor<parameter_count>* grad,
                             const loss_weights& w = {}, int batch_size = 0) {
  loss_terms terms;
  const int entries = u.batch(), B = batch_size > 0 ? batch_size : entries;
  if (entries != int(samples.size())) throw std::invalid_argument("map_losses: batch and sample count differ");
  const std::size_t n = std::size_t(u.height()) * u.width() * parameter_count;
  // Each channel's weight in the L1 term (the lobe channels go through lobe_l1 and w.lobe).
  float channel_weight[parameter_count];
  for (int k = 0; k < parameter_count; ++k)
    channel_weight[k] = float(is_diffuse_channel(k) ? w.diffuse : is_normal_channel(k) ? w.normal : 1.0);
  for (int b = 0; b < entries; ++b) {
    const sample& s = samples[std::size_t(b)];
    double l1 = 0, lobe = 0, sigma = 0, diffuse = 0, normal = 0;
    const double texels = double(u.height()) * u.width();
    const float step = float(1.0 / (double(n) * B)), lobe_step = float(w.lobe / (double(n) * B)),
                sigma_step = float(w.sigma / (2 * texels * B));
    for (int y = 0; y < u.height(); ++y)
      for (int x = 0; x < u.width(); ++x) {
        const float* p = u.pixel(b, y, x);
        const float* q = s.truth_net.pixel(0, y, x);
        float* g = grad ? grad->pixel(b, y, x) : nullptr;
        for (int k = 0; k < parameter_count; ++k) {
          if (k == lobe_x || k == lobe_y || k == rotation) continue;
          const float d = p[k] - q[k];
          l1 += std::abs(d);
          if (is_diffuse_channel(k)) diffuse += std::abs(d);
          if (is_normal_channel(k)) normal += std::abs(d);
          const float channel_step = step * channel_weight[k];
          if (g) g[k] += d > 0 ? channel_step : (d < 0 ? -channel_step : 0.0f);
        }
        int form = 0;
        lobe += lobe_l1(p, q, g, lobe_step, &form);
        sigma += lobe_width_squared_error(p, q, form, w.sigma > 0 ? g : nullptr, sigma_step);
      }
    terms.l1 += (l1 + lobe) / double(n) / B;
    terms.lobe += lobe / double(n) / B;
    terms.diffuse += diffuse / double(n) / B;
    terms.normal += normal / double(n) / B;
    terms.sigma += sigma / (2 * texels) / B;
    const material_maps maps = network_space::network_to_maps(u, b);
    material_maps grad_maps;
    if (grad) grad_maps = material_maps(maps.width(), maps.height());
    const double r = loss_and_gradient(maps, s.loss_configurations, s.targets, grad ? &grad_maps : nullptr);
    terms.render += r / B;
    if (grad) network_space::add_network_gradient(u, b, grad_maps, w.render / B, *grad);
    const bool mse_gradient = grad && w.mse > 0;
    material_maps grad_mse;
    if (mse_gradient) grad_mse = material_maps(maps.width(), maps.height());
    const map_squared_errors mse = map_squared_error(maps, s.truth, mse_gradient ? &grad_mse : nullptr, 1.0, w.diffuse, w.normal);
    terms.mse += mse.total / B;
    terms.mse_diffuse += mse.diffuse / B;
    terms.mse_normal += mse.normal / B;
    if (mse_gradient) network_space::add_network_gradient(u, b, grad_mse, w.mse / B, *grad);
  }
  terms.total = terms.l1 + (w.lobe - 1) * terms.lobe + (w.diffuse - 1) * terms.diffuse + (w.normal - 1) * terms.normal +
                w.sigma * terms.sigma + w.mse * (terms.mse + (w.diffuse - 1) * terms.mse_diffuse + (w.normal - 1) * terms.mse_normal) +
                w.render * terms.render;
  return terms;
}

}  // namespace anisocap::training
