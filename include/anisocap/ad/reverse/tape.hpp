#pragma once
/// @file
/// Reverse mode over whole-tensor operations (one record per layer op, not per scalar).
///
/// Forward code computes values eagerly and, when the tape is recording and an input or a
/// parameter needs a gradient, records a closure that pushes the output's gradient back.
/// `backward()` runs the closures in reverse order. Intermediate values and gradients live in the
/// tape's arena, reset by `clear()`, so a fixed-size step allocates nothing after the first.
#include <functional>  // kept for code that relied on it through this header
#include <memory>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

#include "anisocap/core/memory.hpp"
#include "anisocap/core/tensor.hpp"

namespace anisocap::ad {

/// A tensor value with its gradient. `grad` is allocated (zeroed) only when `requires_grad`.
template <int C, class T = float>
struct variable {
  tensor<C, T> value;
  tensor<C, T> grad;
  bool requires_grad = false;
};

/// The tape: recorded backward closures plus the arena that holds a step's tensors.
class tape {
 public:
  explicit tape(std::size_t initial_arena_bytes = 0) : arena_(initial_arena_bytes) {}
  ~tape() { destroy_steps(); }
  tape(const tape&) = delete;
  tape& operator=(const tape&) = delete;

  /// True when operations should record their backward pass.
  bool recording() const noexcept { return recording_; }

  /// Records a backward closure (ignored in no-grad mode). The closure is moved into the tape's
  /// arena, not the heap, so a fixed-size step allocates nothing once the arena and the step list
  /// have grown to size (a std::function would heap-allocate its captured tensors).
  template <class F>
  void record(F&& backward_step) {
    if (!recording_) return;
    using closure = std::decay_t<F>;
    static_assert(alignof(closure) <= simd::alignment, "closure alignment exceeds the arena's");
    void* memory = arena_.allocate(sizeof(closure));
    closure* c = ::new (memory) closure(std::forward<F>(backward_step));
    try {
      steps_.push_back(step{c, [](void* p) { (*static_cast<closure*>(p))(); },
                            [](void* p) noexcept { static_cast<closure*>(p)->~closure(); }});
    } catch (...) {
      c->~closure();
      throw;
    }
  }

  /// Runs every recorded closure in reverse order, then forgets them. Gradients stay in the arena
  /// until clear().
  void backward() {
    for (auto it = steps_.rbegin(); it != steps_.rend(); ++it) it->run(it->closure);
    destroy_steps();
  }

  /// Forgets recorded steps and releases the arena for reuse (keeps its memory).
  void clear() {
    destroy_steps();
    arena_.reset();
  }

  /// Number of recorded steps.
  std::size_t size() const noexcept { return steps_.size(); }

  /// Memory for a step's activations and gradients.
  anisocap::arena& memory() noexcept { return arena_; }
  /// The arena, read-only (its sizes).
  const anisocap::arena& memory() const noexcept { return arena_; }

  /// A new tensor in the tape's arena (uninitialised).
  template <int C, class T = float>
  tensor<C, T> make_tensor(int batch, int height, int width) { return tensor<C, T>(arena_, batch, height, width); }

  /// How make_variable leaves a new gradient: zeroed, or uninitialised for a caller that zeroes it
  /// itself before anyone else sees the variable (a layer does it in its own parallel pass over
  /// the output, instead of a zeroing pass on one thread here).
  enum class gradient_init { zeroed, by_caller };

  /// A new variable in the arena; its gradient is allocated when requires_grad (and recording),
  /// and zeroed unless `init` is gradient_init::by_caller.
  template <int C, class T = float>
  variable<C, T> make_variable(int batch, int height, int width, bool requires_grad, gradient_init init = gradient_init::zeroed) {
    variable<C, T> v{make_tensor<C, T>(batch, height, width), {}, requires_grad && recording_};
    if (v.requires_grad) {
      v.grad = make_tensor<C, T>(batch, height, width);
      if (init == gradient_init::zeroed) v.grad.fill(T(0));
    }
    return v;
  }

  /// Wraps an existing tensor as a leaf variable.
  template <int C, class T = float>
  variable<C, T> leaf(tensor<C, T> value, bool requires_grad = false) {
    variable<C, T> v{value, {}, requires_grad && recording_};
    if (v.requires_grad) {
      v.grad = make_tensor<C, T>(value.batch(), value.height(), value.width());
      v.grad.fill(T(0));
    }
    return v;
  }

  /// Scope in which nothing is recorded (inference).
  class no_grad_guard {
   public:
    explicit no_grad_guard(tape& t) : t_(t), previous_(t.recording_) { t_.recording_ = false; }
    ~no_grad_guard() { t_.recording_ = previous_; }
    no_grad_guard(const no_grad_guard&) = delete;
    no_grad_guard& operator=(const no_grad_guard&) = delete;

   private:
    tape& t_;
    bool previous_;
  };

 private:
  /// A type-erased closure living in the arena.
  struct step {
    void* closure;
    void (*run)(void*);
    void (*destroy)(void*) noexcept;
  };
  void destroy_steps() noexcept {
    for (auto& s : steps_) s.destroy(s.closure);
    steps_.clear();  // keeps the capacity: later steps push without allocating
  }

  std::vector<step> steps_;
  anisocap::arena arena_;
  bool recording_ = true;
};

/// A tape an object keeps across calls (an inference tape, a per-window scratch), so that each
/// call after the first reuses the arena's memory instead of asking the system for new pages and
/// faulting them in. A copy starts with no tape of its own: copies never share one (two copies may
/// run at once), and copying a network does not copy its scratch memory. The tape is made on first
/// use; release() hands its memory back.
class retained_tape {
 public:
  retained_tape() = default;
  retained_tape(const retained_tape&) noexcept {}
  retained_tape& operator=(const retained_tape&) noexcept { return *this; }
  retained_tape(retained_tape&&) noexcept = default;
  retained_tape& operator=(retained_tape&&) noexcept = default;

  /// The kept tape, cleared (nothing recorded, arena reset, memory kept), recording on.
  tape& fresh() {
    if (!tape_) tape_ = std::make_unique<tape>();
    tape_->clear();
    return *tape_;
  }
  /// Bytes the kept tape holds from the system (0 before first use and after release()).
  std::size_t capacity_bytes() const noexcept { return tape_ ? tape_->memory().capacity_bytes() : 0; }
  /// Frees the kept tape and its memory.
  void release() noexcept { tape_.reset(); }

 private:
  std::unique_ptr<tape> tape_;
};

}  // namespace anisocap::ad
