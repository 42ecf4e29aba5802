#pragma once
// The flags that set the option fields the library's messages name (core/option_names.hpp): each
// command passes its errors through naming_options with its table.
#include "anisocap/core/option_names.hpp"

namespace anisocap::commands {

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
    {"estimate_options::window", "--estimate-window"},
    {"estimate_options::stride", "--estimate-stride"},
    {"capture_options::second_start_lobe_width", "--second-start"},
    {"capture_options::neighbour_restarts", "--neighbour-restarts"},
    {"capture_options::network_precision", "--network-precision"},
    {"capture_options::second_run.above", "--also-models-above"},
    {"capture_options::second_run.residual_ratio", "--also-residual-ratio"},
    {"checkpoint_options::resume", "--resume"},
    {"pipeline_stages", "--stages"},
    {"kernel_options", "--kernel"},
};

}  // namespace anisocap::commands
