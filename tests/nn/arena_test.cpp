// The arena test: a small fixed-size network (convolutions included) trained with Adam allocates nothing after
// its first step, neither through the library's aligned allocator nor through operator new (this
// file replaces the global operator new to count every heap allocation of the program).
#include <doctest/doctest.h>

#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>
#include <vector>

#include "anisocap/nn/nn.hpp"  // the umbrella: it must compile on its own
#include "layer_check.hpp"

namespace {
std::atomic<std::size_t> heap_allocations{0};
}

void* operator new(std::size_t n) {
  heap_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
// GCC cannot tell that these are the replacements matching the operator new above.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

using namespace anisocap;

namespace {

/// Uses every layer of the engine: a 3x3 convolution, per-pixel FC, instance norm, leaky ReLU, a
/// global-feature track (spatial mean, FC, bias broadcast), max over images (sets of 2), concat,
/// a transposed convolution beside nearest upsampling + FC, add, batch norm, SELU, tanh.
struct small_network {
  nn::conv2d<4, 8, 3, 1, 1> conv_in{"conv_in"};
  nn::linear<8, 16> fc_in{"fc_in", 1};
  nn::instance_norm<16> norm{"norm"};
  nn::linear<16, 16> fc_global{"fc_global", 2};
  nn::conv_transpose2d<32, 8> up_conv{"up_conv"};
  nn::linear<32, 8> fc_mix{"fc_mix", 3};
  nn::batch_norm<8> bn{"bn"};
  nn::linear<8, 3> fc_out{"fc_out", 4};

  small_network() {
    nn::he_uniform(conv_in.weight, 9 * 4, 5);
    nn::he_uniform(up_conv.weight, 4 * 32, 6);
  }

  ad::variable<3> operator()(ad::tape& t, const ad::variable<4>& x) {
    auto h = nn::leaky_relu(t, norm(t, fc_in(t, conv_in(t, x))), 0.2f);
    auto global = fc_global(t, nn::spatial_mean(t, h));
    h = nn::add_channel_bias(t, h, global);
    auto fused = nn::max_over_images(t, h, 2);
    auto cat = nn::concat(t, fused, nn::add(t, fused, fused));
    auto up = nn::add(t, up_conv(t, cat), fc_mix(t, nn::upsample_nearest2x(t, cat)));
    return nn::tanh(t, fc_out(t, nn::selu(t, bn(t, up))));
  }
  template <class F>
  void for_each_parameter(F&& f) {
    conv_in.for_each_parameter(f);
    fc_in.for_each_parameter(f);
    norm.for_each_parameter(f);
    fc_global.for_each_parameter(f);
    up_conv.for_each_parameter(f);
    fc_mix.for_each_parameter(f);
    bn.for_each_parameter(f);
    fc_out.for_each_parameter(f);
  }
};

}  // namespace

TEST_CASE("arena: after the first step, a training step allocates nothing") {
  nn::random_generator g(31);
  // Large enough that the element-wise layers run their OpenMP regions.
  auto input = test_nn::random_tensor<4, float>(g, 4, 24, 24);
  auto target = test_nn::random_tensor<3, float>(g, 2, 48, 48, 0.5);
  small_network net;
  nn::adam optimiser(nn::learning_rate_schedule::constant(1e-2));
  optimiser.add_parameters(net);
  ad::tape t;

  auto train_step = [&] {
    t.clear();
    auto y = net(t, t.leaf(input));
    // L2 loss: d/dy 0.5 |y - target|^2 = y - target.
    double loss = 0;
    for (std::size_t i = 0; i < y.value.size(); ++i) {
      const float d = y.value.data()[i] - target.data()[i];
      y.grad.data()[i] = d;
      loss += 0.5 * double(d) * d;
    }
    t.backward();
    optimiser.step();
    return loss;
  };

  const double first_loss = train_step();
  train_step();  // the arena consolidates its blocks on the reset of the second step
  const std::size_t aligned_before = system_allocation_count().load();
  const std::size_t heap_before = heap_allocations.load();
  const std::size_t capacity = t.memory().capacity_bytes();
  double loss = 0;
  for (int i = 0; i < 5; ++i) loss = train_step();
  const std::size_t aligned_after = system_allocation_count().load();
  const std::size_t heap_after = heap_allocations.load();
  CHECK(aligned_before > 0);
  CHECK(heap_before > 0);  // the counters count: the first step did allocate
  CHECK(aligned_after == aligned_before);
  CHECK(heap_after == heap_before);
  CHECK(t.memory().capacity_bytes() == capacity);
  CHECK(loss < first_loss);  // and it is training

  // The heap counter sees an ordinary allocation (so the equality above is meaningful).
  const std::size_t before = heap_allocations.load();
  auto* probe = new std::vector<int>(100);
  CHECK(heap_allocations.load() >= before + 2);
  delete probe;
}

TEST_CASE("aligned_allocate: large buffers start on a huge page, small ones on a cache line") {
  // A buffer of huge_page_min_bytes or more is huge-page aligned (so that MADV_HUGEPAGE covers whole
  // pages); one just below stays cache-line aligned, and both are usable to their last byte.
  for (const std::size_t bytes : {huge_page_min_bytes, huge_page_min_bytes + 12345, huge_page_min_bytes - 64, std::size_t(1000)}) {
    aligned_buffer<std::byte> b(bytes);
    const auto address = reinterpret_cast<std::uintptr_t>(b.data());
    CHECK(address % simd::alignment == 0);
    if (bytes >= huge_page_min_bytes) CHECK(address % huge_page_bytes == 0);
    b[bytes - 1] = std::byte{7};
    CHECK(b[bytes - 1] == std::byte{7});
    CHECK(b[0] == std::byte{0});  // zero-initialised
  }
  // Memory handed back and taken again is zero again, from calloc's heap and from a mapping alike.
  for (const std::size_t bytes : {std::size_t(1000), huge_page_min_bytes}) {
    for (int round = 0; round < 2; ++round) {
      aligned_buffer<std::byte> b(bytes);
      std::size_t nonzero = 0;
      for (std::size_t i = 0; i < bytes; i += 997) nonzero += b[i] != std::byte{0};
      CHECK(nonzero == 0);
      std::memset(b.data(), 0xAB, bytes);
    }
  }
}
