#pragma once
/// @file
/// Adam (Kingma and Ba 2015) with a learning-rate schedule: the optimiser of every training and
/// fine-tuning stage (the paper's section 5: estimator 5e-5, auto-encoder 1e-3, fine-tuning 7.5e-4,
/// refinement 1e-4) and of the per-texel refine (pipeline/refine.hpp, through `adam_update`). The update is PyTorch's torch.optim.Adam (bias corrections folded into the
/// step size and epsilon added after the corrected square root), so settings carry over.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <string>
#include <stdexcept>
#include <vector>

#include "anisocap/core/memory.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/nn/parameter.hpp"
#include "anisocap/nn/safetensors.hpp"
#include "anisocap/nn/schedule.hpp"

namespace anisocap::nn {

/// The constants of one Adam update at step t (counted from 1) with learning rate `rate`.
template <class T>
struct adam_coefficients {
  T beta1, beta2, one_minus_beta1, one_minus_beta2, epsilon;
  T step_size;                 ///< rate / (1 - beta1^t)
  T inverse_root_correction2;  ///< 1 / sqrt(1 - beta2^t)
  adam_coefficients(double b1, double b2, double eps, double rate, long t)
      : beta1(T(b1)), beta2(T(b2)), one_minus_beta1(T(1 - b1)), one_minus_beta2(T(1 - b2)), epsilon(T(eps)),
        step_size(T(rate / (1 - std::pow(b1, double(t))))), inverse_root_correction2(T(1 / std::sqrt(1 - std::pow(b2, double(t))))) {}
};

/// The Adam update of one register of values (Kingma and Ba 2015, Algorithm 1, in PyTorch's form):
/// m = b1 m + (1 - b1) g;  v = b2 v + (1 - b2) g^2;  p -= step_size m / (sqrt(v) / sqrt(1 - b2^t) + eps).
/// The one kernel behind basic_adam and the per-texel refine.
template <class B, class T>
inline void adam_update(T* value, const B& g, T* m, T* v, const adam_coefficients<T>& c) {
  const B m1 = B(c.beta1) * B::load_unaligned(m) + B(c.one_minus_beta1) * g;
  const B v1 = B(c.beta2) * B::load_unaligned(v) + B(c.one_minus_beta2) * (g * g);
  m1.store_unaligned(m);
  v1.store_unaligned(v);
  (B::load_unaligned(value) - B(c.step_size) * m1 / (xsimd::sqrt(v1) * B(c.inverse_root_correction2) + B(c.epsilon)))
      .store_unaligned(value);
}

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
    coefficients_.clear();
    std::size_t total = 0;
    for (std::size_t k = 0; k < states_.size(); ++k) {
      state& s = states_[k];
      if (s.parameter->frozen) continue;
      if (s.parameter->size() != s.m.size())
        throw std::logic_error("adam: parameter '" + s.parameter->name + "' changed size after it was added");
      ++s.steps;
      coefficients_.emplace_back(beta1, beta2, epsilon, rate, s.steps);
      const std::size_t n = s.parameter->size();
      for (std::size_t b = 0; b < n; b += chunk_size)
        chunks_.push_back({k, coefficients_.size() - 1, b, std::min(n, b + chunk_size)});
      total += n;
    }
#pragma omp parallel for schedule(dynamic, 1) if (total >= (std::size_t(1) << 16) && chunks_.size() > 1)
    for (std::ptrdiff_t c = 0; c < std::ptrdiff_t(chunks_.size()); ++c) {
      const chunk& ch = chunks_[std::size_t(c)];
      state& s = states_[ch.state];
      update(*s.parameter, s.m.data(), s.v.data(), coefficients_[ch.coefficients], ch.begin, ch.end);
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
  /// Adds the optimiser's state to a check-point: per parameter "adam.m.<name>", "adam.v.<name>"
  /// (moments) and "adam.steps.<name>" (update count), and the step counter as metadata
  /// "adam.steps". The one key scheme of every check-point (training and fine-tune). The file
  /// borrows the moments (safetensors_file::add_view): write it before the next step.
  void save_state(safetensors_file& file) {
    for (auto& s : states_) {
      const std::int64_t count = s.steps;
      file.template add_view<T>("adam.m." + s.parameter->name, {std::int64_t(s.m.size())}, s.m.data(), s.m.size());
      file.template add_view<T>("adam.v." + s.parameter->name, {std::int64_t(s.v.size())}, s.v.data(), s.v.size());
      file.template add<std::int64_t>("adam.steps." + s.parameter->name, {1}, &count, 1);
    }
    file.metadata.emplace_back("adam.steps", std::to_string(steps_));
  }
  /// Restores what save_state wrote; throws std::runtime_error naming `name` (the file) when a
  /// parameter's state is missing or has the wrong size.
  void load_state(const safetensors_file& file, const std::string& name) {
    for (auto& s : states_) {
      const auto* em = file.find("adam.m." + s.parameter->name);
      const auto* ev = file.find("adam.v." + s.parameter->name);
      const auto* es = file.find("adam.steps." + s.parameter->name);
      if (!em || !ev || !es || em->count() != s.m.size() || ev->count() != s.v.size())
        throw std::runtime_error(name + ": optimiser state of '" + s.parameter->name + "' is missing or has the wrong size");
      std::memcpy(static_cast<void*>(s.m.data()), file.bytes(*em).data(), s.m.size() * sizeof(T));
      std::memcpy(static_cast<void*>(s.v.data()), file.bytes(*ev).data(), s.v.size() * sizeof(T));
      std::int64_t count;
      std::memcpy(&count, file.bytes(*es).data(), sizeof count);
      s.steps = long(count);
    }
    for (const auto& [key, value] : file.metadata)
      if (key == "adam.steps") steps_ = std::stol(value);
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
    take_snapshot(s);
    return s;
  }
  /// Takes a snapshot into `s`, reusing its buffers: one taken every few steps (the fine-tune's
  /// divergence guard) allocates nothing after the first, so it costs a copy and no page faults.
  void take_snapshot(snapshot& s) const {
    s.buffers.resize(3 * states_.size());
    s.counts.clear();
    std::size_t i = 0;
    for (const auto& st : states_) {
      for (const aligned_buffer<T>* b : {static_cast<const aligned_buffer<T>*>(&st.parameter->value), &st.m, &st.v})
        s.buffers[i++].assign(b->begin(), b->end());
      s.counts.push_back(st.steps);
    }
    s.steps = steps_;
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
  };

  /// Elements [begin, end) of the parameter state `state` with the coefficients
  /// `coefficients_[coefficients]`: one work item of step().
  struct chunk {
    std::size_t state, coefficients, begin, end;
  };

  /// adam_update over elements [begin, end) of the parameter (begin a multiple of the register
  /// width), the tail through padded registers.
  void update(basic_parameter<T>& p, T* m, T* v, const adam_coefficients<T>& c, std::size_t begin,
              std::size_t end) const {
    using B = simd::batch<T>;
    constexpr std::size_t W = B::size;
    auto kernel = [&](T* value, const T* grad, T* mm, T* vv) { adam_update(value, B::load_unaligned(grad), mm, vv, c); };
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
  std::vector<chunk> chunks_;                         // step()'s work items, kept to reuse the allocation
  std::vector<adam_coefficients<T>> coefficients_;  // step()'s per-parameter constants, likewise
  long steps_ = 0;
};

/// Adam for float networks.
using adam = basic_adam<float>;

}  // namespace anisocap::nn
