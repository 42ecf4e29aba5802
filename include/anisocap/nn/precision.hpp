#pragma once
/// @file
/// The arithmetic of the convolutions' multiply-adds: FP32 throughout, or bf16 operands with FP32
/// accumulation (AVX-512 BF16, twice the multiply-adds per instruction). One process-wide
/// switch: parameters (the FP32 master weights Adam updates), Adam's state, gradients, biases,
/// activations stored between layers and every accumulation stay FP32 either way; with bf16, each
/// pass of a convolution or transposed convolution (forward, input gradient, weight gradient)
/// rounds its two operands to bf16 as it reads them. Products of two bf16 values are exact in
/// FP32, so the only new error is the rounding of the operands (8 significant bits).
#include <atomic>
#include <stdexcept>
#include <string>
#include <string_view>

#include "anisocap/core/simd.hpp"

namespace anisocap::nn {

/// Operand precision of the convolutions (accumulation is FP32 in both).
enum class precision { fp32, bf16 };

/// "fp32" or "bf16".
inline const char* to_string(precision p) { return p == precision::bf16 ? "bf16" : "fp32"; }

/// The precision a name stands for; throws std::invalid_argument naming it otherwise, after
/// `field` (the option it was given for, e.g. "capture_options::network_precision") where one is given.
inline precision parse_precision(std::string_view name, std::string_view field = {}) {
  if (name == "fp32") return precision::fp32;
  if (name == "bf16") return precision::bf16;
  const std::string prefix = field.empty() ? std::string() : std::string(field) + ": ";
  throw std::invalid_argument(prefix + "unknown precision '" + std::string(name) + "' (expected fp32 or bf16)");
}

/// True when this build's convolutions can run in bf16: compiled for a CPU with AVX-512 BF16
/// (-march=native on Zen 4/5 or Sapphire Rapids and later).
inline constexpr bool bf16_available() { return simd::bf16_dot_available; }

namespace detail {
inline std::atomic<precision>& current_precision() {
  static std::atomic<precision> p{precision::fp32};
  return p;
}
}  // namespace detail

/// The precision the convolutions use now (fp32 unless set).
inline precision convolution_precision() { return detail::current_precision().load(std::memory_order_relaxed); }

/// Throws std::invalid_argument naming `setting` (an option or field) when p is bf16 and this build
/// lacks AVX-512 BF16.
inline void require_available(precision p, const std::string& setting) {
  if (p == precision::bf16 && !bf16_available())
    throw std::invalid_argument(setting + " bf16 needs a build for a CPU with AVX-512 BF16 (this one is built for " +
                                std::string(simd::arch_name()) + " without it); use fp32");
}

/// Sets the convolutions' precision for the whole process. Throws std::invalid_argument when bf16
/// is asked of a build without AVX-512 BF16.
inline void set_convolution_precision(precision p) {
  require_available(p, "precision");
  detail::current_precision().store(p, std::memory_order_relaxed);
}

/// Sets the precision while alive and restores the previous one on destruction.
class precision_scope {
 public:
  explicit precision_scope(precision p) : saved_(convolution_precision()) { set_convolution_precision(p); }
  ~precision_scope() { detail::current_precision().store(saved_, std::memory_order_relaxed); }
  precision_scope(const precision_scope&) = delete;
  precision_scope& operator=(const precision_scope&) = delete;

 private:
  precision saved_;
};

}  // namespace anisocap::nn
