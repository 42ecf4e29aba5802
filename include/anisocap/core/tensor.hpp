#pragma once
/// @file
/// `tensor<C, T>`: batch x height x width x C with the channel count C fixed at compile time.
///
/// Layout: NHWC, channels innermost and contiguous (a pixel's C values are adjacent), so a
/// convolution's inner loop runs over channels with full SIMD registers; row and batch strides are
/// explicit so a tile of a larger tensor is a view without copies. Data are 64-byte aligned when
/// owned or taken from an arena. A tensor is a cheap handle: copying it shares the data (as a
/// PyTorch tensor does); `clone()` copies.
#include <cassert>
#include <cstddef>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>

#include "anisocap/core/memory.hpp"

namespace anisocap {

/// A 4-d tensor batch x height x width x C, channels innermost.
template <int C, class T = float>
class tensor {
  static_assert(C > 0, "channel count must be positive");

 public:
  using value_type = T;
  static constexpr int channels = C;

  tensor() = default;

  /// Owning, zero-filled tensor.
  tensor(int batch, int height, int width) : batch_(batch), height_(height), width_(width) {
    check_shape();
    std::size_t n = dense_size();
    owner_ = std::shared_ptr<void>(aligned_allocate(n * sizeof(T)), aligned_deleter{});  // zero-filled
    data_ = static_cast<T*>(owner_.get());
    set_dense_strides();
  }

  /// Tensor in arena memory (uninitialised; valid until the arena's reset()).
  tensor(arena& a, int batch, int height, int width) : batch_(batch), height_(height), width_(width) {
    check_shape();
    data_ = a.allocate_array<T>(dense_size());
    set_dense_strides();
  }

  /// Non-owning view of external dense NHWC memory.
  static tensor wrap(T* data, int batch, int height, int width) {
    tensor t;
    t.batch_ = batch; t.height_ = height; t.width_ = width;
    t.check_shape();
    t.data_ = data;
    t.set_dense_strides();
    return t;
  }

  int batch() const noexcept { return batch_; }
  int height() const noexcept { return height_; }
  int width() const noexcept { return width_; }
  /// Elements between consecutive rows (>= width * C).
  std::ptrdiff_t row_stride() const noexcept { return row_stride_; }
  /// Elements between consecutive batch entries.
  std::ptrdiff_t batch_stride() const noexcept { return batch_stride_; }
  /// Number of logical elements.
  std::size_t size() const noexcept { return std::size_t(batch_) * height_ * width_ * C; }
  bool empty() const noexcept { return size() == 0; }
  /// True when rows follow each other without gaps (the whole tensor is one dense array).
  bool is_dense() const noexcept {
    return row_stride_ == std::ptrdiff_t(width_) * C && batch_stride_ == row_stride_ * height_;
  }

  T* data() noexcept { return data_; }
  const T* data() const noexcept { return data_; }
  /// Pointer to the C channels of pixel (b, y, x).
  T* pixel(int b, int y, int x) noexcept { return data_ + b * batch_stride_ + y * row_stride_ + std::ptrdiff_t(x) * C; }
  const T* pixel(int b, int y, int x) const noexcept { return data_ + b * batch_stride_ + y * row_stride_ + std::ptrdiff_t(x) * C; }
  T& operator()(int b, int y, int x, int c) noexcept { return pixel(b, y, x)[c]; }
  const T& operator()(int b, int y, int x, int c) const noexcept { return pixel(b, y, x)[c]; }

  /// View of the window [y0, y0+h) x [x0, x0+w) of every batch entry (no copy).
  tensor tile(int y0, int x0, int h, int w) const {
    if (y0 < 0 || x0 < 0 || h < 0 || w < 0 || y0 + h > height_ || x0 + w > width_)
      throw std::out_of_range("tensor::tile: window outside the tensor");
    tensor t = *this;
    t.data_ = const_cast<T*>(pixel(0, y0, x0));
    t.height_ = h; t.width_ = w;
    return t;
  }

  /// View of batch entries [b0, b0+n).
  tensor slice_batch(int b0, int n) const {
    if (b0 < 0 || n < 0 || b0 + n > batch_) throw std::out_of_range("tensor::slice_batch: range outside the tensor");
    tensor t = *this;
    t.data_ = const_cast<T*>(pixel(b0, 0, 0));
    t.batch_ = n;
    return t;
  }

  /// Dense owning copy.
  tensor clone() const {
    tensor t(batch_, height_, width_);
    t.copy_from(*this);
    return t;
  }

  /// Copies values from a tensor of the same shape (either may be a view).
  void copy_from(const tensor& o) {
    if (o.batch_ != batch_ || o.height_ != height_ || o.width_ != width_)
      throw std::invalid_argument("tensor::copy_from: shape mismatch");
    for (int b = 0; b < batch_; ++b)
      for (int y = 0; y < height_; ++y)
        std::memcpy(static_cast<void*>(pixel(b, y, 0)), o.pixel(b, y, 0), sizeof(T) * width_ * C);
  }

  /// Sets every element to v.
  void fill(T v) {
    for (int b = 0; b < batch_; ++b)
      for (int y = 0; y < height_; ++y) {
        T* p = pixel(b, y, 0);
        for (int i = 0; i < width_ * C; ++i) p[i] = v;
      }
  }

  /// Same shape test.
  template <int C2, class T2>
  bool same_spatial_shape(const tensor<C2, T2>& o) const noexcept {
    return batch_ == o.batch() && height_ == o.height() && width_ == o.width();
  }

 private:
  void check_shape() const {
    if (batch_ < 0 || height_ < 0 || width_ < 0)
      throw std::invalid_argument("tensor: negative dimension");
  }
  std::size_t dense_size() const { return std::size_t(batch_) * height_ * width_ * C; }
  void set_dense_strides() {
    row_stride_ = std::ptrdiff_t(width_) * C;
    batch_stride_ = row_stride_ * height_;
  }

  int batch_ = 0, height_ = 0, width_ = 0;
  std::ptrdiff_t row_stride_ = 0, batch_stride_ = 0;
  T* data_ = nullptr;
  std::shared_ptr<void> owner_;
};

}  // namespace anisocap
