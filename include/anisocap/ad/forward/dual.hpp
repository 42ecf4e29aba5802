#pragma once
/// @file
/// Forward-mode automatic differentiation: `dual<T, N>` carries a value and its N partial
/// derivatives. N is compile-time, so every operation is a fixed-length loop the compiler unrolls;
/// T may itself be a SIMD batch (`simd::batch<float>`), which makes one dual hold the derivatives of
/// 16 texels at once: SIMD over texels, unrolled over parameters.
#include <array>
#include <cstddef>
#include <type_traits>

#include "anisocap/core/simd.hpp"

namespace anisocap::ad {

/// A value of type T with its gradient with respect to N independent variables.
template <class T, std::size_t N>
struct dual {
  T value{};
  std::array<T, N> grad{};

  dual() = default;
  /// A constant (zero gradient).
  dual(const T& v) : value(v) { grad.fill(T(0)); }  // NOLINT: implicit on purpose, constants mix in
  /// The independent variable number `index` with value v (gradient e_index).
  static dual variable(const T& v, std::size_t index) {
    dual d(v);
    d.grad[index] = T(1);
    return d;
  }
  /// A value with an explicit gradient.
  static dual make(const T& v, const std::array<T, N>& g) {
    dual d;
    d.value = v;
    d.grad = g;
    return d;
  }

  dual& operator+=(const dual& o) { value += o.value; for (std::size_t i = 0; i < N; ++i) grad[i] += o.grad[i]; return *this; }
  dual& operator-=(const dual& o) { value -= o.value; for (std::size_t i = 0; i < N; ++i) grad[i] -= o.grad[i]; return *this; }
  dual& operator*=(const dual& o) { *this = *this * o; return *this; }
  dual& operator/=(const dual& o) { *this = *this / o; return *this; }
};

/// Builds a dual from a value and a per-variable derivative function (chain rule helper):
/// result = (f, df * a.grad).
template <class T, std::size_t N>
inline dual<T, N> chain(const dual<T, N>& a, const T& f, const T& df) {
  dual<T, N> r;
  r.value = f;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = df * a.grad[i];
  return r;
}

template <class T, std::size_t N>
inline dual<T, N> operator-(const dual<T, N>& a) {
  dual<T, N> r;
  r.value = -a.value;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = -a.grad[i];
  return r;
}
template <class T, std::size_t N>
inline dual<T, N> operator+(const dual<T, N>& a, const dual<T, N>& b) {
  dual<T, N> r;
  r.value = a.value + b.value;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = a.grad[i] + b.grad[i];
  return r;
}
template <class T, std::size_t N>
inline dual<T, N> operator-(const dual<T, N>& a, const dual<T, N>& b) {
  dual<T, N> r;
  r.value = a.value - b.value;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = a.grad[i] - b.grad[i];
  return r;
}
template <class T, std::size_t N>
inline dual<T, N> operator*(const dual<T, N>& a, const dual<T, N>& b) {
  dual<T, N> r;
  r.value = a.value * b.value;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = simd::fma(a.grad[i], b.value, a.value * b.grad[i]);
  return r;
}
template <class T, std::size_t N>
inline dual<T, N> operator/(const dual<T, N>& a, const dual<T, N>& b) {
  const T inv = T(1) / b.value;
  const T q = a.value * inv;
  dual<T, N> r;
  r.value = q;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = (a.grad[i] - q * b.grad[i]) * inv;
  return r;
}
// Mixed dual / plain-value arithmetic (the plain value is a constant).
template <class T, std::size_t N>
inline dual<T, N> operator+(const dual<T, N>& a, const std::type_identity_t<T>& b) { dual<T, N> r = a; r.value += b; return r; }
template <class T, std::size_t N>
inline dual<T, N> operator+(const std::type_identity_t<T>& a, const dual<T, N>& b) { return b + a; }
template <class T, std::size_t N>
inline dual<T, N> operator-(const dual<T, N>& a, const std::type_identity_t<T>& b) { dual<T, N> r = a; r.value -= b; return r; }
template <class T, std::size_t N>
inline dual<T, N> operator-(const std::type_identity_t<T>& a, const dual<T, N>& b) { return -b + a; }
template <class T, std::size_t N>
inline dual<T, N> operator*(const dual<T, N>& a, const std::type_identity_t<T>& b) {
  dual<T, N> r;
  r.value = a.value * b;
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = a.grad[i] * b;
  return r;
}
template <class T, std::size_t N>
inline dual<T, N> operator*(const std::type_identity_t<T>& a, const dual<T, N>& b) { return b * a; }
template <class T, std::size_t N>
inline dual<T, N> operator/(const dual<T, N>& a, const std::type_identity_t<T>& b) { return a * (T(1) / b); }
template <class T, std::size_t N>
inline dual<T, N> operator/(const std::type_identity_t<T>& a, const dual<T, N>& b) {
  const T inv = T(1) / b.value;
  const T q = a * inv;
  return chain(b, q, -q * inv);
}

/// exp, log, sqrt and friends of a dual, by the chain rule.
template <class T, std::size_t N>
inline dual<T, N> exp(const dual<T, N>& a) { const T e = simd::exp(a.value); return chain(a, e, e); }
template <class T, std::size_t N>
inline dual<T, N> log(const dual<T, N>& a) { return chain(a, simd::log(a.value), T(1) / a.value); }
template <class T, std::size_t N>
inline dual<T, N> sqrt(const dual<T, N>& a) { const T s = simd::sqrt(a.value); return chain(a, s, T(0.5) / s); }
template <class T, std::size_t N>
inline dual<T, N> sin(const dual<T, N>& a) { return chain(a, simd::sin(a.value), simd::cos(a.value)); }
template <class T, std::size_t N>
inline dual<T, N> cos(const dual<T, N>& a) { return chain(a, simd::cos(a.value), -simd::sin(a.value)); }
/// x^k for a small positive integer k (repeated multiplication, exact derivative k x^(k-1)).
template <int K, class T, std::size_t N>
inline dual<T, N> pow_int(const dual<T, N>& a) {
  static_assert(K >= 1);
  T below = T(1);  // x^(K-1)
  for (int i = 1; i < K; ++i) below = below * a.value;
  return chain(a, below * a.value, T(K) * below);
}
/// Lane-wise selection between two duals.
template <class M, class T, std::size_t N>
inline dual<T, N> select(const M& mask, const dual<T, N>& a, const dual<T, N>& b) {
  dual<T, N> r;
  r.value = simd::select(mask, a.value, b.value);
  for (std::size_t i = 0; i < N; ++i) r.grad[i] = simd::select(mask, a.grad[i], b.grad[i]);
  return r;
}
/// max(a, c) for a constant c (gradient zero where c wins).
template <class T, std::size_t N>
inline dual<T, N> max(const dual<T, N>& a, const std::type_identity_t<T>& c) { return select(a.value > c, a, dual<T, N>(c)); }
/// min(a, c) for a constant c (gradient zero where c wins).
template <class T, std::size_t N>
inline dual<T, N> min(const dual<T, N>& a, const std::type_identity_t<T>& c) { return select(a.value < c, a, dual<T, N>(c)); }

/// The value of a dual or of a plain number.
template <class T>
inline const T& value_of(const T& x) { return x; }
template <class T, std::size_t N>
inline const T& value_of(const dual<T, N>& x) { return x.value; }

}  // namespace anisocap::ad
