#pragma once
/// @file
/// The entry point of a capture: `capture_material(cap, photos, networks, options)` decides
/// everything a capture is, so that a host program that calls it with `capture_options{}` gets what
/// `anisocap capture` writes:
/// - which stages run: the network stages where there are networks and no start maps, else the
///   first guess (or the start maps) and the refine alone, with its own schedule
///   (capture_options::refine_alone);
/// - the neighbourhood restarts after the refine (capture_options::neighbour_restarts);
/// - the second runs of the network stages, kept where they fit the photographs better
///   (second_run_options: the residual start, then the networks' second prior);
/// - the canonical form of the returned maps (brdf/canonical_maps.hpp);
/// - how well the photographs determine each parameter of each texel (capture_options::uncertainty,
///   pipeline/uncertainty.hpp).
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "anisocap/brdf/canonical_maps.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/pipeline/networks.hpp"

namespace anisocap {

/// How many times worse the auto-encoder projection of the estimate (the encode stage) fits the
/// photographs than the estimate itself: large where the projection loses what the estimator
/// found, the case the residual start (finetune_options::residual) is for. NaN when either stage
/// did not run.
inline double projection_ratio(const capture_result& r) { return r.stage_loss("encode") / r.stage_loss("estimate"); }

namespace capture_material_detail {

/// The options of the refine alone: the first guess (or start maps) and the refine, with
/// refine_alone's schedule and restarts.
inline capture_options refine_alone(const capture_options& o) {
  capture_options a = o;
  a.stages = pipeline_stages{false, false, false, o.stages.refine};
  a.refine = o.refine_alone;
  a.neighbour_restarts = o.neighbour_restarts_alone;
  return a;
}

inline void say(const capture_options& o, const std::string& text) {
  if (o.log) o.log(text);
}

inline std::string run_name(const networks::prior& p, bool residual) {
  return "the weights in " + p.folder.string() + (residual ? " with the residual start" : "");
}

/// One run on `first`, then, where second_run_options allow, a second run: on `second` when given
/// (with `o`'s start), else on `first` with the residual start. Returns the better fit and says
/// in `choice` which it kept. `first_choice` (optional) is the choice made inside the first run
/// (its residual start), whose projection ratio and start the second-prior decision reads.
inline capture_result better_of_two(const networks::prior& first_prior, const networks::prior* second_prior, const capture& cap,
                                    const std::vector<image>& photos, const capture_options& o, const std::vector<image>& masks,
                                    run_choice& choice, const std::optional<run_choice>& first_choice, capture_result first) {
  const bool same_weights = second_prior == nullptr;
  const networks::prior& other = same_weights ? first_prior : *second_prior;
  const bool first_residual = first_choice ? first_choice->chosen_residual : o.finetune.residual;
  const double ratio = first_choice ? first_choice->projection_ratio : projection_ratio(first);
  capture_options o2 = o;
  if (same_weights) o2.finetune.residual = true;
  const bool second_residual = o2.finetune.residual;
  const std::string first_name = first_choice && first_choice->other_ran
                                     ? "the better of two starts with the weights in " + first_prior.folder.string()
                                     : run_name(first_prior, first_residual);
  const std::string second_name = run_name(other, second_residual);
  auto not_tried = [&](const std::string& why) {
    char text[160];
    std::snprintf(text, sizeof text, "%.4f", first.loss);
    say(o, first_name + " fit the photographs to " + text + "; " + why + ": " + second_name + " not tried");
    choice = run_choice{first_prior.folder, other.folder, first.loss, 0, 0, false, first_residual, second_residual, ratio};
    return std::move(first);
  };
  char why[200];
  if (!(first.loss > o.second_run.above)) {
    std::snprintf(why, sizeof why, "at most %g", o.second_run.above);
    return not_tried(why);
  }
  if (same_weights && first_residual) return not_tried("it had the residual start already");
  if (same_weights && o.second_run.residual_ratio > 0 && ratio < o.second_run.residual_ratio) {
    std::snprintf(why, sizeof why, "the auto-encoder's projection fits %.2fx worse than the estimate, under %g", ratio,
                  o.second_run.residual_ratio);
    return not_tried(why);
  }
  std::snprintf(why, sizeof why, "%.4f", first.loss);
  say(o, first_name + " fit the photographs to " + why + "; now " + second_name);
  if (!o2.checkpoint.folder.empty()) o2.checkpoint.folder /= same_weights ? "alternative" : "also_models";
  capture_result second = other.run(cap, photos, o2, nullptr, masks);
  const bool take_second = !first.stopped && !second.stopped && second.loss < first.loss;
  choice = take_second ? run_choice{other.folder, first_prior.folder, second.loss, first.loss, first.stage_seconds(), true,
                                    second_residual, first_residual, ratio}
                       : run_choice{first_prior.folder, other.folder, first.loss, second.loss, second.stage_seconds(), true,
                                    first_residual, second_residual, ratio};
  char kept[120];
  std::snprintf(kept, sizeof kept, " (image loss %.4f against %.4f)", take_second ? second.loss : first.loss,
                take_second ? first.loss : second.loss);
  say(o, "kept " + (take_second ? second_name : first_name) + kept);
  return take_second ? std::move(second) : std::move(first);
}

/// The network stages with `nets`, and their second runs (second_run_options).
inline capture_result with_networks(const networks& nets, const capture& cap, const std::vector<image>& photos,
                                    const capture_options& o, const std::vector<image>& masks) {
  const networks::prior& first_prior = *nets.first();
  // The residual start can differ from the first run only where the encode and fine-tune run.
  const bool residual = o.second_run.residual && o.stages.encode && o.stages.finetune;
  const bool second = o.second_run.second_prior && nets.has_second_prior();
  capture_result result = first_prior.run(cap, photos, o, nullptr, masks);
  std::optional<run_choice> choice;
  if (residual) {
    run_choice c;
    result = better_of_two(first_prior, nullptr, cap, photos, o, masks, c, std::nullopt, std::move(result));
    choice = c;
  }
  if (second) {
    run_choice c;
    result = better_of_two(first_prior, nets.second(), cap, photos, o, masks, c, choice, std::move(result));
    choice = c;
  }
  result.choice = choice;
  return result;
}

}  // namespace capture_material_detail

/// Captures the map set of one material from its photographs (one per configuration of `cap`),
/// as `anisocap capture` does (see the file comment for what it decides). `nets` empty: the first
/// guess and the refine alone. `masks` (optional, one 1-channel image per photograph, 0 = left
/// out, e.g. clipped pixels: data/photo_io.hpp) keep pixels out of every image loss; `start`
/// (optional) replaces the network stages and the first guess. The returned maps are in canonical
/// form. Throws std::invalid_argument for impossible options (capture_options::validate) or
/// inputs of the wrong count or size.
inline capture_result capture_material(const capture& cap, const std::vector<image>& photos, const networks& nets,
                                       const capture_options& o = {}, const std::vector<image>& masks = {},
                                       const material_maps* start = nullptr) {
  o.validate();
  if (start && (start->width() != (photos.empty() ? 0 : photos[0].width()) || start->height() != photos[0].height()))
    throw std::invalid_argument("capture_material: the start maps are " + std::to_string(start->width()) + "x" +
                                std::to_string(start->height()) + ", the photographs " +
                                (photos.empty() ? std::string("none") : std::to_string(photos[0].width()) + "x" + std::to_string(photos[0].height())));
  const bool network_stages = !nets.empty() && !start && o.stages.networks();
  capture_result result = network_stages ? capture_material_detail::with_networks(nets, cap, photos, o, masks)
                                         : capture_once(cap, photos, capture_material_detail::refine_alone(o), start, masks);
  result.networks_ran = network_stages;
  canonicalise(result.maps);
  if (result.after_finetune) canonicalise(*result.after_finetune);
  if (o.uncertainty && !result.stopped) {  // against the photographs as the stages saw them
    const fitted_photographs seen = fitted_targets(cap, photos, masks, result.exposure_scale);
    result.uncertainty = texel_uncertainty(result.maps, seen.configurations, seen.targets, *o.uncertainty);
  }
  return result;
}

/// capture_material on a capture description and its photographs (read_capture_photographs).
inline capture_result capture_material(const capture_photographs& input, const networks& nets, const capture_options& o = {}) {
  return capture_material(input.description, input.pixels(), nets, o, input.masks());
}

}  // namespace anisocap
