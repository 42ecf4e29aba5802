#pragma once
/// @file
/// The gradient of one optimiser step computed in parts (the materials of a data-parallel
/// training batch, the shards of a fine-tune step), the parts spread over the ranks of a
/// communicator and added in ordered_sum's fixed tree, so that any rank count gives the same bits.
#include <algorithm>
#include <cstddef>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "anisocap/core/distributed.hpp"
#include "anisocap/nn/parameter.hpp"

namespace anisocap::nn {

/// The trainable parameters among those `for_each` visits (a network's for_each_parameter, or an
/// auto-encoder's for_each_decoder_parameter), in its order.
template <class ForEach>
std::vector<parameter*> trainable_parameters(ForEach&& for_each) {
  std::vector<parameter*> out;
  for_each([&](parameter& p) {
    if (p.trainable()) out.push_back(&p);
  });
  return out;
}

/// Per-part gradients and losses of one step. Each step: start(parts) deals this rank its parts
/// [first(), last()) (part_range); for each of them the caller computes the part's gradient into
/// the parameters' gradients, take(k) moves it into part k, and loss(k) holds its loss; sum(), on
/// every rank, adds all parts over the ranks; apply() writes the summed gradient into the
/// parameters. `Loss` is a double or a struct of doubles (the training's loss_terms), summed
/// field by field.
template <class Loss>
class part_gradients {
 public:
  part_gradients(std::vector<parameter*> trained, const communicator& comm) : comm_(comm), trained_(std::move(trained)) {
    for (const parameter* p : trained_) size_ += p->size();
  }
  /// Starts a step of `parts` parts: this rank's parts and losses at zero.
  void start(int parts) {
    parts_ = parts;
    const auto range = part_range(parts, comm_.size(), comm_.rank());
    first_ = range.first;
    last_ = range.second;
    gradients_.assign(std::size_t(last_ - first_) * size_, 0.0f);
    losses_.assign(std::size_t(last_ - first_), Loss{});
  }
  /// This rank's parts: [first(), last()).
  int first() const noexcept { return first_; }
  int last() const noexcept { return last_; }
  /// Adds the parameters' gradients to part k's (a part this rank holds) and zeroes them.
  void take(int k) {
    float* out = gradients_.data() + std::size_t(check(k)) * size_;
    for (parameter* p : trained_) {
      for (std::size_t i = 0; i < p->size(); ++i) out[i] += p->grad[i];
      std::fill(p->grad.begin(), p->grad.end(), 0.0f);
      out += p->size();
    }
  }
  /// Part k's loss (a part this rank holds).
  Loss& loss(int k) { return losses_[std::size_t(check(k))]; }
  /// Every rank: adds every part's gradient (kept for apply()) and loss over the ranks, in
  /// ordered_sum's tree. Returns the summed loss.
  Loss sum() {
    sum_.resize(size_);
    ordered_sum<float>(comm_, parts_, size_, gradients_, sum_);
    Loss total{};
    ordered_sum<double>(comm_, parts_, loss_values, std::span<const double>(reinterpret_cast<const double*>(losses_.data()), losses_.size() * loss_values),
                        std::span<double>(reinterpret_cast<double*>(&total), loss_values));
    return total;
  }
  /// Writes the last sum()'s gradient into the parameters' gradients.
  void apply() const {
    const float* in = sum_.data();
    for (parameter* p : trained_) {
      std::copy(in, in + p->size(), p->grad.begin());
      in += p->size();
    }
  }

 private:
  static constexpr std::size_t loss_values = sizeof(Loss) / sizeof(double);
  static_assert(sizeof(Loss) == loss_values * sizeof(double) && loss_values > 0, "a loss holds doubles only");
  int check(int k) const {
    if (k < first_ || k >= last_) throw std::logic_error("part_gradients: part " + std::to_string(k) + " is not this rank's");
    return k - first_;
  }
  const communicator& comm_;
  std::vector<parameter*> trained_;
  std::size_t size_ = 0;
  int parts_ = 0, first_ = 0, last_ = 0;
  std::vector<float> gradients_, sum_;
  std::vector<Loss> losses_;
};

}  // namespace anisocap::nn
