#pragma once
/// @file
/// The SIMD backend: the one place that names xsimd's architectures. Kernels elsewhere write
/// `simd::batch<float>` and stay portable; raw intrinsics belong here only (there are none yet).
#include <xsimd/xsimd.hpp>

namespace anisocap::simd {

/// The instruction set this translation unit was compiled for (-march decides: AVX-512, AVX2, ...).
using arch = xsimd::default_arch;

/// A SIMD register of T for the compiled architecture.
template <class T>
using batch = xsimd::batch<T, arch>;

/// Number of T lanes in one register.
template <class T>
inline constexpr std::size_t width = batch<T>::size;

/// Byte alignment every buffer of the library guarantees (a cache line, and enough for AVX-512).
inline constexpr std::size_t alignment = 64;

/// Name of the compiled instruction set, for benchmark reports.
inline const char* arch_name() { return arch::name(); }

}  // namespace anisocap::simd
