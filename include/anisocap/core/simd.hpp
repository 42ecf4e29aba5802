#pragma once
/// @file
/// The SIMD backend: the one place that names xsimd's architectures. Kernels elsewhere write
/// `simd::batch<float>` and stay portable; raw intrinsics belong here only (the
/// reciprocal estimates below).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include <xsimd/xsimd.hpp>
#if defined(__SSE__) || defined(__x86_64__)
#include <immintrin.h>
#endif

/// Forces a kernel helper inline where the compiler's size heuristics would not: a helper that
/// returns a struct of many registers otherwise passes it through memory in the hottest loop.
#if defined(__GNUC__) || defined(__clang__)
#define ANISOCAP_ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define ANISOCAP_ALWAYS_INLINE inline
#endif

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

/// While alive, the calling thread flushes denormal results to zero and reads denormal inputs as
/// zero (x86 MXCSR FTZ and DAZ); restores the previous mode on destruction. Lobes far from their
/// peak produce denormals, which cost extra cycles on most CPUs. Each OpenMP thread has its own
/// mode, so kernels create one inside their parallel region. No effect when `enable` is false or
/// on other architectures.
class flush_denormals_scope {
 public:
  explicit flush_denormals_scope(bool enable = true) {
#if defined(__SSE__) || defined(__x86_64__)
    saved_ = _mm_getcsr();
    if (enable) _mm_setcsr(saved_ | 0x8040u);  // FTZ (bit 15) | DAZ (bit 6)
#else
    (void)enable;
#endif
  }
  ~flush_denormals_scope() {
#if defined(__SSE__) || defined(__x86_64__)
    _mm_setcsr(saved_);
#endif
  }
  flush_denormals_scope(const flush_denormals_scope&) = delete;
  flush_denormals_scope& operator=(const flush_denormals_scope&) = delete;

 private:
  unsigned saved_ = 0;
};

// ---- one vocabulary for scalar and SIMD values ---------------------------------------------------
// Kernels are templates on a value type V that is either a plain float/double (the scalar build,
// also used in double for gradient checks) or an xsimd batch. These overloads give both the same
// spelling, so one template compiles to both paths.

/// Number of lanes of V (1 for scalars).
template <class V>
struct lanes : std::integral_constant<std::size_t, 1> {};
template <class T, class A>
struct lanes<xsimd::batch<T, A>> : std::integral_constant<std::size_t, xsimd::batch<T, A>::size> {};
template <class V>
inline constexpr std::size_t lanes_v = lanes<V>::value;

/// Scalar element type of V.
template <class V>
struct scalar_of { using type = V; };
template <class T, class A>
struct scalar_of<xsimd::batch<T, A>> { using type = T; };
template <class V>
using scalar_t = typename scalar_of<V>::type;

/// Loads lanes_v<V> consecutive values (aligned for batches). U may differ from V's element type
/// (floats into a double batch): the values are converted, and no alignment is needed then.
template <class V, class U>
inline V load(const U* p) {
  if constexpr (lanes_v<V> == 1) return V(*p);
  else if constexpr (std::is_same_v<U, scalar_t<V>>) return V::load_aligned(p);
  else return V::load_unaligned(p);
}
/// Loads lanes_v<V> consecutive values without an alignment requirement.
template <class V>
inline V load_unaligned(const scalar_t<V>* p) {
  if constexpr (lanes_v<V> == 1) return *p;
  else return V::load_unaligned(p);
}
/// The first n values at p (0 < n <= lanes) in the first lanes, zeros in the rest; reads nothing past
/// p + n (a masked load on AVX-512, a copy through the stack elsewhere).
template <class V>
inline V load_first(const scalar_t<V>* p, int n) {
  using T = scalar_t<V>;
  if constexpr (lanes_v<V> == 1) return *p;
#if defined(__AVX512F__)
  else if constexpr (std::is_same_v<T, float> && lanes_v<V> == 16) return V(_mm512_maskz_loadu_ps(__mmask16((1u << n) - 1), p));
  else if constexpr (std::is_same_v<T, double> && lanes_v<V> == 8) return V(_mm512_maskz_loadu_pd(__mmask8((1u << n) - 1), p));
#endif
  else {
    alignas(alignment) T v[lanes_v<V>] = {};
    for (int i = 0; i < n; ++i) v[i] = p[i];
    return V::load_aligned(v);
  }
}
/// True when load_first and store_first on V are single masked instructions (AVX-512 float and
/// double batches), not copies through the stack.
template <class V>
inline constexpr bool masked_first_v =
#if defined(__AVX512F__)
    lanes_v<V> == 64 / sizeof(scalar_t<V>) && (std::is_same_v<scalar_t<V>, float> || std::is_same_v<scalar_t<V>, double>);
#else
    false;
#endif
/// Stores the first n values of v at p (0 < n <= lanes); writes nothing past p + n (a masked store
/// on AVX-512, value by value elsewhere).
template <class V>
inline void store_first(scalar_t<V>* p, const V& v, int n) {
  using T = scalar_t<V>;
  if constexpr (lanes_v<V> == 1) *p = v;
#if defined(__AVX512F__)
  else if constexpr (std::is_same_v<T, float> && lanes_v<V> == 16) _mm512_mask_storeu_ps(p, __mmask16((1u << n) - 1), v);
  else if constexpr (std::is_same_v<T, double> && lanes_v<V> == 8) _mm512_mask_storeu_pd(p, __mmask8((1u << n) - 1), v);
#endif
  else {
    alignas(alignment) T b[lanes_v<V>];
    v.store_aligned(b);
    for (int i = 0; i < n; ++i) p[i] = b[i];
  }
}
/// Stores lanes_v<V> consecutive values (aligned for batches). U may differ from V's element type
/// (a double batch into floats): the values are converted (rounded), no alignment needed then.
template <class V, class U>
inline void store(U* p, const V& v) {
  if constexpr (lanes_v<V> == 1) *p = U(v);
  else if constexpr (std::is_same_v<U, scalar_t<V>>) v.store_aligned(p);
  else v.store_unaligned(p);
}
/// Lane i holds first + i.
template <class V>
inline V iota(scalar_t<V> first) {
  if constexpr (lanes_v<V> == 1) return first;
  else {
    alignas(alignment) scalar_t<V> v[lanes_v<V>];
    for (std::size_t i = 0; i < lanes_v<V>; ++i) v[i] = first + scalar_t<V>(i);
    return V::load_aligned(v);
  }
}
/// Sum of all lanes.
template <class V>
inline scalar_t<V> reduce_add(const V& v) {
  if constexpr (lanes_v<V> == 1) return v;
  else return xsimd::hadd(v);
}
/// True when any lane of a mask is set.
inline bool any(bool b) { return b; }
template <class T, class A>
inline bool any(const xsimd::batch_bool<T, A>& b) { return xsimd::any(b); }
/// True when every lane of a mask is set.
inline bool all(bool b) { return b; }
template <class T, class A>
inline bool all(const xsimd::batch_bool<T, A>& b) { return xsimd::all(b); }

/// Lane-wise c ? a : b.
template <class T>
inline T select(bool c, const T& a, const T& b) { return c ? a : b; }
template <class T, class A>
inline xsimd::batch<T, A> select(const xsimd::batch_bool<T, A>& c, const xsimd::batch<T, A>& a,
                                 const xsimd::batch<T, A>& b) {
  return xsimd::select(c, a, b);
}

#define ANISOCAP_SIMD_UNARY(name, expr_scalar, expr_batch)                              \
  inline float name(float x) { return expr_scalar; }                                    \
  inline double name(double x) { return expr_scalar; }                                  \
  template <class T, class A>                                                           \
  inline xsimd::batch<T, A> name(const xsimd::batch<T, A>& x) { return expr_batch; }
ANISOCAP_SIMD_UNARY(exp, std::exp(x), xsimd::exp(x))
ANISOCAP_SIMD_UNARY(log, std::log(x), xsimd::log(x))
ANISOCAP_SIMD_UNARY(sqrt, std::sqrt(x), xsimd::sqrt(x))
ANISOCAP_SIMD_UNARY(abs, std::abs(x), xsimd::abs(x))
ANISOCAP_SIMD_UNARY(sin, std::sin(x), xsimd::sin(x))
ANISOCAP_SIMD_UNARY(cos, std::cos(x), xsimd::cos(x))
#undef ANISOCAP_SIMD_UNARY

inline float min(float a, float b) { return a < b ? a : b; }
inline double min(double a, double b) { return a < b ? a : b; }
inline float max(float a, float b) { return a > b ? a : b; }
inline double max(double a, double b) { return a > b ? a : b; }
template <class T, class A>
inline xsimd::batch<T, A> min(const xsimd::batch<T, A>& a, const xsimd::batch<T, A>& b) { return xsimd::min(a, b); }
template <class T, class A>
inline xsimd::batch<T, A> max(const xsimd::batch<T, A>& a, const xsimd::batch<T, A>& b) { return xsimd::max(a, b); }
/// Double batches: the same operation as MINPD / MAXPD (a < b ? a : b, a > b ? a : b, the second
/// operand where either is NaN) written as a compare and a blend, since GCC 12's AVX-512
/// _mm512_min_pd / _mm512_max_pd fill an unused operand from _mm512_undefined_pd(), whose
/// self-initialisation GCC 12 then reports as -Wuninitialized wherever the double kernels inline it.
template <class A>
inline xsimd::batch<double, A> min(const xsimd::batch<double, A>& a, const xsimd::batch<double, A>& b) { return xsimd::select(a < b, a, b); }
template <class A>
inline xsimd::batch<double, A> max(const xsimd::batch<double, A>& a, const xsimd::batch<double, A>& b) { return xsimd::select(a > b, a, b); }
/// Double batches on AVX-512: the square root through the zero-masked intrinsic with every lane
/// selected (the same values as _mm512_sqrt_pd, which GCC 12 builds on _mm512_undefined_pd(), see
/// min/max above).
template <class A>
inline xsimd::batch<double, A> sqrt(const xsimd::batch<double, A>& x) {
#if defined(__AVX512F__)
  if constexpr (xsimd::batch<double, A>::size == 8) return xsimd::batch<double, A>(_mm512_maskz_sqrt_pd(__mmask8(0xFF), x));
  else
#endif
    return xsimd::sqrt(x);
}
/// 1 / sqrt(x) for x > 0. Float batches: the hardware estimate (AVX-512 rsqrt14, AVX rsqrt: 14 or
/// 12 bits) refined by one Newton step, within about 2 ulp of the correctly rounded value and a
/// few times cheaper than a square root and a division. Scalars and doubles: 1 / sqrt(x).
inline float inverse_sqrt(float x) { return 1.0f / std::sqrt(x); }
inline double inverse_sqrt(double x) { return 1.0 / std::sqrt(x); }
template <class T, class A>
inline xsimd::batch<T, A> inverse_sqrt(const xsimd::batch<T, A>& x) {
  using B = xsimd::batch<T, A>;
  if constexpr (std::is_same_v<T, float> && std::is_base_of_v<xsimd::avx512f, A>) {
    // The zero-masked form: the plain intrinsic trips GCC 12's -Wuninitialized on its undefined source.
    const B y(_mm512_maskz_rsqrt14_ps(__mmask16(0xFFFF), x));
    return y * xsimd::fnma(B(0.5f) * x, y * y, B(1.5f));
  } else if constexpr (std::is_same_v<T, float> && sizeof(B) == 32 && std::is_base_of_v<xsimd::avx, A>) {
    const B y(_mm256_rsqrt_ps(x));
    return y * xsimd::fnma(B(0.5f) * x, y * y, B(1.5f));
  } else {
    return B(T(1)) / xsimd::sqrt(x);
  }
}

/// 1 / x for finite non-zero x. Float batches: the hardware estimate refined by one Newton step
/// (within about 2 ulp); scalars and doubles: an exact division.
inline float reciprocal(float x) { return 1.0f / x; }
inline double reciprocal(double x) { return 1.0 / x; }
template <class T, class A>
inline xsimd::batch<T, A> reciprocal(const xsimd::batch<T, A>& x) {
  using B = xsimd::batch<T, A>;
  if constexpr (std::is_same_v<T, float> && std::is_base_of_v<xsimd::avx512f, A>) {
    const B y(_mm512_maskz_rcp14_ps(__mmask16(0xFFFF), x));
    return y * xsimd::fnma(x, y, B(2.0f));
  } else if constexpr (std::is_same_v<T, float> && sizeof(B) == 32 && std::is_base_of_v<xsimd::avx, A>) {
    const B y(_mm256_rcp_ps(x));
    return y * xsimd::fnma(x, y, B(2.0f));
  } else {
    return B(T(1)) / x;
  }
}

/// log(x) for positive, normal, finite x (no checks for zero, negative, denormal, infinite or NaN
/// input). Float batches: the exponent split off as in fdlibm (mantissa in [sqrt(1/2), sqrt(2))),
/// then Cephes' logf polynomial for log(1 + f), which needs no division; within about 1 ulp.
/// Scalars and doubles: std::log / xsimd::log.
inline float log_positive(float x) { return std::log(x); }
inline double log_positive(double x) { return std::log(x); }
template <class T, class A>
inline xsimd::batch<T, A> log_positive(const xsimd::batch<T, A>& x) {
  if constexpr (std::is_same_v<T, float>) {
    using B = xsimd::batch<float, A>;
    using I = xsimd::batch<std::int32_t, A>;
    I ix = xsimd::bitwise_cast<I>(x) + I(0x3f800000 - 0x3f3504f3);
    const B k = xsimd::to_float(I((ix >> 23) - I(0x7f)));
    ix = (ix & I(0x007fffff)) + I(0x3f3504f3);
    const B f = xsimd::bitwise_cast<B>(ix) - B(1.0f);
    const B z = f * f;
    B p(7.0376836292e-2f);
    p = xsimd::fma(p, f, B(-1.1514610310e-1f));
    p = xsimd::fma(p, f, B(1.1676998740e-1f));
    p = xsimd::fma(p, f, B(-1.2420140846e-1f));
    p = xsimd::fma(p, f, B(1.4249322787e-1f));
    p = xsimd::fma(p, f, B(-1.6668057665e-1f));
    p = xsimd::fma(p, f, B(2.0000714765e-1f));
    p = xsimd::fma(p, f, B(-2.4999993993e-1f));
    p = xsimd::fma(p, f, B(3.3333331174e-1f));
    // log(1 + f) = f - f^2/2 + f^3 p(f); k log 2 split into an exact high part and a correction.
    B r = xsimd::fma(p * f, z, xsimd::fma(k, B(-2.12194440e-4f), f));
    r = xsimd::fnma(B(0.5f), z, r);
    return xsimd::fma(k, B(0.693359375f), r);
  } else {
    return xsimd::log(x);
  }
}

/// Asks the cache to fetch the line holding `p` for reading soon (no fault and no effect on the
/// results whatever `p` points at). For streams a loop reads too many of at once for the hardware
/// prefetchers to follow, such as one plane per image and channel in the fused loss.
inline void prefetch(const void* p) {
#if defined(__GNUC__) || defined(__clang__)
  __builtin_prefetch(p, 0, 3);
#else
  (void)p;
#endif
}

/// a * b + c (one fused instruction for batches where the target has FMA).
inline float fma(float a, float b, float c) { return a * b + c; }
inline double fma(double a, double b, double c) { return a * b + c; }
template <class T, class A>
inline xsimd::batch<T, A> fma(const xsimd::batch<T, A>& a, const xsimd::batch<T, A>& b, const xsimd::batch<T, A>& c) {
  return xsimd::fma(a, b, c);
}

// ---- BF16 dot products (AVX-512 BF16) -------------------------------------------------------------
// bfloat16 keeps float's 8-bit exponent and 7 of its 23 mantissa bits. `vdpbf16ps` multiplies
// pairs of bf16 values and adds both products to one FP32 lane: 32 multiply-adds per instruction,
// twice an FP32 FMA's, with FP32 accumulation.

/// Round-to-nearest-even bf16 of x (the upper 16 bits of the rounded float); NaN stays NaN.
inline std::uint16_t to_bf16(float x) {
  std::uint32_t u;
  std::memcpy(&u, &x, sizeof u);
  if ((u & 0x7fffffffu) > 0x7f800000u) return std::uint16_t((u >> 16) | 0x40u);  // quiet NaN
  u += 0x7fffu + ((u >> 16) & 1u);
  return std::uint16_t(u >> 16);
}
/// The float a bf16 value stands for (exact).
inline float from_bf16(std::uint16_t h) {
  const std::uint32_t u = std::uint32_t(h) << 16;
  float x;
  std::memcpy(&x, &u, sizeof x);
  return x;
}

#if defined(__AVX512BF16__) && defined(__AVX512F__)
/// 1 where the BF16 dot product below exists (for preprocessor tests), else 0.
#define ANISOCAP_BF16_DOT 1
/// True when this translation unit has the BF16 dot product and batch<float> is 16 lanes.
inline constexpr bool bf16_dot_available = width<float> == 16;
/// 32 bf16 values: 16 pairs, one per FP32 lane.
using bf16_pairs = __m512bh;
/// Loads 32 bf16 values (16 pairs); no alignment needed.
ANISOCAP_ALWAYS_INLINE bf16_pairs load_bf16_pairs(const std::uint16_t* p) { return (__m512bh)_mm512_loadu_si512(p); }
/// The pair (p[0], p[1]) in every lane.
ANISOCAP_ALWAYS_INLINE bf16_pairs broadcast_bf16_pair(const std::uint16_t* p) {
  std::int32_t v;
  std::memcpy(&v, p, sizeof v);
  return (__m512bh)_mm512_set1_epi32(v);
}
/// acc[i] + a[2i] b[2i] + a[2i+1] b[2i+1] in FP32, for each of the 16 lanes.
template <class A>
ANISOCAP_ALWAYS_INLINE xsimd::batch<float, A> dot_bf16_pairs(const xsimd::batch<float, A>& acc, bf16_pairs a, bf16_pairs b) {
  return xsimd::batch<float, A>(_mm512_dpbf16_ps(acc, a, b));
}
/// dst[2j] = bf16(a[j]) and dst[2j + 1] = bf16(b[j]) for j < n: two rows side by side as the pairs
/// dot_bf16_pairs reads (rounded to nearest even; denormal inputs read as zero).
inline void interleave_to_bf16(const float* a, const float* b, int n, std::uint16_t* dst) {
  const __m512i lo = _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
  const __m512i hi = _mm512_setr_epi32(8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
  for (int j = 0; j < n; j += 16) {
    // 16 channels a step, the last n - j < 16 masked (the 12-channel layers have nothing else).
    const __mmask16 m = n - j >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << (n - j)) - 1);
    const __m512 x = _mm512_maskz_loadu_ps(m, a + j), y = _mm512_maskz_loadu_ps(m, b + j);
    const __m512bh v = _mm512_cvtne2ps_pbh(_mm512_permutex2var_ps(x, hi, y), _mm512_permutex2var_ps(x, lo, y));
    _mm512_mask_storeu_epi32(dst + 2 * j, m, (__m512i)v);
  }
}
/// The bf16 pairs of 16 float rows, transposed: for l < 16 and q < pairs, the pair
/// (bf16(row_l[2q]), bf16(row_l[2q + 1])) is written at dst + 2 (q stride + l), row l being the
/// 2 x pairs floats at src + l ld for l < nrows, and zero for the rows from nrows on (src is not
/// read when nrows is 0). Rounded as convert_to_bf16 rounds; 16 pairs of the 16 rows at a time are
/// converted into 16 registers, transposed in registers and stored as 16 whole registers.
inline void transpose_to_bf16_pairs(const float* src, std::ptrdiff_t ld, int nrows, int pairs, std::uint16_t* dst,
                                    std::ptrdiff_t stride) {
  for (int q0 = 0; q0 < pairs; q0 += 16) {
    const int k = pairs - q0 < 16 ? pairs - q0 : 16;  // pairs in this step
    const int values = 2 * k;
    const __mmask16 m0 = values >= 16 ? __mmask16(0xFFFF) : __mmask16((1u << values) - 1);
    const __mmask16 m1 = values >= 32 ? __mmask16(0xFFFF) : values > 16 ? __mmask16((1u << (values - 16)) - 1) : __mmask16(0);
    __m512i r[16], t[16];
    for (int l = 0; l < 16; ++l) {
      if (l < nrows) {
        const float* s = src + l * ld + 2 * q0;
        r[l] = (__m512i)_mm512_cvtne2ps_pbh(_mm512_maskz_loadu_ps(m1, s + 16), _mm512_maskz_loadu_ps(m0, s));
      } else {
        r[l] = _mm512_setzero_si512();
      }
    }
    // A 16 x 16 transpose of 32-bit words: pairs of rows interleaved by words, then by two words
    // (t[4i + m], 128-bit lane c: rows 4i..4i+3 of column 4c + m), then the lanes gathered.
    for (int i = 0; i < 8; ++i) {
      t[2 * i] = _mm512_unpacklo_epi32(r[2 * i], r[2 * i + 1]);
      t[2 * i + 1] = _mm512_unpackhi_epi32(r[2 * i], r[2 * i + 1]);
    }
    for (int i = 0; i < 4; ++i) {
      r[4 * i] = _mm512_unpacklo_epi64(t[4 * i], t[4 * i + 2]);
      r[4 * i + 1] = _mm512_unpackhi_epi64(t[4 * i], t[4 * i + 2]);
      r[4 * i + 2] = _mm512_unpacklo_epi64(t[4 * i + 1], t[4 * i + 3]);
      r[4 * i + 3] = _mm512_unpackhi_epi64(t[4 * i + 1], t[4 * i + 3]);
    }
    for (int m = 0; m < 4; ++m) {
      const __m512i x0 = _mm512_shuffle_i32x4(r[m], r[4 + m], 0x88), x1 = _mm512_shuffle_i32x4(r[m], r[4 + m], 0xDD);
      const __m512i y0 = _mm512_shuffle_i32x4(r[8 + m], r[12 + m], 0x88), y1 = _mm512_shuffle_i32x4(r[8 + m], r[12 + m], 0xDD);
      t[m] = _mm512_shuffle_i32x4(x0, y0, 0x88);       // column m
      t[4 + m] = _mm512_shuffle_i32x4(x1, y1, 0x88);   // column 4 + m
      t[8 + m] = _mm512_shuffle_i32x4(x0, y0, 0xDD);   // column 8 + m
      t[12 + m] = _mm512_shuffle_i32x4(x1, y1, 0xDD);  // column 12 + m
    }
    for (int c = 0; c < k; ++c) _mm512_storeu_si512(dst + 2 * (std::ptrdiff_t(q0 + c) * stride), t[c]);
  }
}
/// dst[i] = bf16(src[i]) for i < n (rounded to nearest even; denormal inputs read as zero).
inline void convert_to_bf16(const float* src, std::ptrdiff_t n, std::uint16_t* dst) {
  std::ptrdiff_t i = 0;
  for (; i + 32 <= n; i += 32)
    _mm512_storeu_si512(dst + i, (__m512i)_mm512_cvtne2ps_pbh(_mm512_loadu_ps(src + i + 16), _mm512_loadu_ps(src + i)));
  // The last n - i < 32 values masked, converted by the hardware as the others (denormals read as zero).
  for (; i < n; i += 16) {
    const int k = n - i < 16 ? int(n - i) : 16;
    const __mmask16 m = __mmask16((1u << k) - 1);
    _mm256_mask_storeu_epi16(dst + i, m, (__m256i)_mm512_cvtneps_pbh(_mm512_maskz_loadu_ps(m, src + i)));
  }
}
#else
#define ANISOCAP_BF16_DOT 0
/// True when this translation unit has the BF16 dot product (it does not: built without AVX-512 BF16).
inline constexpr bool bf16_dot_available = false;
#endif

}  // namespace anisocap::simd
