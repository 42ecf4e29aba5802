#pragma once
// The training options the training tests share: 4 steps of 2 materials, a validation and a
// check-point every 2 steps, no log output.
#include <filesystem>
#include <string>

#include "anisocap/training/training.hpp"

namespace anisocap::testing {

/// Options of a tiny training run into `dir` on size x size materials.
inline training::train_options tiny_options(const std::filesystem::path& dir, int size) {
  training::train_options o;
  o.out_dir = dir;
  o.steps = 4;
  o.size = size;
  o.batch = 2;
  o.learning_rate = 1e-3;
  o.seed = 5;
  o.validate_every = 2;
  o.validation_count = 1;
  o.checkpoint_minutes = 1e9;
  o.checkpoint_every = 2;
  o.log = [](const std::string&) {};
  return o;
}

}  // namespace anisocap::testing
