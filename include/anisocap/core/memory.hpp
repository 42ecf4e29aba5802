#pragma once
/// @file
/// Aligned buffers and the arena that a training step reuses, so that a fixed-size network
/// allocates nothing after its first step.
#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <new>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

#include "anisocap/core/simd.hpp"

namespace anisocap {

/// Counts calls to the system allocator made through this header (aligned_allocate), so tests can
/// prove that a steady-state step allocates nothing.
inline std::atomic<std::size_t>& system_allocation_count() {
  static std::atomic<std::size_t> count{0};
  return count;
}

/// The size of a transparent huge page (x86-64 Linux).
inline constexpr std::size_t huge_page_bytes = std::size_t(2) << 20;

/// Allocations of at least this many bytes are aligned to a huge page, rounded up to whole ones and
/// advised MADV_HUGEPAGE (Linux; the kernel's transparent huge pages in madvise mode, Debian's
/// default, otherwise give 4 KiB pages): weights, optimiser moments and arenas streamed every step
/// then cost one TLB entry per 2 MiB instead of 512. Smaller buffers keep 4 KiB pages: on a huge page
/// the physical address equals the virtual one modulo 2 MiB, so the planes of a map with a
/// power-of-two stride all fall in the same sets of the physically indexed L2 and evict one another
/// (a 2 MiB threshold made the refine stage 20% slower). Measured in bench/README.md, "Huge pages".
inline constexpr std::size_t huge_page_min_bytes = std::size_t(16) << 20;

namespace memory_detail {
/// What aligned_deleter needs, stored just below an aligned_allocate block's start: where the
/// system's allocation begins and, for a mapping, its length (0: from std::calloc).
struct block_header {
  void* base;
  std::size_t mapped;
};
}  // namespace memory_detail

/// Allocates `bytes` of zero-filled memory aligned to simd::alignment (64), or to huge_page_bytes
/// when at least huge_page_min_bytes (then advised MADV_HUGEPAGE); throws std::bad_alloc on
/// failure. Free it with aligned_deleter. The memory comes straight from the kernel for a large
/// block (an anonymous mapping, Linux) and from std::calloc otherwise, which both leave pages fresh
/// from the kernel untouched (already zero): a large buffer that is never written, such as the
/// gradients of a network that only infers, costs no page faults, and a written one is faulted in
/// once, by its first writer, on huge pages.
inline void* aligned_allocate(std::size_t bytes) {
  using memory_detail::block_header;
  const std::size_t align = bytes >= huge_page_min_bytes ? huge_page_bytes : simd::alignment;
  std::size_t rounded = (bytes + align - 1) / align * align;
  if (rounded == 0) rounded = simd::alignment;
  const std::size_t total = rounded + align + sizeof(block_header);  // room for the header below the aligned start
  block_header header{nullptr, 0};
#if defined(__linux__)
  if (align == huge_page_bytes) {
    void* m = ::mmap(nullptr, total, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (m == MAP_FAILED) throw std::bad_alloc();
    header = {m, total};
  }
#endif
  if (!header.base) {
    header.base = std::calloc(1, total);
    if (!header.base) throw std::bad_alloc();
  }
  const std::uintptr_t start = (reinterpret_cast<std::uintptr_t>(header.base) + sizeof(block_header) + align - 1) / align * align;
  void* p = reinterpret_cast<void*>(start);
  std::memcpy(static_cast<std::byte*>(p) - sizeof(block_header), &header, sizeof(block_header));
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  if (align == huge_page_bytes) ::madvise(p, rounded, MADV_HUGEPAGE);  // advice only: failure is harmless
#endif
  system_allocation_count().fetch_add(1, std::memory_order_relaxed);
  return p;
}

/// Deleter for aligned_allocate.
struct aligned_deleter {
  void operator()(void* p) const noexcept {
    if (!p) return;
    memory_detail::block_header header;
    std::memcpy(&header, static_cast<std::byte*>(p) - sizeof(header), sizeof(header));
#if defined(__linux__)
    if (header.mapped) {
      ::munmap(header.base, header.mapped);
      return;
    }
#endif
    std::free(header.base);
  }
};

/// An owning, 64-byte-aligned, zero-initialised array of T (T trivially copyable).
template <class T>
class aligned_buffer {
 public:
  aligned_buffer() = default;
  explicit aligned_buffer(std::size_t n) : size_(n), data_(static_cast<T*>(aligned_allocate(n * sizeof(T)))) {}  // zero-filled
  aligned_buffer(const aligned_buffer& o) : aligned_buffer(o.size_) {
    if (size_) std::memcpy(static_cast<void*>(data_.get()), o.data(), size_ * sizeof(T));
  }
  aligned_buffer& operator=(const aligned_buffer& o) {
    if (this != &o) { aligned_buffer t(o); *this = std::move(t); }
    return *this;
  }
  aligned_buffer(aligned_buffer&&) noexcept = default;
  aligned_buffer& operator=(aligned_buffer&&) noexcept = default;

  T* data() noexcept { return data_.get(); }
  const T* data() const noexcept { return data_.get(); }
  std::size_t size() const noexcept { return size_; }
  bool empty() const noexcept { return size_ == 0; }
  T& operator[](std::size_t i) noexcept { return data_.get()[i]; }
  const T& operator[](std::size_t i) const noexcept { return data_.get()[i]; }
  T* begin() noexcept { return data(); }
  T* end() noexcept { return data() + size_; }
  const T* begin() const noexcept { return data(); }
  const T* end() const noexcept { return data() + size_; }

 private:
  std::size_t size_ = 0;
  std::unique_ptr<T, aligned_deleter> data_;
};

/// A bump allocator over large aligned blocks. `reset()` makes all memory reusable without
/// returning it to the system; after one pass has sized the arena, identical passes allocate
/// nothing (the blocks are merged into one of the high-water size on reset).
class arena {
 public:
  /// Size of the first block an empty arena takes from the system.
  static constexpr std::size_t minimum_block_bytes = std::size_t(1) << 18;

  explicit arena(std::size_t initial_bytes = 0) {
    if (initial_bytes) blocks_.push_back(block(initial_bytes));
  }

  /// Returns `bytes` of 64-byte-aligned, uninitialised memory valid until the next reset().
  void* allocate(std::size_t bytes) {
    bytes = (bytes + simd::alignment - 1) / simd::alignment * simd::alignment;
    if (blocks_.empty() || blocks_.back().used + bytes > blocks_.back().capacity) {
      // Geometric growth keeps the first (sizing) pass to a few system allocations.
      const std::size_t grown = blocks_.empty() ? minimum_block_bytes : 2 * blocks_.back().capacity;
      blocks_.push_back(block(std::max(bytes, grown)));
    }
    auto& b = blocks_.back();
    void* p = b.memory.get() + b.used;
    b.used += bytes;
    in_use_ += bytes;
    high_water_ = std::max(high_water_, in_use_);
    return p;
  }

  template <class T>
  T* allocate_array(std::size_t n) { return static_cast<T*>(allocate(n * sizeof(T))); }

  /// Frees everything at once; keeps (and consolidates) the memory for the next pass.
  void reset() {
    if (blocks_.size() > 1) {
      // One block of the high-water size holds the next identical pass without a new allocation
      // (a pass only bumps, so its peak is its total; one block wastes nothing at block ends).
      blocks_.clear();
      blocks_.push_back(block(high_water_));
    } else if (!blocks_.empty()) {
      blocks_.back().used = 0;
    }
    in_use_ = 0;
  }

  /// Largest number of bytes in use at once since construction.
  std::size_t high_water_bytes() const noexcept { return high_water_; }
  /// Bytes held from the system.
  std::size_t capacity_bytes() const noexcept {
    std::size_t c = 0;
    for (auto& b : blocks_) c += b.capacity;
    return c;
  }

 private:
  struct block {
    explicit block(std::size_t bytes)
        : capacity(bytes), memory(static_cast<std::byte*>(aligned_allocate(bytes))) {}
    std::size_t capacity;
    std::size_t used = 0;
    std::unique_ptr<std::byte, aligned_deleter> memory;
  };
  std::vector<block> blocks_;
  std::size_t in_use_ = 0;
  std::size_t high_water_ = 0;
};

}  // namespace anisocap
