#pragma once
/// @file
/// Learning-rate schedules of the optimisers (nn/adam.hpp): constant, step and exponential decay,
/// each with an optional linear warm-up.
#include <cmath>
#include <stdexcept>

namespace anisocap::nn {

/// Learning rate as a function of the optimiser's step number (0 for the first step).
class learning_rate_schedule {
 public:
  /// The same rate at every step.
  static learning_rate_schedule constant(double rate) { return {rate, 1, 1.0, kind::constant}; }
  /// rate * factor^floor(step / every): the rate drops by `factor` every `every` steps.
  static learning_rate_schedule step_decay(double rate, long every, double factor) {
    if (every <= 0) throw std::invalid_argument("learning_rate_schedule::step_decay: every must be positive");
    return {rate, every, factor, kind::step};
  }
  /// rate * factor^(step / every): a smooth decay by `factor` per `every` steps.
  static learning_rate_schedule exponential_decay(double rate, double factor, long every = 1) {
    if (every <= 0) throw std::invalid_argument("learning_rate_schedule::exponential_decay: every must be positive");
    return {rate, every, factor, kind::exponential};
  }

  /// The same schedule with a linear warm-up: step s < `steps` gets (s + 1) / steps of its rate
  /// (large rates that diverge from a cold start become usable). 0: no warm-up.
  learning_rate_schedule with_warmup(long steps) const {
    if (steps < 0) throw std::invalid_argument("learning_rate_schedule::with_warmup: steps must not be negative");
    learning_rate_schedule s = *this;
    s.warmup_ = steps;
    return s;
  }

  /// `rate` after a linear warm-up of `warmup` steps, halving every `half_life` steps (0: constant),
  /// the fine-tune's schedule (docs/method.md section 8).
  static learning_rate_schedule warmup_half_life(double rate, long warmup, long half_life) {
    return (half_life > 0 ? exponential_decay(rate, 0.5, half_life) : constant(rate)).with_warmup(warmup);
  }

  /// The same schedule with every rate multiplied by `factor`.
  learning_rate_schedule scaled(double factor) const {
    learning_rate_schedule s = *this;
    s.rate_ *= factor;
    return s;
  }

  /// The learning rate of step `step` (counted from 0).
  double operator()(long step) const {
    const double ramp = step < warmup_ ? double(step + 1) / double(warmup_) : 1.0;
    switch (kind_) {
      case kind::constant: return ramp * rate_;
      case kind::step: return ramp * rate_ * std::pow(factor_, double(step / every_));
      case kind::exponential: return ramp * rate_ * std::pow(factor_, double(step) / double(every_));
    }
    return rate_;
  }

 private:
  enum class kind { constant, step, exponential };
  learning_rate_schedule(double rate, long every, double factor, kind k)
      : rate_(rate), every_(every), factor_(factor), kind_(k) {}
  double rate_;
  long every_;
  double factor_;
  kind kind_;
  long warmup_ = 0;
};

}  // namespace anisocap::nn
