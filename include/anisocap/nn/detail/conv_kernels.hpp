#pragma once
/// @file
/// Register-blocked microkernels shared by convolution and transposed convolution (docs/method.md section 7:
/// every layer of the estimator and the auto-encoder is one of them, so they carry the run time).
///
/// All passes are direct convolutions on NHWC data written as small GEMMs:
/// - `run_forward`: out[pixel][co] (+)= sum over taps t and channels ci of
///   A[pixel + tap_t][ci] * W[t][ci][co]. A tile of NX pixels of one row times NV SIMD registers of
///   output channels stays in registers while the loop runs over taps and ci; weights are vector
///   loads, inputs broadcasts. Forward convolution, both backward-input passes and the four
///   parity sub-convolutions of a transposed convolution are all of this form.
/// - `run_weight`: gW[t][ci][co] += sum over pixels of A[pixel + a_tap_t][ci] * G[pixel + g_tap_t][co].
///   A block of CIB input channels times NV registers of output channels stays in registers while
///   the loop runs over pixels.
/// Borders are handled by copying the input into a zero-padded scratch once per call, so the
/// inner loops never test bounds.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <omp.h>

#include "anisocap/core/memory.hpp"
#include "anisocap/core/simd.hpp"
#include "anisocap/core/tensor.hpp"
#include "anisocap/nn/precision.hpp"

namespace anisocap::nn::detail::conv {

/// SIMD lanes of T.
template <class T>
inline constexpr int lanes = int(simd::width<T>);

/// Accumulator registers a tile may use: 24 of the 32 AVX-512 registers, 12 of the 16 AVX2 ones
/// (the rest hold weights and the broadcast input).
template <class T>
inline constexpr int accumulator_budget = (sizeof(T) * simd::width<T> >= 64) ? 24 : 12;

/// A forward tile's pixels for NV registers of output channels: as many as the accumulator budget
/// holds (the wide tile), and about two thirds of that (the narrow tile, for the rest of a row).
template <class T>
constexpr int forward_tile_width(int nv) { return std::max(1, accumulator_budget<T> / nv); }
template <class T>
constexpr int forward_narrow_width(int nv) { return std::max(1, 2 * forward_tile_width<T>(nv) / 3); }

/// Channels rounded up to whole registers.
template <class T>
constexpr int padded_channels(int c) { return (c + lanes<T> - 1) / lanes<T> * lanes<T>; }

/// Registers of output channels per tile for C output channels: 4, 2 or 1, dividing the count.
template <class T>
constexpr int vectors_per_tile(int c) {
  const int n = padded_channels<T>(c) / lanes<T>;
  if (accumulator_budget<T> >= 24 && n % 4 == 0) return 4;
  if (n % 2 == 0) return 2;
  return 1;
}

/// Per-thread scratch memory that grows to the largest size asked and is then reused, so steady
/// training steps allocate nothing. Slots separate buffers alive at the same time.
template <class T>
inline T* scratch(int slot, std::size_t n) {
  thread_local aligned_buffer<T> buffers[8];
  if (buffers[slot].size() < n) buffers[slot] = aligned_buffer<T>(n + n / 8 + 64);
  return buffers[slot].data();
}

using simd::batch;

// ---- forward-type pass ------------------------------------------------------------------------

/// One pass of `run_forward`: a grid batch x rows x cols of output pixels, where pixel (b, r, c)
/// reads A at a + b*a_batch + r*a_row + c*a_col and writes out at o + b*o_batch + r*o_row + c*o_col.
/// The kernels take a_col at run time, so that one kernel per register block serves every layer
/// shape, except with one-register tiles (ACOL > 0, see run_forward): their 24 pixel offsets fit
/// no general registers and stay compile-time displacements.
template <class T>
struct forward_pass {
  const T* a = nullptr;
  std::ptrdiff_t a_batch = 0, a_row = 0, a_col = 0;
  T* o = nullptr;
  std::ptrdiff_t o_batch = 0, o_row = 0, o_col = 0;
  int batch = 0, rows = 0, cols = 0;
  int taps = 0;
  std::ptrdiff_t a_tap[16] = {};  ///< offset of each tap in A
  std::ptrdiff_t w_tap[16] = {};  ///< offset of each tap's weights (weight_layout::tap_stride times its index)
};

/// A register tile's accumulators at the start: `init` 0 = zero, 1 = the bias vector, 2 = out's
/// current values, NX rows o_col apart (pixels of an output, or input channels of a weight
/// gradient; the last register of each row holds last_lanes channels).
template <int NX, int NV, class T>
ANISOCAP_ALWAYS_INLINE void tile_start(batch<T> (&acc)[NX][NV], const T* out, std::ptrdiff_t o_col, int last_lanes, const T* bias, int init) {
  constexpr int W = lanes<T>;
  #pragma GCC unroll 32
  for (int p = 0; p < NX; ++p)
    #pragma GCC unroll 32
    for (int v = 0; v < NV; ++v) {
      if (init == 2) {
        const T* src = out + p * o_col + v * W;
        acc[p][v] = (v == NV - 1 && last_lanes != W) ? simd::load_first<batch<T>>(src, last_lanes) : batch<T>::load_unaligned(src);
      } else if (init == 1) {
        acc[p][v] = batch<T>::load_unaligned(bias + v * W);
      } else {
        acc[p][v] = batch<T>(T(0));
      }
    }
}
/// Stores a register tile's accumulators into out.
template <int NX, int NV, class T>
ANISOCAP_ALWAYS_INLINE void tile_finish(const batch<T> (&acc)[NX][NV], T* out, std::ptrdiff_t o_col, int last_lanes) {
  constexpr int W = lanes<T>;
  #pragma GCC unroll 32
  for (int p = 0; p < NX; ++p)
    #pragma GCC unroll 32
    for (int v = 0; v < NV; ++v) {
      T* dst = out + p * o_col + v * W;
      if (v == NV - 1 && last_lanes != W) simd::store_first(dst, acc[p][v], last_lanes);
      else acc[p][v].store_unaligned(dst);
    }
}

/// The register tile: NX pixels (A step ACOL apart, or a_col when ACOL is 0) x NV registers of
/// output channels. `init`: 0 = zero, 1 = bias vector, 2 = accumulate onto out.
template <int NX, int NV, int ACOL, class T>
inline void forward_tile(const T* const* a_tap, const T* const* w_tap, int taps, int n, std::ptrdiff_t ldw, std::ptrdiff_t a_col, T* out,
                         std::ptrdiff_t o_col, int last_lanes, const T* bias, int init) {
  constexpr int W = lanes<T>;
  const std::ptrdiff_t step = ACOL > 0 ? ACOL : a_col;
  batch<T> acc[NX][NV];
  tile_start<NX, NV>(acc, out, o_col, last_lanes, bias, init);
  for (int t = 0; t < taps; ++t) {
    const T* a = a_tap[t];
    const T* w = w_tap[t];
    for (int ci = 0; ci < n; ++ci, w += ldw) {
      batch<T> wv[NV];
      #pragma GCC unroll 32
      for (int v = 0; v < NV; ++v) wv[v] = batch<T>::load_unaligned(w + v * W);
      #pragma GCC unroll 32
      for (int p = 0; p < NX; ++p) {
        const batch<T> x(a[p * step + ci]);
        #pragma GCC unroll 32
        for (int v = 0; v < NV; ++v) acc[p][v] = xsimd::fma(x, wv[v], acc[p][v]);
      }
    }
  }
  tile_finish<NX, NV>(acc, out, o_col, last_lanes);
}

/// The three register tiles of a forward pass (the wide tile, the narrow one, one pixel), as
/// function pointers of type Tile: the pass driver is compiled once per register count NV, and only
/// the tiles once per compile-time column step ACOL. A call per tile costs nothing beside the
/// tile's taps x channels x pixels of FMAs.
template <class Tile>
struct forward_tiles {
  Tile wide, narrow, single;
  /// The tile for `nx` pixels, where the wide tile has nx1 and the narrow one nx2.
  Tile of_width(int nx, int nx1, int nx2) const { return nx == nx1 ? wide : nx == nx2 ? narrow : single; }
};
/// The tiles of run_forward<NV, ACOL, T>. The single-pixel tile never steps between pixels, so
/// it is the same for every ACOL.
template <int NX1, int NX2, int NV, int ACOL, class T>
inline constexpr forward_tiles<decltype(&forward_tile<1, NV, 0, T>)> forward_tiles_of{
    &forward_tile<NX1, NV, ACOL, T>, &forward_tile<NX2, NV, ACOL, T>, &forward_tile<1, NV, 0, T>};

/// How the weights of a forward-type pass are laid out: tap t's [ci][co] slice of output-channel
/// block cb starts at w + t * tap_stride + cb * block_stride, rows ld apart. Packed weights
/// ([cb][tap][ci][block], see pack_weights) make every block one contiguous stream.
template <class T>
struct weight_layout {
  const T* w = nullptr;
  std::ptrdiff_t ld = 0, tap_stride = 0, block_stride = 0;
  /// The weights are the caller's [taps][Ca][ld] array: each work item copies the block of
  /// taps x ci-chunk x block it needs into a per-thread, L2-sized, contiguous buffer (one read of
  /// the weights from memory, no 4 KiB strides in the inner loop, no whole-array copy).
  bool pack = false;
  /// With pack: the caller's array holds the kernel transposed, [taps][out][reduced] with rows
  /// ld apart (an input-gradient pass reading [K][K][Cin][Cout] weights); the work item
  /// transposes its block while packing it, in cache, instead of a whole-array transposed copy.
  bool transposed = false;
};

/// How one row of `cols` pixels is cut into register tiles: n_wide tiles of the wide width, then
/// n_narrow of the narrow one, then single pixels. Chosen by a cost model (single pixels reload
/// the weights for every pixel and run at about 40% of a tile's speed, narrow tiles at about 80%).
struct row_plan {
  int wide = 0, n_wide = 0, narrow = 0, n_narrow = 0, n_single = 0;
  int tiles() const { return n_wide + n_narrow + n_single; }
  /// First column and width of tile k.
  std::pair<int, int> tile(int k) const {
    if (k < n_wide) return {k * wide, wide};
    k -= n_wide;
    if (k < n_narrow) return {n_wide * wide + k * narrow, narrow};
    k -= n_narrow;
    return {n_wide * wide + n_narrow * narrow + k, 1};
  }
  static row_plan make(int cols, int wide, int narrow) {
    row_plan best;
    double best_cost = 1e300;
    for (int a = cols / wide; a >= 0 && a >= cols / wide - 2; --a) {
      const int rest = cols - a * wide;
      const int b = rest / narrow, c = rest % narrow;
      const double cost = a * wide * 1.0 + b * narrow * 1.25 + c * 2.5;
      if (cost < best_cost) { best_cost = cost; best = row_plan{wide, a, narrow, b, c}; }
    }
    return best;
  }
};

/// Copies rows r0..r1 of one block of a transposed kernel (weight_layout::transposed: stored
/// [out][reduced], rows ld apart, from src = the tap's start) into dst as [r - r0][block], column j
/// from stored row co0 + j; columns from n_cols on are zero. The block is small, so it stays in cache.
template <class T>
void transpose_block(const T* src, std::ptrdiff_t ld, int co0, int n_cols, int r0, int r1, int block, T* dst) {
  for (int j = 0; j < block; ++j) {
    if (j < n_cols) {
      const T* sj = src + std::ptrdiff_t(co0 + j) * ld + r0;
      for (int r = 0; r < r1 - r0; ++r) dst[std::ptrdiff_t(r) * block + j] = sj[r];
    } else {
      for (int r = 0; r < r1 - r0; ++r) dst[std::ptrdiff_t(r) * block + j] = T(0);
    }
  }
}

/// Asks the cache for `rows` rows of n values, ld apart, starting at p (no effect on any result).
/// For rows a page or more apart, which no hardware prefetcher follows: the weights a pass packs,
/// the gradient rows a weight tile adds to.
template <class T>
inline void prefetch_rows(const T* p, std::ptrdiff_t ld, int rows, int n) {
  const int lines = int((std::size_t(n) * sizeof(T) + 63) / 64);
  for (int r = 0; r < rows; ++r)
    for (int l = 0; l < lines; ++l) simd::prefetch(p + std::ptrdiff_t(r) * ld + std::ptrdiff_t(l) * (64 / sizeof(T)));
}

/// How run_forward cuts its passes into work items: each pass's rows into register tiles
/// (row_plan), the tiles into chunks of `chunk`, and each chunk into one item per output-channel
/// block. Consecutive items share pixels and differ in output-channel block, so the inputs stay
/// cached.
template <class T>
struct forward_items {
  row_plan plan[4];
  long long tiles_in[4] = {}, first_item[5] = {};
  long long total_tiles = 0, chunk = 32, items = 0;
  int coblocks = 0;
  /// One work item: its pass, output-channel block and range of tiles.
  struct item {
    int pass, cb;
    long long t0, t1;
  };
  /// One register tile of a pass: batch entry, row, first column and width.
  struct tile {
    int b, r, x, nx;
  };
  forward_items(const forward_pass<T>* passes, int npasses, int wide, int narrow, int blocks) : coblocks(blocks) {
    const int threads = omp_get_max_threads();
    for (int i = 0; i < npasses; ++i) {
      plan[i] = row_plan::make(passes[i].cols, wide, narrow);
      tiles_in[i] = (long long)passes[i].batch * passes[i].rows * plan[i].tiles();
      total_tiles += tiles_in[i];
    }
    // Tiles per work item: enough for weight reuse, small enough to feed every thread.
    while (chunk > 1 && ((total_tiles + chunk - 1) / chunk) * coblocks < 8LL * threads) chunk /= 2;
    for (int i = 0; i < npasses; ++i) {
      first_item[i] = items;
      items += (tiles_in[i] + chunk - 1) / chunk * coblocks;
    }
    first_item[npasses] = items;
  }
  item at(long long k) const {
    int pi = 0;
    while (k >= first_item[pi + 1]) ++pi;
    const long long local = k - first_item[pi];
    const long long t0 = local / coblocks * chunk;
    return {pi, int(local % coblocks), t0, std::min(tiles_in[pi], t0 + chunk)};
  }
  tile tile_of(const forward_pass<T>& ps, int pass, long long k) const {
    const row_plan& pl = plan[pass];
    const long long row = k / pl.tiles();
    const auto [x, nx] = pl.tile(int(k % pl.tiles()));
    return {int(row / ps.rows), int(row % ps.rows), x, nx};
  }
};

// ---- bf16 forward-type pass ------------------------------------------------------------------
#if ANISOCAP_BF16_DOT

/// The bf16 register tile: as forward_tile, with inputs and weights in bf16 and two input channels
/// per instruction. a_tap points into the bf16 copy of A (same offsets as the FP32 data); tap t's
/// weights are `pairs` rows of [block][2] bf16 (channels 2q and 2q+1 of each output column side by
/// side), block = NV x 16.
template <int NX, int NV, int ACOL>
inline void forward_tile_bf16(const std::uint16_t* const* a_tap, const std::uint16_t* const* w_tap, int taps, int pairs,
                              std::ptrdiff_t a_col, float* out, std::ptrdiff_t o_col, int last_lanes, const float* bias, int init) {
  constexpr int W = lanes<float>;
  const std::ptrdiff_t step = ACOL > 0 ? ACOL : a_col;
  batch<float> acc[NX][NV];
  tile_start<NX, NV>(acc, out, o_col, last_lanes, bias, init);
  for (int t = 0; t < taps; ++t) {
    const std::uint16_t* a = a_tap[t];
    const std::uint16_t* w = w_tap[t];
    for (int q = 0; q < pairs; ++q, w += 2 * NV * W) {
      simd::bf16_pairs wv[NV];
      #pragma GCC unroll 32
      for (int v = 0; v < NV; ++v) wv[v] = simd::load_bf16_pairs(w + 2 * v * W);
      #pragma GCC unroll 32
      for (int p = 0; p < NX; ++p) {
        const simd::bf16_pairs x = simd::broadcast_bf16_pair(a + p * step + 2 * q);
        #pragma GCC unroll 32
        for (int v = 0; v < NV; ++v) acc[p][v] = simd::dot_bf16_pairs(acc[p][v], x, wv[v]);
      }
    }
  }
  tile_finish<NX, NV>(acc, out, o_col, last_lanes);
}

/// The bf16 tiles of run_forward<NV, ACOL, float> (see forward_tiles).
template <int NX1, int NX2, int NV, int ACOL>
inline constexpr forward_tiles<decltype(&forward_tile_bf16<1, NV, 0>)> forward_tiles_bf16_of{
    &forward_tile_bf16<NX1, NV, ACOL>, &forward_tile_bf16<NX2, NV, ACOL>, &forward_tile_bf16<1, NV, 0>};

/// `n` values at p and at p + step side by side as bf16 pairs (two pixels of a weight gradient,
/// or two weight rows); `second` false: the second of each pair is zero.
inline void pixel_pair_to_bf16(const float* p, std::ptrdiff_t step, bool second, int n, std::uint16_t* dst) {
  if (second) {
    simd::interleave_to_bf16(p, p + step, n, dst);
  } else {
    for (int j = 0; j < n; ++j) dst[2 * j] = simd::to_bf16(p[j]), dst[2 * j + 1] = 0;
  }
}

/// Writes rows r0..r1 of one tap of a forward-type pass's weights (layout wl, output-channel block
/// cb of `block` columns, n_cols of them real) as bf16 pairs [(r1 - r0 + 1) / 2][block][2]; a
/// missing odd row and the columns beyond n_cols are zero. A transposed source (the kernel of an
/// input-gradient pass in its stored layout) is converted row by row and its pairs written
/// across, one 32-bit word each: no FP32 copy of the transposed kernel.
inline void pack_bf16_pairs(const weight_layout<float>& wl, std::ptrdiff_t w_tap, int cb, int block, int n_cols, int r0, int r1,
                            std::uint16_t* dst) {
  const int rows = r1 - r0;
  const int co0 = cb * block;
  if (wl.pack && wl.transposed) {
    // Column j of the block is source row co0 + j, whose values r0..r1 lie side by side: pair q of
    // column j is two neighbours of it, converted together and written as one 32-bit word.
    const int full = rows & ~1, pairs = (rows + 1) / 2;
    if (full == rows && block % 16 == 0) {
      // Sixteen columns at a time, transposed in registers (the same conversion, whole stores).
      for (int j0 = 0; j0 < block; j0 += 16) {
        const int nrows = std::clamp(n_cols - j0, 0, 16);
        const float* s = nrows > 0 ? wl.w + w_tap + std::ptrdiff_t(co0 + j0) * wl.ld + r0 : nullptr;
        simd::transpose_to_bf16_pairs(s, wl.ld, nrows, pairs, dst + 2 * j0, block);
      }
      return;
    }
    std::uint16_t* t = scratch<std::uint16_t>(7, std::size_t(pairs) * 2);
    for (int j = 0; j < block; ++j) {
      if (j < n_cols) {
        const float* s = wl.w + w_tap + std::ptrdiff_t(co0 + j) * wl.ld + r0;
        simd::convert_to_bf16(s, full, t);
        if (rows & 1) t[full] = simd::to_bf16(s[full]), t[full + 1] = 0;
      } else {
        std::fill(t, t + 2 * pairs, std::uint16_t(0));
      }
      for (int q = 0; q < pairs; ++q) std::memcpy(dst + (std::ptrdiff_t(q) * block + j) * 2, t + 2 * q, 2 * sizeof(std::uint16_t));
    }
    return;
  }
  const float* base = wl.pack ? wl.w + w_tap + co0 + std::ptrdiff_t(r0) * wl.ld : wl.w + w_tap + cb * wl.block_stride + std::ptrdiff_t(r0) * wl.ld;
  const std::ptrdiff_t ld = wl.ld;
  const int n = wl.pack ? n_cols : block;
  // The rows lie ld apart, often a page or more: each is asked for `ahead` rows early.
  constexpr int ahead = 8;
  for (int r = 0; r < rows; r += 2) {
    std::uint16_t* d = dst + std::ptrdiff_t(r) * block;
    const float* a = base + std::ptrdiff_t(r) * ld;
    if (r + ahead < rows) prefetch_rows(a + std::ptrdiff_t(ahead) * ld, ld, std::min(2, rows - r - ahead), n);
    pixel_pair_to_bf16(a, ld, r + 1 < rows, n, d);
    if (n < block) std::memset(static_cast<void*>(d + 2 * n), 0, sizeof(std::uint16_t) * 2 * (block - n));
  }
}

/// run_forward in bf16 (see nn/precision.hpp): the span of A the passes read is converted to bf16
/// once (same offsets), the weights are converted to bf16 pairs either once for the call (when
/// many work items share each block) or by each work item for its block, as the FP32 path packs
/// them; the tiles accumulate in FP32.
template <int NV, class Tile>
void run_forward_bf16(forward_pass<float>* passes, int npasses, int Ca, int Cb, const weight_layout<float>& wl,
                      const float* bias, bool accumulate, bool whole_blocks, const forward_tiles<Tile>& tiles) {
  constexpr int W = lanes<float>;
  constexpr int NX1 = forward_tile_width<float>(NV), NX2 = forward_narrow_width<float>(NV);
  const int block = NV * W;
  const int coblocks = (Cb + block - 1) / block;
  const int last_lanes = Cb - (coblocks - 1) * block - (NV - 1) * W;
  const int pairs_total = (Ca + 1) / 2;
  // The bf16 copy of A: every pass reads one buffer, from its start to the last tap of its last pixel.
  const float* lo = passes[0].a;
  const float* hi = passes[0].a;
  for (int i = 0; i < npasses; ++i) {
    const forward_pass<float>& ps = passes[i];
    std::ptrdiff_t last_tap = 0;
    for (int t = 0; t < ps.taps; ++t) last_tap = std::max(last_tap, ps.a_tap[t]);
    lo = std::min(lo, ps.a);
    hi = std::max(hi, ps.a + (ps.batch - 1) * ps.a_batch + (ps.rows - 1) * ps.a_row + std::ptrdiff_t(ps.cols - 1) * ps.a_col + last_tap + Ca);
  }
  const std::ptrdiff_t span = hi - lo;
  // Two zeros past the end: an odd channel count's last pair reads one value beyond (its weight is 0).
  std::uint16_t* a16 = scratch<std::uint16_t>(0, std::size_t(span) + 2);
#pragma omp parallel for schedule(static) if (span > (1 << 16))
  for (std::ptrdiff_t i = 0; i < span; i += 4096) simd::convert_to_bf16(lo + i, std::min<std::ptrdiff_t>(4096, span - i), a16 + i);
  a16[span] = a16[span + 1] = 0;
  // Input-channel chunk (even) so that a chunk of weights (taps x ci x block) stays in L2.
  int ci_chunk = Ca;
  {
    const std::size_t bytes = std::size_t(passes[0].taps) * block * sizeof(std::uint16_t);
    ci_chunk = int(std::max<std::size_t>(16, (std::size_t(256) << 10) / bytes)) & ~1;
    if (ci_chunk >= Ca) ci_chunk = Ca;
  }
  const forward_items<float> work(passes, npasses, NX1, NX2, coblocks);
  const long long items = work.items;
  // Weights converted once for the call when each block serves several work items, else by the items.
  const std::ptrdiff_t tap_pairs = std::ptrdiff_t(pairs_total) * block * 2;  // one tap of one block
  std::ptrdiff_t pass_offset[4] = {};
  int total_taps = 0;
  for (int i = 0; i < npasses; ++i) {
    pass_offset[i] = std::ptrdiff_t(total_taps) * coblocks * tap_pairs;
    total_taps += passes[i].taps;
  }
  const bool convert_once = items >= 3LL * coblocks * npasses;
  std::uint16_t* packed = nullptr;
  if (convert_once) {
    packed = scratch<std::uint16_t>(1, std::size_t(total_taps) * coblocks * tap_pairs);
    const int jobs = total_taps * coblocks;
#pragma omp parallel for schedule(dynamic, 1) if (jobs > 1 && std::size_t(total_taps) * Ca * Cb > (1u << 16))
    for (int job = 0; job < jobs; ++job) {
      int pi = 0, rest = job;
      while (rest >= passes[pi].taps * coblocks) rest -= passes[pi].taps * coblocks, ++pi;
      const int cb = rest / passes[pi].taps, t = rest % passes[pi].taps;
      pack_bf16_pairs(wl, passes[pi].w_tap[t], cb, block, std::min(block, Cb - cb * block), 0, Ca,
                      packed + pass_offset[pi] + (std::ptrdiff_t(cb) * passes[pi].taps + t) * tap_pairs);
    }
  }

#pragma omp parallel for schedule(dynamic, 1) if (items > 1 && work.total_tiles * Ca * Cb > (1 << 16))
  for (long long item = 0; item < items; ++item) {
    const auto [pi, cb, t0, t1] = work.at(item);
    const forward_pass<float>& ps = passes[pi];
    const int co0 = cb * block;
    const std::uint16_t* w_tap[16];
    const int n_cols = std::min(block, Cb - co0);
    const float* bias_block = bias ? bias + co0 : nullptr;
    const int lanes_here = (cb == coblocks - 1 && !whole_blocks) ? last_lanes : W;
    const std::uint16_t* a_base = a16 + (ps.a - lo);
    for (int c0 = 0; c0 < Ca; c0 += ci_chunk) {
      const int c1 = std::min(Ca, c0 + ci_chunk);
      const int pairs = (c1 - c0 + 1) / 2;
      if (convert_once) {
        for (int t = 0; t < ps.taps; ++t)
          w_tap[t] = packed + pass_offset[pi] + (std::ptrdiff_t(cb) * ps.taps + t) * tap_pairs + std::ptrdiff_t(c0 / 2) * block * 2;
      } else {
        std::uint16_t* buffer = scratch<std::uint16_t>(4, std::size_t(ps.taps) * pairs * block * 2);
        for (int t = 0; t < ps.taps; ++t) {
          std::uint16_t* dst = buffer + std::ptrdiff_t(t) * pairs * block * 2;
          pack_bf16_pairs(wl, ps.w_tap[t], cb, block, n_cols, c0, c1, dst);
          w_tap[t] = dst;
        }
      }
      const int init = c0 > 0 || accumulate ? 2 : (bias_block ? 1 : 0);
      for (long long tile = t0; tile < t1; ++tile) {
        const auto [b, r, x, nx] = work.tile_of(ps, pi, tile);
        const std::uint16_t* abase = a_base + b * ps.a_batch + r * ps.a_row + std::ptrdiff_t(x) * ps.a_col + c0;
        float* obase = ps.o + b * ps.o_batch + r * ps.o_row + std::ptrdiff_t(x) * ps.o_col + co0;
        const std::uint16_t* a_tap[16];
        for (int t = 0; t < ps.taps; ++t) a_tap[t] = abase + ps.a_tap[t];
        tiles.of_width(nx, NX1, NX2)(a_tap, w_tap, ps.taps, pairs, ps.a_col, obase, ps.o_col, lanes_here, bias_block, init);
      }
    }
  }
}

#endif  // ANISOCAP_BF16_DOT

/// The FP32 (or FP64) driver of run_forward, with its register tiles.
template <int NV, class T, class Tile>
void run_forward_with(forward_pass<T>* passes, int npasses, int Ca, int Cb, const weight_layout<T>& wl, const T* bias,
                      bool accumulate, bool whole_blocks, const forward_tiles<Tile>& tiles) {
  constexpr int W = lanes<T>;
  constexpr int NX1 = forward_tile_width<T>(NV), NX2 = forward_narrow_width<T>(NV);
  const int block = NV * W;
  const int coblocks = (Cb + block - 1) / block;
  const int last_lanes = Cb - (coblocks - 1) * block - (NV - 1) * W;
  // Input-channel chunk so that a chunk of weights (taps x ci x block) stays in L2.
  int ci_chunk = Ca;
  {
    const std::size_t bytes = std::size_t(passes[0].taps) * block * sizeof(T);
    ci_chunk = int(std::max<std::size_t>(16, (std::size_t(256) << 10) / bytes));
    ci_chunk = std::min(ci_chunk, Ca);
  }
  const forward_items<T> work(passes, npasses, NX1, NX2, coblocks);
  const long long items = work.items;

#pragma omp parallel for schedule(dynamic, 1) if (items > 1 && work.total_tiles * Ca * Cb > (1 << 16))
  for (long long item = 0; item < items; ++item) {
    const auto [pi, cb, t0, t1] = work.at(item);
    const forward_pass<T>& ps = passes[pi];
    const int co0 = cb * block;
    const T* w_tap[16];
    std::ptrdiff_t ld = wl.ld;
    T* buffer = wl.pack ? scratch<T>(4, std::size_t(ps.taps) * ci_chunk * block) : nullptr;
    const int n_cols = std::min(block, Cb - co0);
    const T* bias_block = bias ? bias + co0 : nullptr;
    // whole_blocks: the output has room for whole blocks (a padded buffer), so no partial stores.
    const int lanes_here = (cb == coblocks - 1 && !whole_blocks) ? last_lanes : W;
    for (int c0 = 0; c0 < Ca; c0 += ci_chunk) {
      const int c1 = std::min(Ca, c0 + ci_chunk);
      if (wl.pack && wl.transposed) {
        for (int t = 0; t < ps.taps; ++t) {
          T* dst = buffer + std::ptrdiff_t(t) * (c1 - c0) * block;
          transpose_block(wl.w + ps.w_tap[t], wl.ld, co0, n_cols, c0, c1, block, dst);
          w_tap[t] = dst;
        }
        ld = block;
      } else if (wl.pack) {
        for (int t = 0; t < ps.taps; ++t) {
          const T* src = wl.w + ps.w_tap[t] + std::ptrdiff_t(c0) * wl.ld + co0;
          T* dst = buffer + std::ptrdiff_t(t) * (c1 - c0) * block;
          for (int ci = c0; ci < c1; ++ci, src += wl.ld, dst += block) {
            std::memcpy(static_cast<void*>(dst), src, sizeof(T) * n_cols);
            if (n_cols < block) std::memset(static_cast<void*>(dst + n_cols), 0, sizeof(T) * (block - n_cols));
          }
          w_tap[t] = buffer + std::ptrdiff_t(t) * (c1 - c0) * block;
        }
        ld = block;
      } else {
        for (int t = 0; t < ps.taps; ++t) w_tap[t] = wl.w + ps.w_tap[t] + cb * wl.block_stride + std::ptrdiff_t(c0) * wl.ld;
      }
      const int init = c0 > 0 || accumulate ? 2 : (bias_block ? 1 : 0);
      for (long long tile = t0; tile < t1; ++tile) {
        const auto [b, r, x, nx] = work.tile_of(ps, pi, tile);
        const T* abase = ps.a + b * ps.a_batch + r * ps.a_row + std::ptrdiff_t(x) * ps.a_col + c0;
        T* obase = ps.o + b * ps.o_batch + r * ps.o_row + std::ptrdiff_t(x) * ps.o_col + co0;
        const T* a_tap[16];
        for (int t = 0; t < ps.taps; ++t) a_tap[t] = abase + ps.a_tap[t];
        tiles.of_width(nx, NX1, NX2)(a_tap, w_tap, ps.taps, c1 - c0, ld, ps.a_col, obase, ps.o_col, lanes_here, bias_block, init);
      }
    }
  }
}

/// Runs forward-type passes on all threads. Ca: channels of A; Cb: output channels, in blocks of
/// NV registers; ACOL: every pass's a_col when it is a compile-time constant (one-register tiles),
/// else 0; bias: readable for whole blocks, or null; accumulate: add onto out instead of
/// overwriting it. Only the register tiles depend on ACOL (forward_tiles).
template <int NV, int ACOL, class T>
void run_forward(forward_pass<T>* passes, int npasses, int Ca, int Cb, const weight_layout<T>& wl,
                 const T* bias, bool accumulate, bool whole_blocks = false) {
  constexpr int NX1 = forward_tile_width<T>(NV), NX2 = forward_narrow_width<T>(NV);
#if ANISOCAP_BF16_DOT
  if constexpr (std::is_same_v<T, float> && simd::bf16_dot_available) {
    if (convolution_precision() == precision::bf16) {
      run_forward_bf16<NV>(passes, npasses, Ca, Cb, wl, bias, accumulate, whole_blocks, forward_tiles_bf16_of<NX1, NX2, NV, ACOL>);
      return;
    }
  }
#endif
  run_forward_with<NV>(passes, npasses, Ca, Cb, wl, bias, accumulate, whole_blocks, forward_tiles_of<NX1, NX2, NV, ACOL, T>);
}

// ---- weight-gradient pass ---------------------------------------------------------------------

/// gW[tap][ci][co] += sum over pixels (b, r, c) of A[a + b*a_batch + r*a_row + c*a_col + a_tap][ci]
/// * G[g + b*g_batch + r*g_row + c*g_col + g_tap][co]. G rows hold at least ldg >= Cb readable
/// values per pixel (channel-padded with zeros when Cb is not a multiple of the SIMD width).
template <class T>
struct weight_pass {
  const T* a = nullptr;
  std::ptrdiff_t a_batch = 0, a_row = 0, a_col = 0;
  const T* g = nullptr;
  std::ptrdiff_t g_batch = 0, g_row = 0, g_col = 0;
  int batch = 0, rows = 0, cols = 0;
  int taps = 0;
  std::ptrdiff_t a_tap[16] = {}, g_tap[16] = {};
};

/// CIB input channels x NV registers of output channels, accumulated over `nrows` rows of `cols`
/// pixels; gw points at [ci0][co0] of one tap (row stride ldw = Cb).
template <int CIB, int NV, class T>
inline void weight_tile(const T* const* a_rows, const T* const* g_rows, int nrows, std::ptrdiff_t a_off,
                        std::ptrdiff_t g_off, int cols, std::ptrdiff_t a_col, std::ptrdiff_t g_col, T* gw,
                        std::ptrdiff_t ldw, int last_lanes) {
  constexpr int W = lanes<T>;
  batch<T> acc[CIB][NV];
  tile_start<CIB, NV>(acc, gw, ldw, last_lanes, static_cast<const T*>(nullptr), 2);
  for (int r = 0; r < nrows; ++r) {
    const T* a = a_rows[r] + a_off;
    const T* g = g_rows[r] + g_off;
    for (int c = 0; c < cols; ++c, a += a_col, g += g_col) {
      batch<T> gv[NV];
      #pragma GCC unroll 32
      for (int v = 0; v < NV; ++v) gv[v] = batch<T>::load_unaligned(g + v * W);
      #pragma GCC unroll 32
      for (int i = 0; i < CIB; ++i) {
        const batch<T> x(a[i]);
        #pragma GCC unroll 32
        for (int v = 0; v < NV; ++v) acc[i][v] = xsimd::fma(x, gv[v], acc[i][v]);
      }
    }
  }
  tile_finish<CIB, NV>(acc, gw, ldw, last_lanes);
}

/// How run_weight cuts a weight pass into work items: (output-channel block, tap, range of input-
/// channel blocks), each sweeping every pixel in chunks of about 96 (whole rows when rows are
/// shorter, else row segments) whose output-gradient block stays in L1 while the item's
/// input-channel blocks run over it. Input channels go in blocks of CIB; a remainder of 4 or more
/// runs as one 4-channel block, the rest one channel at a time. `even`: segments of an even width.
///
/// `group_taps` (the bf16 pass): an item takes a group of taps instead of one (consecutive taps in
/// the order run_weight_bf16 gives them, which puts the taps that read the same rows together),
/// and runs them one after another on each chunk, so that each row its taps read is converted to
/// bf16 once (item_pairs) instead of once per tap. Groups are as few as give about one item per
/// thread: every further group converts its operands' rows again, which cost more on the
/// decoder's narrow layers than the finer balance gained (measured on 2 threads). Each item still
/// owns its part of gW and sums its pixels in the same order, so the result is the same either
/// way.
struct weight_items {
  int block, coblocks, last_lanes, CIB, ciblocks, quads, ci_items, groups, parts;
  long long items;
  int rows_total, seg, segs_per_row, chunk_rows;
  double work;
  /// One work item: output-channel block, taps t..t_end, and input-channel blocks k0..k1.
  struct item {
    int cb, t, k0, k1, t_end;
  };
  weight_items(int taps, int batch, int rows, int cols, int Ca, int Cb, int lanes, int NV, int cib, std::size_t value_bytes,
               bool even, bool group_taps = false)
      : block(NV * lanes), coblocks((Cb + block - 1) / block), last_lanes(Cb - (coblocks - 1) * block - (NV - 1) * lanes),
        CIB(cib), ciblocks(Ca / cib), quads(cib > 4 && Ca % cib >= 4 ? 1 : 0),
        ci_items(ciblocks + quads + (Ca % cib - 4 * quads)) {
    const int threads = omp_get_max_threads();
    groups = group_taps ? std::clamp((threads + coblocks - 1) / coblocks, 1, taps) : taps;
    // Split the input channels when (block, tap group) pairs alone would not feed every thread.
    const int pairs = coblocks * groups;
    const int wanted = group_taps ? threads : 8 * threads;
    parts = std::max(1, std::min(ci_items, (wanted + pairs - 1) / pairs));
    items = (long long)pairs * parts;
    rows_total = batch * rows;
    const int target = std::max(16, int((std::size_t(24) << 10) / (std::size_t(block) * value_bytes)));
    seg = std::min(cols, even ? (target + 1) & ~1 : target);
    segs_per_row = (cols + seg - 1) / seg;
    chunk_rows = seg < cols ? 1 : std::max(1, std::min(64, target / std::max(1, cols)));
    work = double(rows_total) * cols * taps * Ca * Cb;
  }
  item at(long long it, int taps) const {
    const int pair = int(it / parts), part = int(it % parts), group = pair % groups;
    return {pair / groups, taps * group / groups, ci_items * part / parts, ci_items * (part + 1) / parts, taps * (group + 1) / groups};
  }
  /// First input channel of input-channel block ck.
  int ci_start(int ck) const {
    if (ck < ciblocks) return ck * CIB;
    if (ck < ciblocks + quads) return ciblocks * CIB;
    return ciblocks * CIB + 4 * quads + (ck - ciblocks - quads);
  }
  /// Input channels of block ck: CIB, 4 or 1.
  int ci_width(int ck) const { return ck < ciblocks ? CIB : ck < ciblocks + quads ? 4 : 1; }
};

#if ANISOCAP_BF16_DOT

/// The bf16 weight-gradient tile: as weight_tile, two pixels per instruction. For each row r of the
/// chunk, a16[r] holds the pixel pairs' input channels [pair][nci][2] (this tile's channels start
/// at ci) and g16[r] their output-gradient block [pair][block][2].
template <int CIB, int NV>
inline void weight_tile_bf16(const std::uint16_t* const* a16, const std::uint16_t* const* g16, int nrows, int pairs, int nci,
                             int ci, float* gw, std::ptrdiff_t ldw, int last_lanes) {
  constexpr int W = lanes<float>;
  batch<float> acc[CIB][NV];
  tile_start<CIB, NV>(acc, gw, ldw, last_lanes, static_cast<const float*>(nullptr), 2);
  for (int r = 0; r < nrows; ++r) {
    const std::uint16_t* a = a16[r] + 2 * ci;
    const std::uint16_t* g = g16[r];
    for (int q = 0; q < pairs; ++q, a += 2 * nci, g += 2 * NV * W) {
      simd::bf16_pairs gv[NV];
      #pragma GCC unroll 32
      for (int v = 0; v < NV; ++v) gv[v] = simd::load_bf16_pairs(g + 2 * v * W);
      #pragma GCC unroll 32
      for (int i = 0; i < CIB; ++i) {
        const simd::bf16_pairs x = simd::broadcast_bf16_pair(a + 2 * i);
        #pragma GCC unroll 32
        for (int v = 0; v < NV; ++v) acc[i][v] = simd::dot_bf16_pairs(acc[i][v], x, gv[v]);
      }
    }
  }
  tile_finish<CIB, NV>(acc, gw, ldw, last_lanes);
}

/// The taps of one operand of a weight pass in classes that read the same pixels: taps whose
/// offsets differ by whole pass rows (a stride-1 kernel's rows, a strided kernel's rows `stride`
/// apart) read the rows of the class's first tap (its smallest offset), `shift` rows on.
struct tap_classes {
  /// The most rows a class spans beyond its first tap's.
  static constexpr int max_shift = 4;
  int count = 0;
  int of[16] = {}, shift[16] = {};
  std::ptrdiff_t offset[16] = {};
  tap_classes(const std::ptrdiff_t* tap, int taps, std::ptrdiff_t row) {
    int order[16];
    for (int t = 0; t < taps; ++t) order[t] = t;
    std::stable_sort(order, order + taps, [&](int x, int y) { return tap[x] < tap[y]; });
    for (int i = 0; i < taps; ++i) {
      const int t = order[i];
      int c = 0;
      for (; c < count; ++c) {
        const std::ptrdiff_t d = tap[t] - offset[c];
        if (d == 0 || (row > 0 && d % row == 0 && d / row <= max_shift)) break;
      }
      if (c == count) offset[count++] = tap[t];
      of[t] = c;
      shift[t] = tap[t] == offset[c] ? 0 : int((tap[t] - offset[c]) / row);
    }
  }
};

/// One operand's bf16 pixel pairs in a work item of the bf16 weight pass: for each class of the
/// item's taps, the rows the class's taps read, each converted once while the item sweeps the
/// pixels. Within an image the rows go round a ring of `ring` rows per class and segment: a chunk
/// converts only the rows the previous chunk did not (a kernel row shifted by one pass row reads
/// the rows the item's other tap of the class read the chunk before). A chunk that spans images
/// converts each (row, shift) it reads into rows of its own after the rings.
struct item_pairs {
  int classes = 0, segs = 1, ring = 1, stride = 1, rows_per_image = 1;
  int class_of[16] = {}, shift_of[16] = {}, shift_index[16] = {};  // per tap of the item: class slot, shift, its index in shifts
  int cls[16] = {}, smin[16] = {}, smax[16] = {}, nshift[16] = {}, shifts[16][16] = {};
  std::ptrdiff_t row_len = 0;
  std::uint16_t* buffer = nullptr;
  long long* tag = nullptr;  // [class][segment][ring slot]: the (image, row) a slot holds, -1 none
  int r0 = 0, nr = 0;
  bool one_image = true;

  /// The taps order[t_first..t_end) of an item, of an operand whose classes are `tc`.
  item_pairs(const tap_classes& tc, const int* order, int t_first, int t_end) {
    for (int i = t_first; i < t_end; ++i) {
      const int t = order[i], c = tc.of[t], s = tc.shift[t];
      int k = 0;
      while (k < classes && cls[k] != c) ++k;
      if (k == classes) cls[classes++] = c, smin[k] = s, smax[k] = s;
      smin[k] = std::min(smin[k], s), smax[k] = std::max(smax[k], s);
      int j = 0;
      while (j < nshift[k] && shifts[k][j] != s) ++j;
      if (j == nshift[k]) shifts[k][nshift[k]++] = s;
      class_of[i - t_first] = k, shift_of[i - t_first] = s, shift_index[i - t_first] = j;
    }
  }
  /// Ring rows per class and segment for chunks of up to chunk_rows rows (the most any class needs).
  int ring_rows(int chunk_rows) const {
    int n = 1;
    for (int k = 0; k < classes; ++k) n = std::max(n, chunk_rows + smax[k] - smin[k]);
    return n;
  }
  /// Rows per class and segment: the ring, then the rows of a chunk that spans images.
  int rows_per_class(int chunk_rows) const {
    int spanning = 0;
    for (int k = 0; k < classes; ++k) spanning = std::max(spanning, chunk_rows * nshift[k]);
    return ring_rows(chunk_rows) + spanning;
  }
  /// Sets up an item's sweep with chunks of up to chunk_rows rows and `segs_` segments of `pairs`
  /// pixel pairs of `width` channels: `buffer_` holds classes x segs x rows_per_class rows,
  /// `tag_` classes x segs x ring_rows values.
  void start(int chunk_rows, int segs_, int pairs, int width, int rows_per_image_, std::uint16_t* buffer_, long long* tag_) {
    segs = segs_, rows_per_image = rows_per_image_, row_len = std::ptrdiff_t(pairs) * width * 2;
    ring = ring_rows(chunk_rows), stride = rows_per_class(chunk_rows);
    buffer = buffer_, tag = tag_;
    std::fill(tag, tag + std::size_t(classes) * segs * ring, -1LL);
  }
  std::uint16_t* row(int k, int sg, int slot) const { return buffer + ((std::ptrdiff_t(k) * segs + sg) * stride + slot) * row_len; }
  /// Sets the chunk of nr_ pass rows from r0_.
  void chunk(int r0_, int nr_) {
    r0 = r0_, nr = nr_;
    one_image = r0 / rows_per_image == (r0 + nr - 1) / rows_per_image;
  }
  /// Converts the rows segment sg of the chunk needs and has not converted: convert(k, b, y, dst)
  /// writes class k's row y of image b.
  template <class Convert>
  void convert_rows(int sg, Convert&& convert) {
    for (int k = 0; k < classes; ++k) {
      long long* tags = tag + (std::ptrdiff_t(k) * segs + sg) * ring;
      if (one_image) {
        const int b = r0 / rows_per_image, y0 = r0 % rows_per_image;
        for (int y = y0 + smin[k]; y <= y0 + nr - 1 + smax[k]; ++y) {
          const long long key = (long long)b * (rows_per_image + tap_classes::max_shift + 1) + y;
          const int slot = y % ring;
          if (tags[slot] == key) continue;
          convert(k, b, y, row(k, sg, slot));
          tags[slot] = key;
        }
      } else {
        for (int r = 0; r < nr; ++r)
          for (int j = 0; j < nshift[k]; ++j) {
            const int R = r0 + r;
            convert(k, R / rows_per_image, R % rows_per_image + shifts[k][j], row(k, sg, ring + r * nshift[k] + j));
          }
      }
    }
  }
  /// The converted row that tap i of the item reads at chunk row r, segment sg.
  const std::uint16_t* at(int i, int sg, int r) const {
    const int k = class_of[i];
    if (one_image) return row(k, sg, (r0 % rows_per_image + r + shift_of[i]) % ring);
    return row(k, sg, ring + r * nshift[k] + shift_index[i]);
  }
};

/// run_weight in bf16 (see nn/precision.hpp): the same work items, each summing its pixels in the
/// same order. An item takes a group of taps that share classes (tap_classes) and converts the
/// rows of its input channels and of its output-gradient block that its taps read to bf16 pixel
/// pairs once each, in cache, as it sweeps the pixels (item_pairs); its tiles reduce two pixels per
/// instruction in FP32.
template <int NV, int CIB>
void run_weight_bf16(const weight_pass<float>& ps, int Ca, int Cb, float* gw) {
  constexpr int W = lanes<float>;
  const weight_items plan(ps.taps, ps.batch, ps.rows, ps.cols, Ca, Cb, W, NV, CIB, sizeof(float), true, true);
  const int block = plan.block, seg = plan.seg, chunk_rows = plan.chunk_rows;
  const tap_classes a_classes(ps.a_tap, ps.taps, ps.a_row), g_classes(ps.g_tap, ps.taps, ps.g_row);
  // The taps grouped by their classes, so that a group of consecutive taps shares them.
  int order[16];
  for (int t = 0; t < ps.taps; ++t) order[t] = t;
  std::stable_sort(order, order + ps.taps, [&](int x, int y) {
    return a_classes.of[x] * 16 + g_classes.of[x] < a_classes.of[y] * 16 + g_classes.of[y];
  });
#pragma omp parallel for schedule(dynamic, 1) if (plan.items > 1 && plan.work > double(1 << 16))
  for (long long it = 0; it < plan.items; ++it) {
    const auto [cb, t_first, k0, k1, t_end] = plan.at(it, ps.taps);
    if (k0 >= k1) continue;
    const int ci_lo = plan.ci_start(k0), ci_hi = k1 < plan.ci_items ? plan.ci_start(k1) : Ca;
    const int nci = ci_hi - ci_lo;
    const int co0 = cb * block;
    const int lanes_here = (cb == plan.coblocks - 1) ? plan.last_lanes : W;
    const int max_pairs = (seg + 1) / 2, segs = plan.segs_per_row;
    item_pairs ap(a_classes, order, t_first, t_end), gp(g_classes, order, t_first, t_end);
    const std::size_t a_rows = std::size_t(ap.classes) * segs * ap.rows_per_class(chunk_rows);
    const std::size_t g_rows = std::size_t(gp.classes) * segs * gp.rows_per_class(chunk_rows);
    const std::size_t a_tags = std::size_t(ap.classes) * segs * ap.ring_rows(chunk_rows);
    long long* tags = scratch<long long>(0, a_tags + std::size_t(gp.classes) * segs * gp.ring_rows(chunk_rows));
    ap.start(chunk_rows, segs, max_pairs, nci, ps.rows, scratch<std::uint16_t>(5, a_rows * max_pairs * nci * 2), tags);
    gp.start(chunk_rows, segs, max_pairs, block, ps.rows, scratch<std::uint16_t>(6, g_rows * max_pairs * block * 2), tags + a_tags);
    const std::uint16_t* a16[64];
    const std::uint16_t* g16[64];
    for (int r0 = 0; r0 < plan.rows_total; r0 += chunk_rows) {
      const int nr = std::min(chunk_rows, plan.rows_total - r0);
      ap.chunk(r0, nr);
      gp.chunk(r0, nr);
      for (int sg = 0; sg < segs; ++sg) {
        const int c0 = sg * seg, nc = std::min(seg, ps.cols - c0);
        const int pairs = (nc + 1) / 2;
        // The nc pixels of a row (col apart, n channels each) as pixel pairs [pair][n][2].
        const auto pairs_of_row = [&](const float* src, std::ptrdiff_t col, int n, std::uint16_t* d) {
          for (int q = 0; q < pairs; ++q) pixel_pair_to_bf16(src + 2 * q * col, col, 2 * q + 1 < nc, n, d + std::ptrdiff_t(q) * n * 2);
        };
        ap.convert_rows(sg, [&](int k, int b, int y, std::uint16_t* d) {
          pairs_of_row(ps.a + b * ps.a_batch + y * ps.a_row + c0 * ps.a_col + a_classes.offset[ap.cls[k]] + ci_lo, ps.a_col, nci, d);
        });
        gp.convert_rows(sg, [&](int k, int b, int y, std::uint16_t* d) {
          pairs_of_row(ps.g + b * ps.g_batch + y * ps.g_row + c0 * ps.g_col + g_classes.offset[gp.cls[k]] + co0, ps.g_col, block, d);
        });
        for (int i = t_first; i < t_end; ++i) {
          const int t = order[i];
          for (int r = 0; r < nr; ++r) {
            a16[r] = ap.at(i - t_first, sg, r);
            g16[r] = gp.at(i - t_first, sg, r);
          }
          for (int ck = k0; ck < k1; ++ck) {
            const int ci0 = plan.ci_start(ck), width = plan.ci_width(ck);
            float* dst = gw + (std::ptrdiff_t(t) * Ca + ci0) * Cb + co0;
            {
              // The next tile's gradient rows (Cb apart, often a page or more: no hardware
              // prefetcher follows them) asked for now; with few pixels a tile's sums take less
              // time than fetching the rows it adds them to.
              const int nck = ck + 1 < k1 ? ck + 1 : k0, ni = ck + 1 < k1 ? i : i + 1;
              if (ni < t_end)
                prefetch_rows(gw + (std::ptrdiff_t(order[ni]) * Ca + plan.ci_start(nck)) * Cb + co0, Cb, plan.ci_width(nck), NV * W);
            }
            if (width == CIB) {
              weight_tile_bf16<CIB, NV>(a16, g16, nr, pairs, nci, ci0 - ci_lo, dst, Cb, lanes_here);
            } else if (width == 4) {
              if constexpr (CIB > 4) weight_tile_bf16<4, NV>(a16, g16, nr, pairs, nci, ci0 - ci_lo, dst, Cb, lanes_here);
            } else {
              weight_tile_bf16<1, NV>(a16, g16, nr, pairs, nci, ci0 - ci_lo, dst, Cb, lanes_here);
            }
          }
        }
      }
    }
  }
}

#endif  // ANISOCAP_BF16_DOT

/// Accumulates a weight gradient gw [taps][Ca][Cb] over one pass on all threads. Work items are
/// (output-channel block, tap, range of input-channel blocks); each item sweeps every pixel and
/// owns its part of gw, so no reduction is needed and the result does not depend on the number of
/// threads. Items are handed out dynamically (a thread that the system slows down takes fewer).
template <int NV, class T>
void run_weight(const weight_pass<T>& ps, int Ca, int Cb, T* gw) {
  constexpr int W = lanes<T>;
  // Input channels per register block: CIB x NV accumulators (24 of the 32 AVX-512 registers:
  // 16 measured about 1.4x slower), NV loads and CIB broadcasts per pixel. A remainder of 4 or
  // more channels runs as one 4-channel block, the rest one channel at a time.
  constexpr int CIB = NV == 4 ? (accumulator_budget<T> >= 24 ? 6 : 4) : (accumulator_budget<T> / NV >= 8 ? 8 : 4);
#if ANISOCAP_BF16_DOT
  if constexpr (std::is_same_v<T, float> && simd::bf16_dot_available) {
    if (convolution_precision() == precision::bf16) {
      run_weight_bf16<NV, CIB>(ps, Ca, Cb, gw);
      return;
    }
  }
#endif
  const weight_items plan(ps.taps, ps.batch, ps.rows, ps.cols, Ca, Cb, W, NV, CIB, sizeof(T), false);
  const int block = plan.block, seg = plan.seg, chunk_rows = plan.chunk_rows;
#pragma omp parallel for schedule(dynamic, 1) if (plan.items > 1 && plan.work > double(1 << 16))
  for (long long it = 0; it < plan.items; ++it) {
    const auto [cb, t, k0, k1, t_end] = plan.at(it, ps.taps);  // one tap per item: t_end is t + 1
    const int co0 = cb * block;
    const int lanes_here = (cb == plan.coblocks - 1) ? plan.last_lanes : W;
    const T* a_rows[64];
    const T* g_rows[64];
    for (int r0 = 0; r0 < plan.rows_total; r0 += chunk_rows) {
      const int nr = std::min(chunk_rows, plan.rows_total - r0);
      for (int sg = 0; sg < plan.segs_per_row; ++sg) {
        const int c0 = sg * seg, nc = std::min(seg, ps.cols - c0);
        for (int r = 0; r < nr; ++r) {
          const int b = (r0 + r) / ps.rows, y = (r0 + r) % ps.rows;
          a_rows[r] = ps.a + b * ps.a_batch + y * ps.a_row + c0 * ps.a_col;
          g_rows[r] = ps.g + b * ps.g_batch + y * ps.g_row + c0 * ps.g_col;
        }
        for (int ck = k0; ck < k1; ++ck) {
          const int ci0 = plan.ci_start(ck), width = plan.ci_width(ck);
          T* dst = gw + (std::ptrdiff_t(t) * Ca + ci0) * Cb + co0;
          // The next tile's gradient rows, as in run_weight_bf16.
          if (ck + 1 < k1) prefetch_rows(gw + (std::ptrdiff_t(t) * Ca + plan.ci_start(ck + 1)) * Cb + co0, Cb, plan.ci_width(ck + 1), NV * W);
          if (width == CIB) {
            weight_tile<CIB, NV>(a_rows, g_rows, nr, ps.a_tap[t] + ci0, ps.g_tap[t] + co0, nc, ps.a_col, ps.g_col, dst, Cb, lanes_here);
          } else if (width == 4) {
            if constexpr (CIB > 4)
              weight_tile<4, NV>(a_rows, g_rows, nr, ps.a_tap[t] + ci0, ps.g_tap[t] + co0, nc, ps.a_col, ps.g_col, dst, Cb, lanes_here);
          } else {
            weight_tile<1, NV>(a_rows, g_rows, nr, ps.a_tap[t] + ci0, ps.g_tap[t] + co0, nc, ps.a_col, ps.g_col, dst, Cb, lanes_here);
          }
        }
      }
    }
  }
}

/// Whether run_weight_of exchanges the operands' roles for a pass of Ca x Cb channels (below).
template <class T>
constexpr bool exchanges_weight_roles(int Ca, int Cb) { return Cb < lanes<T> && Ca % lanes<T> == 0; }

/// Channels a pixel of the output-gradient operand (Cb channels) holds in a weight pass: whole
/// registers, or Cb itself where the pass exchanges the operands' roles and only broadcasts it.
template <class T, int Ca, int Cb>
inline constexpr int weight_gradient_channels = exchanges_weight_roles<T>(Ca, Cb) ? Cb : padded_channels<T>(Cb);

/// run_weight for a pass of Ca x Cb channels, with the operands' roles exchanged where
/// exchanges_weight_roles: Cb less than a register and Ca whole registers (the 12-channel output
/// layers). The tiles then hold Ca in their lanes with no lane left empty and broadcast Cb, fewer
/// loads per multiply-add, and gw is accumulated through its transpose [taps][Cb][Ca]; the Cb
/// operand is only broadcast then, so it needs no padding to whole registers. Each element still
/// sums the same pixels in the same order, so the gradient is the same bits either way.
template <int Ca, int Cb, class T>
void run_weight_of(const weight_pass<T>& ps, T* gw) {
  if constexpr (exchanges_weight_roles<T>(Ca, Cb)) {
    weight_pass<T> swapped = ps;
    swapped.a = ps.g, swapped.a_batch = ps.g_batch, swapped.a_row = ps.g_row, swapped.a_col = ps.g_col;
    swapped.g = ps.a, swapped.g_batch = ps.a_batch, swapped.g_row = ps.a_row, swapped.g_col = ps.a_col;
    for (int t = 0; t < ps.taps; ++t) swapped.a_tap[t] = ps.g_tap[t], swapped.g_tap[t] = ps.a_tap[t];
    const std::size_t per_tap = std::size_t(Ca) * Cb;
    T* transposed = scratch<T>(3, std::size_t(ps.taps) * per_tap);  // slot 3: the forward's padded bias, not alive here
    for (int t = 0; t < ps.taps; ++t)
      for (int i = 0; i < Ca; ++i)
        for (int o = 0; o < Cb; ++o) transposed[t * per_tap + std::size_t(o) * Ca + i] = gw[t * per_tap + std::size_t(i) * Cb + o];
    run_weight<vectors_per_tile<T>(Ca)>(swapped, Cb, Ca, transposed);
    for (int t = 0; t < ps.taps; ++t)
      for (int i = 0; i < Ca; ++i)
        for (int o = 0; o < Cb; ++o) gw[t * per_tap + std::size_t(i) * Cb + o] = transposed[t * per_tap + std::size_t(o) * Ca + i];
  } else {
    run_weight<vectors_per_tile<T>(Cb)>(ps, Ca, Cb, gw);
  }
}

// ---- data movement ----------------------------------------------------------------------------

/// The rows of a zero-padded dense buffer [B][Hp][Wp][ldc] around a source of B x height x width
/// pixels that lands at (b, y + top, x + left): rows and columns outside the source are zeroed,
/// and fill(b, y, x0, x1, d) writes the source pixels of row y that land in padded columns
/// x0..x1 (x1 exclusive), column x0 at d. Rows run in parallel.
template <class T, class Fill>
void pad_rows(int B, int height, int width, int top, int left, int Hp, int Wp, int ldc, T* dst, Fill&& fill) {
  const std::ptrdiff_t row = std::ptrdiff_t(Wp) * ldc;
#pragma omp parallel for schedule(static) if (std::size_t(B) * Hp * Wp * ldc > (1u << 16))
  for (int by = 0; by < B * Hp; ++by) {
    const int b = by / Hp, yp = by % Hp, y = yp - top;
    T* d = dst + std::ptrdiff_t(by) * row;
    if (y < 0 || y >= height) {
      std::memset(static_cast<void*>(d), 0, sizeof(T) * row);
      continue;
    }
    const int x0 = std::max(0, left), x1 = std::min(Wp, width + left);  // padded columns with data
    if (x0 > 0) std::memset(static_cast<void*>(d), 0, sizeof(T) * std::ptrdiff_t(x0) * ldc);
    fill(b, y, x0, x1, d + std::ptrdiff_t(x0) * ldc);
    if (x1 < Wp) std::memset(static_cast<void*>(d + std::ptrdiff_t(x1) * ldc), 0, sizeof(T) * std::ptrdiff_t(Wp - x1) * ldc);
  }
}

/// Copies x into a zero-padded dense buffer [B][Hp][Wp][ldc]: x(b, y, x) lands at
/// (b, y + top, x + left); rows/columns of x beyond the buffer are dropped; channels C..ldc are 0.
template <int C, class T>
void pad_copy(const tensor<C, T>& x, int top, int left, int Hp, int Wp, int ldc, T* dst) {
  pad_rows(x.batch(), x.height(), x.width(), top, left, Hp, Wp, ldc, dst, [&](int b, int y, int x0, int x1, T* d) {
    const T* s = x.pixel(b, y, x0 - left);
    if (ldc == C) {
      std::memcpy(static_cast<void*>(d), s, sizeof(T) * std::ptrdiff_t(x1 - x0) * C);
      return;
    }
    for (int xx = x0; xx < x1; ++xx, d += ldc, s += C) {
      std::memcpy(static_cast<void*>(d), s, sizeof(T) * C);
      std::memset(static_cast<void*>(d + C), 0, sizeof(T) * (ldc - C));
    }
  });
}

/// pad_copy of the channel concatenation [a, b] (ldc = C1 + C2, a's channels first) without
/// forming it: the same buffer, one copy instead of two. a and b have the same shape.
template <int C1, int C2, class T>
void pad_copy_concat(const tensor<C1, T>& a, const tensor<C2, T>& b, int top, int left, int Hp, int Wp, T* dst) {
  pad_rows(a.batch(), a.height(), a.width(), top, left, Hp, Wp, C1 + C2, dst, [&](int bi, int y, int x0, int x1, T* d) {
    const T* sa = a.pixel(bi, y, x0 - left);
    const T* sb = b.pixel(bi, y, x0 - left);
    for (int xx = x0; xx < x1; ++xx, sa += C1, sb += C2, d += C1 + C2) {
      std::memcpy(static_cast<void*>(d), sa, sizeof(T) * C1);
      std::memcpy(static_cast<void*>(d + C1), sb, sizeof(T) * C2);
    }
  });
}

/// Packs weights [taps][Ci][Co] for run_forward as [cb][tap][r][block]: blocks of `block` output
/// columns, each one contiguous stream (no 4 KiB strides that thrash the TLB on wide layers), and
/// 64-byte aligned. Plain: rows r = ci, columns co. `transpose`: rows r = co, columns ci (the
/// kernel of an input-gradient pass). `flip`: tap t goes to taps-1-t (the 180-degree rotation of a
/// stride-1 input-gradient pass). Columns beyond the matrix are zero.
template <class T>
weight_layout<T> pack_weights(const T* w, int taps, int Ci, int Co, bool transpose, bool flip, int block, T* dst) {
  const int rows = transpose ? Co : Ci, cols = transpose ? Ci : Co;
  const int blocks = (cols + block - 1) / block;
  const std::ptrdiff_t tap_stride = std::ptrdiff_t(rows) * block;
#pragma omp parallel for schedule(static) if (std::size_t(taps) * Ci * Co > (1u << 16))
  for (int job = 0; job < blocks * taps; ++job) {
    const int cb = job / taps, t = job % taps;
    const int td = flip ? taps - 1 - t : t;
    const int c0 = cb * block, n = std::min(block, cols - c0);
    T* d = dst + (std::ptrdiff_t(cb) * taps + td) * tap_stride;
    const T* s = w + std::ptrdiff_t(t) * Ci * Co;
    if (!transpose) {
      for (int r = 0; r < rows; ++r) {
        std::memcpy(static_cast<void*>(d + std::ptrdiff_t(r) * block), s + std::ptrdiff_t(r) * Co + c0, sizeof(T) * n);
        std::memset(static_cast<void*>(d + std::ptrdiff_t(r) * block + n), 0, sizeof(T) * (block - n));
      }
    } else {
      // d[r][j] = s[c0 + j][r], in panels of 64 rows so the written lines stay in L1.
      for (int r0 = 0; r0 < rows; r0 += 64) {
        const int r1 = std::min(rows, r0 + 64);
        for (int j = 0; j < block; ++j) {
          if (j < n) {
            const T* src = s + std::ptrdiff_t(c0 + j) * Co;
            for (int r = r0; r < r1; ++r) d[std::ptrdiff_t(r) * block + j] = src[r];
          } else {
            for (int r = r0; r < r1; ++r) d[std::ptrdiff_t(r) * block + j] = T(0);
          }
        }
      }
    }
  }
  return {dst, block, tap_stride, std::ptrdiff_t(taps) * tap_stride};
}

/// grad_bias[c] += sum over pixels of g[c]. Rows are split into fixed per-thread ranges whose
/// partial sums are added in thread order, so the result is the same on every run.
template <int C, class T>
void bias_gradient(const tensor<C, T>& g, T* grad_bias) {
  const int rows = g.batch() * g.height();
  const int threads = g.size() > (1u << 16) ? omp_get_max_threads() : 1;
  T* partial = scratch<T>(5, std::size_t(threads) * C);
  std::fill(partial, partial + std::size_t(threads) * C, T(0));  // a thread the runtime withholds adds 0
#pragma omp parallel num_threads(threads)
  {
    const int nt = omp_get_num_threads(), id = omp_get_thread_num();
    // Each channel's lane adds the pixels in order from 0, as a scalar loop would, so the sums
    // are the same bits; the last register of a channel count that is not whole is a masked load.
    constexpr int W = lanes<T>, NB = (C + W - 1) / W, tail = C - (NB - 1) * W;
    batch<T> acc[NB];
    for (auto& a : acc) a = batch<T>(T(0));
    for (int r = rows * id / nt; r < rows * (id + 1) / nt; ++r) {
      const T* p = g.pixel(r / g.height(), r % g.height(), 0);
      for (int x = 0; x < g.width(); ++x, p += C) {
        #pragma GCC unroll 16
        for (int v = 0; v < NB - 1; ++v) acc[v] += batch<T>::load_unaligned(p + v * W);
        acc[NB - 1] += tail == W ? batch<T>::load_unaligned(p + (NB - 1) * W) : simd::load_first<batch<T>>(p + (NB - 1) * W, tail);
      }
    }
    T* sum = partial + std::size_t(id) * C;
    for (int v = 0; v < NB; ++v)
      if (v < NB - 1 || tail == W) acc[v].store_unaligned(sum + v * W);
      else simd::store_first(sum + v * W, acc[v], tail);
  }
  for (int t = 0; t < threads; ++t)
    for (int c = 0; c < C; ++c) grad_bias[c] += partial[std::size_t(t) * C + c];
}

}  // namespace anisocap::nn::detail::conv
