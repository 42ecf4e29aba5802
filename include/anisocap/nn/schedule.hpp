#pragma once
/// @file
/// Learning-rate schedules of the optimisers (nn/adam.hpp): constant, step and exponential decay,
/// and a cosine decay between two steps, each with an optional linear warm-up.
#include <cmath>
#include <stdexcept>
#include <string>

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

  /// `rate` up to step `from`, then half a cosine down to `rate * final_factor` at step `to`, and
  /// `rate * final_factor` after it (training runs: a constant rate, then a decay at the end).
  /// Throws std::invalid_argument unless 0 <= from < to and final_factor is in [0, 1].
  static learning_rate_schedule cosine_decay(double rate, long from, long to, double final_factor) {
    if (!(from >= 0 && to > from))
      throw std::invalid_argument("learning_rate_schedule::cosine_decay: the decay must end after it starts (0 <= from < to), got " +
                                  std::to_string(from) + " and " + std::to_string(to));
    if (!(final_factor >= 0 && final_factor <= 1))
      throw std::invalid_argument("learning_rate_schedule::cosine_decay: the final factor must be in [0, 1], got " +
                                  std::to_string(final_factor));
    learning_rate_schedule s{rate, 1, final_factor, kind::cosine};
    s.from_ = from;
    s.to_ = to;
    return s;
  }

  /// The same schedule with a linear warm-up: step s < `steps` gets (s + 1) / steps of its rate
  /// (large rates that diverge from a cold start become usable). 0: no warm-up.
  learning_rate_schedule with_warmup(long steps) const {
    if (steps < 0) throw std::invalid_argument("learning_rate_schedule::with_warmup: steps must not be negative");
    learning_rate_schedule s = *this;
    s.warmup_ = {0, steps};
    return s;
  }

  /// The same schedule with a second linear warm-up in the middle of a run: step s in
  /// [from, from + steps) gets (s - from + 1) / steps of its rate, the steps outside it are as before.
  /// A run resumed with its optimiser state and a new decay restarts at the full rate from the low
  /// rate its last decay ended at; this ramps it up again instead. steps 0: none.
  learning_rate_schedule with_rewarmup(long from, long steps) const {
    if (from < 0 || steps < 0)
      throw std::invalid_argument("learning_rate_schedule::with_rewarmup: the first step and the length must not be negative");
    learning_rate_schedule s = *this;
    s.rewarmup_ = {from, steps};
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

  /// The rate the schedule starts from, before its warm-up and decay scale it (what `--lr` sets).
  double base_rate() const { return rate_; }

  /// The learning rate of step `step` (counted from 0).
  double operator()(long step) const {
    const double ramp = warmup_.factor(step) * rewarmup_.factor(step);
    switch (kind_) {
      case kind::constant: return ramp * rate_;
      case kind::step: return ramp * rate_ * std::pow(factor_, double(step / every_));
      case kind::exponential: return ramp * rate_ * std::pow(factor_, double(step) / double(every_));
      case kind::cosine: {
        if (step <= from_) return ramp * rate_;
        if (step >= to_) return ramp * rate_ * factor_;
        const double t = double(step - from_) / double(to_ - from_);
        return ramp * rate_ * (factor_ + (1 - factor_) * 0.5 * (1 + std::cos(3.14159265358979323846 * t)));
      }
    }
    return rate_;
  }

 private:
  enum class kind { constant, step, exponential, cosine };
  /// A linear ramp: step s in [from, from + steps) gets (s - from + 1) / steps, the others 1.
  struct linear_ramp {
    long from = 0, steps = 0;
    double factor(long step) const {
      return step >= from && step < from + steps ? double(step - from + 1) / double(steps) : 1.0;
    }
  };
  learning_rate_schedule(double rate, long every, double factor, kind k)
      : rate_(rate), every_(every), factor_(factor), kind_(k) {}
  double rate_;
  long every_;
  double factor_;
  kind kind_;
  linear_ramp warmup_;    // the warm-up at the start of the run (from step 0)
  linear_ramp rewarmup_;  // the second warm-up
  long from_ = 0, to_ = 0;  // cosine decay: first and last step of the decay
};

}  // namespace anisocap::nn
