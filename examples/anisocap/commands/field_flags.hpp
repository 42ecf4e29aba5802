#pragma once
// The flags that set the option fields the library's messages name (core/option_names.hpp), every
// command's table in this one place: each command binds its flags by field (capture_flag,
// train_flag) and passes its errors through naming_options with its table, so that a flag is
// spelt once and the messages cannot name another.
#include <span>
#include <string_view>

#include "anisocap/core/option_names.hpp"

namespace anisocap::commands {

/// The flag `table` gives `field`, at compile time: a field the table lacks does not compile.
consteval const char* flag_of(std::span<const option_name> table, std::string_view field) {
  for (const option_name& e : table)
    if (e.field == field) return e.name.data();  // the table's names are string literals
  throw "the table names no flag for this field";  // not a constant expression: a compile error
}

/// The fields of capture_options (with its refine_options, finetune_options, estimate_options,
/// pipeline_stages and kernel_options) that capture, demo and eval set by flags.
inline constexpr option_name capture_field_flags[] = {
    {"refine_options::steps", "--steps"},
    {"refine_options::learning_rate", "--lr"},
    {"refine_options::min_relative_improvement", "--refine-stop"},
    {"refine_options::freeze_tolerance", "--freeze"},
    {"finetune_options::steps", "--finetune-steps"},
    {"finetune_options::learning_rate", "--finetune-lr"},
    {"finetune_options::warmup", "--finetune-warmup"},
    {"finetune_options::half_life", "--finetune-half-life"},
    {"finetune_options::crop.cells", "--finetune-crop"},
    {"finetune_options::shard_cells", "--finetune-shards"},
    {"finetune_options::min_improvement", "--finetune-stop"},
    {"finetune_options::guard.factor", "--finetune-guard"},
    {"finetune_options::residual", "--finetune-residual"},
    {"estimate_options::window", "--estimate-window"},
    {"estimate_options::stride", "--estimate-stride"},
    {"capture_options::second_start_lobe_width", "--second-start"},
    {"capture_options::neighbour_restarts", "--neighbour-restarts"},
    {"capture_options::network_precision", "--network-precision"},
    {"capture_options::second_run.above", "--also-models-above"},
    {"capture_options::second_run.residual_ratio", "--also-residual-ratio"},
    {"capture_options::second_run.residual", "--also-residual"},
    {"checkpoint_options::resume", "--resume"},
    {"pipeline_stages", "--stages"},
    {"kernel_options", "--kernel"},
};

/// The flag of capture, demo and eval that sets `field` (capture_field_flags).
consteval const char* capture_flag(std::string_view field) { return flag_of(capture_field_flags, field); }

/// The flags of train-estimator and train-autoencoder that set each train_options field a library
/// message names, and the names a resume's hint gives.
inline constexpr option_name train_field_flags[] = {
    {"train_options::steps", "--steps"},
    {"train_options::seed", "--seed"},
    {"train_options::size", "--size"},
    {"train_options::batch", "--batch"},
    {"train_options::learning_rate", "--lr"},
    {"train_options::checkpoint_minutes", "--checkpoint-minutes"},
    {"train_options::validate_every", "--validate-every"},
    {"train_options::validation_count", "--validation-count"},
    {"train_options::resume", "--resume"},
    {"train_options::init_weights", "--init"},
    {"train_options::smoothness_weight", "--smoothness"},
    {"train_options::latent_noise", "--latent-noise"},
    {"train_options::render_weight", "--render-weight"},
    {"train_options::lobe_weight", "--lobe-weight"},
    {"train_options::sigma_weight", "--sigma-weight"},
    {"train_options::mse_weight", "--mse-weight"},
    {"train_options::diffuse_weight", "--diffuse-weight"},
    {"train_options::normal_weight", "--normal-weight"},
    {"train_options::encoder_only false", "--trainable all"},  // a resume's hint, before the field alone
    {"train_options::encoder_only true", "--trainable encoder"},
    {"train_options::encoder_only", "--trainable encoder"},
    {"train_options::inputs_are_estimates false", "--inputs truth"},
    {"train_options::inputs_are_estimates true", "--inputs estimates"},
    {"train_options::inputs_are_estimates", "--inputs estimates"},
    {"train_options::mix", "--materials"},
    {"train_options::emphasis", "--emphasis"},
    {"train_options::emphasis_share", "--emphasis-share"},
    {"train_options::input_noise.shot", "--shot-noise"},
    {"train_options::input_noise.read", "--read-noise"},
    {"train_options::lr_decay_from", "--lr-decay-from"},
    {"train_options::lr_decay_to", "--lr-decay-to"},
    {"train_options::lr_end", "--lr-end"},
    {"train_options::lr_warmup", "--lr-warmup"},
    {"train_options::lr_rewarmup", "--lr-rewarmup"},
    {"train_options::lr_rewarmup_from", "--lr-rewarmup-from"},
    {"train_options::data_parallel", "--data-parallel"},
    {"train_options::prefetch", "--prefetch"},
    {"train_options::precision", "--network-precision"},
    {"train_autoencoder", "train-autoencoder"},  // the trainer a resume names
    {"train_estimator", "train-estimator"},
    {"the preset", "--preset"},                  // the trainer's template argument
};

/// The flag of train-estimator and train-autoencoder that sets `field` (train_field_flags).
consteval const char* train_flag(std::string_view field) { return flag_of(train_field_flags, field); }

/// The flags of batch that set each batch_selection field a library message names.
inline constexpr option_name batch_field_flags[] = {
    {"batch_selection::names", "--sample"},
    {"batch_selection::index", "--index"},
    {"batch_selection::count", "--count"},
};

/// The flags that set the estimate_options fields eval-networks' messages name.
inline constexpr option_name eval_networks_field_flags[] = {{"estimate_options::window", "--window"},
                                                            {"estimate_options::stride", "--stride"}};

}  // namespace anisocap::commands
