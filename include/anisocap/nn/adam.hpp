#pragma once
/// @file
/// Adam (Kingma and Ba 2015) with a learning-rate schedule: the optimiser of every training and
/// fine-tuning stage (MODEL.md 7 and 8: estimator 5e-5, auto-encoder 1e-3, fine-tuning 7.5e-4,
/// refinement 1e-4). The update is PyTorch's torch.optim.Adam (bias corrections folded into the
/// step size and epsilon added after the corrected square root), so settings carry over.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <vector>

#include "anisocap/core/memory.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/nn/parameter.hpp"

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

/// Adam over a set of parameters. State (first and second moments, step count) is kept per
/// parameter and allocated when the parameter is added, so `step()` allocates nothing. Frozen
/// parameters are skipped entirely: their values, moments and step counts stay as they are.
template <class T = float>
class basic_adam {
 public:
  double beta1 = 0.9;    ///< decay of the first-moment average
  double beta2 = 0.999;  ///< decay of the second-moment average
  double epsilon = 1e-8;  ///< added to the corrected root of the second moment
  learning_rate_schedule schedule;  ///< learning rate per step

  explicit basic_adam(learning_rate_schedule s = learning_rate_schedule::constant(1e-3), double b1 = 0.9,
                      double b2 = 0.999, double eps = 1e-8)
      : beta1(b1), beta2(b2), epsilon(eps), schedule(s) {}

  /// Adds one parameter (it must outlive the optimiser).
  void add(basic_parameter<T>& p) { states_.push_back(state{&p, aligned_buffer<T>(p.size()), aligned_buffer<T>(p.size()), 0}); }

  /// Adds every parameter a layer or network visits with for_each_parameter.
  template <class Layer>
  void add_parameters(Layer& layer) {
    layer.for_each_parameter([this](basic_parameter<T>& p) { add(p); });
  }

  /// One update of every parameter that is not frozen, with the schedule's rate for this step;
  /// then zeroes their gradients (backward passes accumulate).
  ///
  /// Every parameter is cut into chunks of `chunk_size` elements and all chunks of all parameters
  /// share one parallel loop: a network's many small parameters (biases, norms, deep layers below
  /// the size worth a parallel region of their own) then run beside the large ones instead of one
  /// after another on one thread. Chunk boundaries fall on whole registers, so each element gets
  /// exactly the arithmetic it gets in a serial pass.
  void step() {
    const double rate = schedule(steps_);
    chunks_.clear();
    std::size_t total = 0;
    for (std::size_t k = 0; k < states_.size(); ++k) {
      state& s = states_[k];
      if (s.parameter->frozen) continue;
      if (s.parameter->size() != s.m.size())
        throw std::logic_error("adam: parameter '" + s.parameter->name + "' changed size after it was added");
      ++s.steps;
      const double correction1 = 1 - std::pow(beta1, double(s.steps));
      const double correction2 = 1 - std::pow(beta2, double(s.steps));
      s.step_size = T(rate / correction1);
      s.inverse_root_correction2 = T(1 / std::sqrt(correction2));
      const std::size_t n = s.parameter->size();
      for (std::size_t b = 0; b < n; b += chunk_size) chunks_.push_back({k, b, std::min(n, b + chunk_size)});
      total += n;
    }
#pragma omp parallel for schedule(dynamic, 1) if (total >= (std::size_t(1) << 16) && chunks_.size() > 1)
    for (std::ptrdiff_t c = 0; c < std::ptrdiff_t(chunks_.size()); ++c) {
      const chunk& ch = chunks_[std::size_t(c)];
      state& s = states_[ch.state];
      update(*s.parameter, s.m.data(), s.v.data(), s.step_size, s.inverse_root_correction2, ch.begin, ch.end);
      std::fill(s.parameter->grad.begin() + std::ptrdiff_t(ch.begin), s.parameter->grad.begin() + std::ptrdiff_t(ch.end), T(0));
    }
    ++steps_;
  }

  /// Elements per work item of step() (a multiple of every register width).
  static constexpr std::size_t chunk_size = 16384;

  /// Zeroes the gradients of every added parameter.
  void zero_grad() {
    for (auto& s : states_) s.parameter->zero_grad();
  }

  /// Number of step() calls so far.
  long steps() const noexcept { return steps_; }
  /// Sets the step counter (restoring a checkpoint; the schedule reads it).
  void set_steps(long n) noexcept { steps_ = n; }
  /// Visits each added parameter's state f(parameter, m, v, steps) (first and second moments and
  /// the parameter's own update count), so a checkpoint can save and restore it exactly.
  template <class F>
  void for_each_state(F&& f) {
    for (auto& s : states_) f(*s.parameter, s.m, s.v, s.steps);
  }
  /// The learning rate the next step will use.
  double learning_rate() const { return schedule(steps_); }

  /// A copy of every added parameter's values and of the optimiser's state (moments, update
  /// counts, step counter); restore() goes back to it exactly. The schedule is not part of it.
  struct snapshot {
    std::vector<std::vector<T>> buffers;  ///< per parameter: values, first and second moments
    std::vector<long> counts;             ///< per parameter: update count
    long steps = 0;                       ///< the step counter
    bool empty() const noexcept { return buffers.empty(); }
  };
  snapshot take_snapshot() const {
    snapshot s;
    for (const auto& st : states_) {
      for (const aligned_buffer<T>* b : {static_cast<const aligned_buffer<T>*>(&st.parameter->value), &st.m, &st.v})
        s.buffers.emplace_back(b->begin(), b->end());
      s.counts.push_back(st.steps);
    }
    s.steps = steps_;
    return s;
  }
  /// Puts back a snapshot taken from this optimiser (same parameters).
  void restore(const snapshot& s) {
    if (s.counts.size() != states_.size()) throw std::invalid_argument("basic_adam::restore: the snapshot is of other parameters");
    std::size_t i = 0;
    for (std::size_t k = 0; k < states_.size(); ++k) {
      for (auto* b : {&states_[k].parameter->value, &states_[k].m, &states_[k].v}) {
        if (s.buffers[i].size() != b->size()) throw std::invalid_argument("basic_adam::restore: the snapshot is of other parameters");
        std::copy(s.buffers[i].begin(), s.buffers[i].end(), b->begin());
        ++i;
      }
      states_[k].steps = s.counts[k];
    }
    steps_ = s.steps;
  }

 private:
  struct state {
    basic_parameter<T>* parameter;
    aligned_buffer<T> m, v;
    long steps;
    T step_size = 0, inverse_root_correction2 = 0;  ///< this step's factors (set by step())
  };
  /// Elements [begin, end) of the parameter state `state`: one work item of step().
  struct chunk {
    std::size_t state, begin, end;
  };

  /// m = b1 m + (1 - b1) g;  v = b2 v + (1 - b2) g^2;  p -= step_size m / (sqrt(v) / sqrt(1 - b2^t) + eps).
  /// Updates elements [begin, end) of p; begin is a multiple of the register width.
  void update(basic_parameter<T>& p, T* m, T* v, T step_size, T inverse_root_correction2, std::size_t begin,
              std::size_t end) const {
    using B = simd::batch<T>;
    constexpr std::size_t W = B::size;
    const T b1 = T(beta1), b2 = T(beta2), c1 = T(1 - beta1), c2 = T(1 - beta2), eps = T(epsilon);
    auto kernel = [&](T* value, const T* grad, T* mm, T* vv) {
      const B g = B::load_unaligned(grad);
      const B m1 = b1 * B::load_unaligned(mm) + c1 * g;
      const B v1 = b2 * B::load_unaligned(vv) + c2 * (g * g);
      m1.store_unaligned(mm);
      v1.store_unaligned(vv);
      (B::load_unaligned(value) - step_size * m1 / (xsimd::sqrt(v1) * inverse_root_correction2 + eps)).store_unaligned(value);
    };
    const std::size_t n = end;
    const std::size_t body = begin + (end - begin) / W * W;
    T* value = p.value.data();
    const T* grad = p.grad.data();
    for (std::size_t i = begin; i < body; i += W) kernel(value + i, grad + i, m + i, v + i);
    if (body < n) {
      // The tail through padded registers: the same arithmetic as the body.
      alignas(simd::alignment) T pv[W] = {}, pg[W] = {}, pm[W] = {}, pw[W] = {};
      const std::size_t r = n - body;
      for (std::size_t i = 0; i < r; ++i) { pv[i] = value[body + i]; pg[i] = grad[body + i]; pm[i] = m[body + i]; pw[i] = v[body + i]; }
      kernel(pv, pg, pm, pw);
      for (std::size_t i = 0; i < r; ++i) { value[body + i] = pv[i]; m[body + i] = pm[i]; v[body + i] = pw[i]; }
    }
  }

  std::vector<state> states_;
  std::vector<chunk> chunks_;  // step()'s work items, kept to reuse the allocation
  long steps_ = 0;
};

/// Adam for float networks.
using adam = basic_adam<float>;

}  // namespace anisocap::nn
