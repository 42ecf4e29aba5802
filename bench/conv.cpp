// Convolution benchmark: every convolution of the paper-width auto-encoder at 256 x 256, the
// compact auto-encoder's decoder and a representative set of the estimator's (docs/method.md
// section 7), forward / backward-input / backward-weight, on 1 and 2 threads, as GFLOP/s and as
// a fraction of the FP32 FMA peak measured in the same run; beside it an im2col + Eigen GEMM
// version of the same passes, and a full forward + backward step of the auto-encoder's decoder
// on one 256 x 256 tile. Where the build has AVX-512 BF16, the
// three passes and the decoder step again in bf16 (anisocap_bf16/...; the
// peak fraction stays relative to the FP32 FMA peak, of which bf16 can reach 2).
//
//   anisocap_bench_conv --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
//
// Counters: gflops, peak_fraction (of the peak on the same number of threads).
#include <benchmark/benchmark.h>
#include <omp.h>
#include <sys/resource.h>

// GCC 12 reports Eigen's AVX-512 transposes (inlined here) as maybe-uninitialized: a known false positive.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
// GCC 12 also misreports std::string concatenation (benchmark names) under -Wrestrict (PR 105329).
#pragma GCC diagnostic ignored "-Wrestrict"
#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "anisocap/core/simd.hpp"
#include "anisocap/nn/conv_transpose.hpp"
#include "anisocap/nn/precision.hpp"

using namespace anisocap;

namespace {

// ---- FP32 FMA peak ----------------------------------------------------------------------------

/// FLOP/s of independent FMA chains (enough accumulators to hide the FMA latency on both pipes)
/// on `threads` threads.
double fma_peak(int threads, double seconds = 0.25) {
  using B = simd::batch<float>;
  constexpr int A = 16;
  const long iterations = 4'000'000;
  double best = 0;
  auto start = std::chrono::steady_clock::now();
  do {
    const auto t0 = std::chrono::steady_clock::now();
#pragma omp parallel num_threads(threads)
    {
      B acc[A];
      for (int a = 0; a < A; ++a) acc[a] = B(1.0f + 0.01f * a);
      const B x(0.999999f), y(1e-6f);
      for (long i = 0; i < iterations; ++i)
        for (int a = 0; a < A; ++a) acc[a] = xsimd::fma(acc[a], x, y);
      // An opaque use of every chain (a volatile store alone let GCC drop the loop body).
      for (int a = 0; a < A; ++a) benchmark::DoNotOptimize(acc[a]);
    }
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    best = std::max(best, double(threads) * iterations * A * B::size * 2 / dt);
  } while (std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() < seconds);
  return best;
}

double peak_flops[3] = {0, 0, 0};  // index: threads

void set_counters(benchmark::State& state, double flops, int threads) {
  state.counters["gflops"] = benchmark::Counter(flops / 1e9, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["peak_fraction"] =
      benchmark::Counter(flops / peak_flops[threads], benchmark::Counter::kIsIterationInvariantRate);
}

void fill(float* p, std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (std::size_t i = 0; i < n; ++i) p[i] = u(rng);
}
template <int C>
tensor<C> random_tensor(int b, int h, int w, unsigned seed) {
  tensor<C> t(b, h, w);
  fill(t.data(), t.size(), seed);
  return t;
}

enum pass_kind { forward = 0, backward_input = 1, backward_weight = 2 };
const char* pass_name[] = {"fwd", "bwd_in", "bwd_w"};

// ---- anisocap kernels -------------------------------------------------------------------------

template <int Cin, int Cout, int K, int S, int P>
void conv_case(benchmark::State& state, int n, int threads, pass_kind pass, nn::precision precision) {
  omp_set_num_threads(threads);
  nn::precision_scope scope(precision);
  const int m = nn::conv2d_output_size<K, S, P>(n);
  auto in = random_tensor<Cin>(1, n, n, 1);
  auto gout = random_tensor<Cout>(1, m, m, 2);
  tensor<Cout> out(1, m, m);
  tensor<Cin> gin(1, n, n);
  // Aligned like nn::parameter storage, which is what the layers pass.
  aligned_buffer<float> w(static_cast<std::size_t>(K * K * Cin * Cout)), b(Cout), gw(w.size()), gb(Cout);
  fill(w.data(), w.size(), 3);
  for (auto _ : state) {
    if (pass == forward) nn::conv2d_forward<Cin, Cout, K, S, P>(in, w.data(), b.data(), out);
    if (pass == backward_input) nn::conv2d_backward_input<Cin, Cout, K, S, P>(gout, w.data(), gin);
    if (pass == backward_weight) nn::conv2d_backward_weight<Cin, Cout, K, S, P>(in, gout, gw.data(), gb.data());
    benchmark::ClobberMemory();
  }
  set_counters(state, 2.0 * m * m * K * K * Cin * Cout, threads);
}

template <int Cin, int Cout>
void conv_transpose_case(benchmark::State& state, int n, int threads, pass_kind pass, nn::precision precision) {
  omp_set_num_threads(threads);
  nn::precision_scope scope(precision);
  auto in = random_tensor<Cin>(1, n, n, 1);
  auto gout = random_tensor<Cout>(1, 2 * n, 2 * n, 2);
  tensor<Cout> out(1, 2 * n, 2 * n);
  tensor<Cin> gin(1, n, n);
  aligned_buffer<float> w(std::size_t(16) * Cin * Cout), b(Cout), gw(w.size()), gb(Cout);
  fill(w.data(), w.size(), 3);
  for (auto _ : state) {
    if (pass == forward) nn::conv_transpose2d_forward<Cin, Cout>(in, w.data(), b.data(), out);
    if (pass == backward_input) nn::conv_transpose2d_backward_input<Cin, Cout>(gout, w.data(), gin);
    if (pass == backward_weight) nn::conv_transpose2d_backward_weight<Cin, Cout>(in, gout, gw.data(), gb.data());
    benchmark::ClobberMemory();
  }
  set_counters(state, 2.0 * n * n * 16 * Cin * Cout, threads);
}

// ---- im2col + Eigen GEMM baseline -------------------------------------------------------------
// What a careful user would write with the libraries at hand: unfold the K x K windows into a
// matrix (im2col), one Eigen GEMM, fold back (col2im) where the pass scatters. A transposed
// convolution is the adjoint of a convolution: its forward is the convolution's input-gradient
// pass (GEMM + col2im), its input gradient the convolution's forward.

using matrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// cols[(oy*Wo+ox)][(kh*K+kw)*C + c] = x[oy*S-P+kh][ox*S-P+kw][c] (0 outside).
void im2col(const float* x, int H, int W, int C, int K, int S, int P, int Ho, int Wo, matrix& cols) {
  cols.resize(Ho * Wo, K * K * C);
#pragma omp parallel for
  for (int oy = 0; oy < Ho; ++oy)
    for (int ox = 0; ox < Wo; ++ox) {
      float* row = cols.data() + std::ptrdiff_t(oy * Wo + ox) * K * K * C;
      for (int kh = 0; kh < K; ++kh)
        for (int kw = 0; kw < K; ++kw) {
          const int iy = oy * S - P + kh, ix = ox * S - P + kw;
          float* d = row + (kh * K + kw) * C;
          if (iy < 0 || ix < 0 || iy >= H || ix >= W) std::fill(d, d + C, 0.0f);
          else std::copy(x + (std::ptrdiff_t(iy) * W + ix) * C, x + (std::ptrdiff_t(iy) * W + ix + 1) * C, d);
        }
    }
}

/// x[oy*S-P+kh][ox*S-P+kw][c] += cols[...] (the adjoint of im2col); rows split by output parity
/// classes would be needed for a race-free parallel fold, so it runs on one thread per row band.
void col2im(const matrix& cols, int H, int W, int C, int K, int S, int P, int Ho, int Wo, float* x) {
  std::fill(x, x + std::ptrdiff_t(H) * W * C, 0.0f);
  for (int oy = 0; oy < Ho; ++oy)
    for (int ox = 0; ox < Wo; ++ox) {
      const float* row = cols.data() + std::ptrdiff_t(oy * Wo + ox) * K * K * C;
      for (int kh = 0; kh < K; ++kh)
        for (int kw = 0; kw < K; ++kw) {
          const int iy = oy * S - P + kh, ix = ox * S - P + kw;
          if (iy < 0 || ix < 0 || iy >= H || ix >= W) continue;
          float* d = x + (std::ptrdiff_t(iy) * W + ix) * C;
          const float* s = row + (kh * K + kw) * C;
          for (int c = 0; c < C; ++c) d[c] += s[c];
        }
    }
}

/// The three passes of a convolution (A channels in at n x n, B out) with im2col + Eigen.
struct im2col_conv {
  int A, B, K, S, P, n, m;
  matrix w, cols, small, big;  // w: [K*K*A][B]
  im2col_conv(int a, int b, int k, int s, int p, int n_) : A(a), B(b), K(k), S(s), P(p), n(n_) {
    m = (n + 2 * P - K) / S + 1;
    w = matrix::Random(K * K * A, B);
    small = matrix::Random(m * m, B);
    big = matrix::Random(n * n, A);
  }
  void run(pass_kind pass) {
    if (pass == forward) {
      im2col(big.data(), n, n, A, K, S, P, m, m, cols);
      small.noalias() = cols * w;
    } else if (pass == backward_input) {
      cols.resize(m * m, K * K * A);
      cols.noalias() = small * w.transpose();
      col2im(cols, n, n, A, K, S, P, m, m, big.data());
    } else {
      im2col(big.data(), n, n, A, K, S, P, m, m, cols);
      w.noalias() = cols.transpose() * small;
    }
  }
};

void eigen_case(benchmark::State& state, int a, int b, int k, int s, int p, int n, bool transposed, int threads,
                pass_kind pass) {
  omp_set_num_threads(threads);
  Eigen::setNbThreads(threads);
  // A transposed convolution Cin -> Cout at n is the adjoint of the convolution Cout -> Cin at 2n.
  im2col_conv c = transposed ? im2col_conv(b, a, 4, 2, 1, 2 * n) : im2col_conv(a, b, k, s, p, n);
  const pass_kind run = !transposed ? pass : pass == forward ? backward_input : pass == backward_input ? forward : backward_weight;
  for (auto _ : state) {
    c.run(run);
    benchmark::ClobberMemory();
  }
  const double flops = 2.0 * c.m * c.m * c.K * c.K * c.A * c.B;
  set_counters(state, flops, threads);
}

// ---- decoder step -----------------------------------------------------------------------------

/// Leaky ReLU (slope 0.2) recorded on the tape, written here because it is not the subject.
template <int C>
ad::variable<C> leaky_relu(ad::tape& t, const ad::variable<C>& x) {
  auto y = t.make_variable<C>(x.value.batch(), x.value.height(), x.value.width(), x.requires_grad);
  const std::size_t n = x.value.size();
  const float* xs = x.value.data();
  float* ys = y.value.data();
#pragma omp parallel for schedule(static) if (n > (1 << 16))
  for (std::size_t i = 0; i < n; ++i) ys[i] = xs[i] > 0 ? xs[i] : 0.2f * xs[i];
  if (y.requires_grad)
    t.record([xv = x.value, xg = x.grad, yg = y.grad, n]() mutable {
      const float* xs = xv.data();
      const float* g = yg.data();
      float* d = xg.data();
#pragma omp parallel for schedule(static) if (n > (1 << 16))
      for (std::size_t i = 0; i < n; ++i) d[i] += xs[i] > 0 ? g[i] : 0.2f * g[i];
    });
  return y;
}

/// The paper-width auto-encoder's decoder (docs/method.md section 7): 5 transposed convolutions from the
/// 8 x 8 x 1024 latent of a 256 x 256 tile back to 12 channels.
struct decoder {
  nn::conv_transpose2d<1024, 512> d0{"dec0"};
  nn::conv_transpose2d<512, 256> d1{"dec1"};
  nn::conv_transpose2d<256, 128> d2{"dec2"};
  nn::conv_transpose2d<128, 64> d3{"dec3"};
  nn::conv_transpose2d<64, 12> d4{"dec4"};
  decoder() {
    unsigned seed = 7;
    auto init = [&](nn::parameter& p) {
      fill(p.value.data(), p.size(), seed++);
      for (auto& v : p.value) v *= 0.03f;
    };
    d0.for_each_parameter(init);
    d1.for_each_parameter(init);
    d2.for_each_parameter(init);
    d3.for_each_parameter(init);
    d4.for_each_parameter(init);
  }
  ad::variable<12> operator()(ad::tape& t, const ad::variable<1024>& z) {
    auto h0 = leaky_relu(t, d0(t, z));
    auto h1 = leaky_relu(t, d1(t, h0));
    auto h2 = leaky_relu(t, d2(t, h1));
    auto h3 = leaky_relu(t, d3(t, h2));
    return d4(t, h3);
  }
};

void decoder_step(benchmark::State& state, int threads, nn::precision precision) {
  omp_set_num_threads(threads);
  nn::precision_scope scope(precision);
  decoder net;
  ad::tape t;
  tensor<1024> latent = random_tensor<1024>(1, 8, 8, 11);
  tensor<12> target_grad = random_tensor<12>(1, 256, 256, 12);
  double flops = 0;
  for (int layer = 0; layer < 5; ++layer) {
    const int cin = 1024 >> layer, cout = layer == 4 ? 12 : 512 >> layer, n = 8 << layer;
    flops += 3 * 2.0 * n * n * 16 * cin * cout;  // forward, input gradient, weight gradient
  }
  for (auto _ : state) {
    t.clear();
    auto z = t.leaf(latent, true);  // the latent's gradient is what fine-tuning through the decoder needs
    auto y = net(t, z);
    y.grad.copy_from(target_grad);
    t.backward();
    benchmark::ClobberMemory();
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  state.counters["arena_MiB"] = double(t.memory().high_water_bytes()) / (1 << 20);
  state.counters["max_rss_MiB"] = double(usage.ru_maxrss) / 1024;
  set_counters(state, flops, threads);
}

// ---- registration -----------------------------------------------------------------------------

template <int Cin, int Cout, int K, int S, int P>
void add_conv(const std::string& kind, int n) {
  const std::string shape = kind + "/" + std::to_string(Cin) + "->" + std::to_string(Cout) + "@" + std::to_string(n);
  for (int pass = 0; pass < 3; ++pass)
    for (int threads = 1; threads <= 2; ++threads) {
      const std::string suffix = "/" + std::string(pass_name[pass]) + "/threads:" + std::to_string(threads);
      benchmark::RegisterBenchmark(("anisocap/" + shape + suffix).c_str(), [=](benchmark::State& s) {
        conv_case<Cin, Cout, K, S, P>(s, n, threads, pass_kind(pass), nn::precision::fp32);
      })->UseRealTime()->Unit(benchmark::kMillisecond);
      if (nn::bf16_available())
        benchmark::RegisterBenchmark(("anisocap_bf16/" + shape + suffix).c_str(), [=](benchmark::State& s) {
          conv_case<Cin, Cout, K, S, P>(s, n, threads, pass_kind(pass), nn::precision::bf16);
        })->UseRealTime()->Unit(benchmark::kMillisecond);
      benchmark::RegisterBenchmark(("eigen_im2col/" + shape + suffix).c_str(), [=](benchmark::State& s) {
        eigen_case(s, Cin, Cout, K, S, P, n, false, threads, pass_kind(pass));
      })->UseRealTime()->Unit(benchmark::kMillisecond);
    }
}

template <int Cin, int Cout>
void add_conv_transpose(int n) {
  const std::string shape = "convT4x4s2/" + std::to_string(Cin) + "->" + std::to_string(Cout) + "@" + std::to_string(n);
  for (int pass = 0; pass < 3; ++pass)
    for (int threads = 1; threads <= 2; ++threads) {
      const std::string suffix = "/" + std::string(pass_name[pass]) + "/threads:" + std::to_string(threads);
      benchmark::RegisterBenchmark(("anisocap/" + shape + suffix).c_str(), [=](benchmark::State& s) {
        conv_transpose_case<Cin, Cout>(s, n, threads, pass_kind(pass), nn::precision::fp32);
      })->UseRealTime()->Unit(benchmark::kMillisecond);
      if (nn::bf16_available())
        benchmark::RegisterBenchmark(("anisocap_bf16/" + shape + suffix).c_str(), [=](benchmark::State& s) {
          conv_transpose_case<Cin, Cout>(s, n, threads, pass_kind(pass), nn::precision::bf16);
        })->UseRealTime()->Unit(benchmark::kMillisecond);
      benchmark::RegisterBenchmark(("eigen_im2col/" + shape + suffix).c_str(), [=](benchmark::State& s) {
        eigen_case(s, Cin, Cout, 4, 2, 1, n, true, threads, pass_kind(pass));
      })->UseRealTime()->Unit(benchmark::kMillisecond);
    }
}

}  // namespace

int main(int argc, char** argv) {
  peak_flops[1] = fma_peak(1);
  peak_flops[2] = fma_peak(2);
  benchmark::AddCustomContext("simd_arch", simd::arch_name());
  benchmark::AddCustomContext("fma_peak_gflops_1thread", std::to_string(peak_flops[1] / 1e9));
  benchmark::AddCustomContext("fma_peak_gflops_2threads", std::to_string(peak_flops[2] / 1e9));
  for (int threads = 1; threads <= 2; ++threads)
    benchmark::RegisterBenchmark(("fma_peak/threads:" + std::to_string(threads)).c_str(), [=](benchmark::State& s) {
      double f = 0;
      for (auto _ : s) f = fma_peak(threads, 0.05);
      s.counters["gflops"] = f / 1e9;
      s.counters["peak_fraction"] = f / peak_flops[threads];
    })->Iterations(3)->UseRealTime();

  // Auto-encoder encoder (4x4 stride 2), inputs 256 x 256 x 12 down to 16 x 16 x 512.
  add_conv<12, 64, 4, 2, 1>("conv4x4s2", 256);
  add_conv<64, 128, 4, 2, 1>("conv4x4s2", 128);
  add_conv<128, 256, 4, 2, 1>("conv4x4s2", 64);
  add_conv<256, 512, 4, 2, 1>("conv4x4s2", 32);
  add_conv<512, 1024, 4, 2, 1>("conv4x4s2", 16);
  // Auto-encoder decoder (transposed 4x4 stride 2), inputs 8 x 8 x 1024 up to 128 x 128 x 64.
  add_conv_transpose<1024, 512>(8);
  add_conv_transpose<512, 256>(16);
  add_conv_transpose<256, 128>(32);
  add_conv_transpose<128, 64>(64);
  add_conv_transpose<64, 12>(128);
  // The shipped compact auto-encoder's decoder (what the fine-tune runs), 8 x 8 x 128 up to
  // 256 x 256 x 12; its 128->64 layer reads 32 x 32 (the paper-width one above reads 64 x 64).
  add_conv_transpose<128, 128>(8);
  add_conv_transpose<128, 128>(16);
  add_conv_transpose<128, 64>(32);
  add_conv_transpose<64, 32>(64);
  add_conv_transpose<32, 12>(128);
  // Estimator: its first and last encoder layers (the middle ones are the auto-encoder's shapes)
  // and the 3x3 convolutions of its decoder.
  add_conv<3, 64, 4, 2, 1>("conv4x4s2", 256);
  add_conv<1024, 1024, 4, 2, 1>("conv4x4s2", 8);
  add_conv<64, 64, 3, 1, 1>("conv3x3", 256);
  add_conv<128, 128, 3, 1, 1>("conv3x3", 128);
  add_conv<256, 256, 3, 1, 1>("conv3x3", 64);
  add_conv<512, 512, 3, 1, 1>("conv3x3", 32);
  for (int threads = 1; threads <= 2; ++threads)
    for (nn::precision precision : {nn::precision::fp32, nn::precision::bf16}) {
      if (precision == nn::precision::bf16 && !nn::bf16_available()) continue;
      const std::string name = precision == nn::precision::bf16 ? "anisocap_bf16" : "anisocap";
      benchmark::RegisterBenchmark((name + "/decoder_step@256/threads:" + std::to_string(threads)).c_str(),
                                   [=](benchmark::State& s) { decoder_step(s, threads, precision); })
          ->UseRealTime()
          ->Unit(benchmark::kMillisecond);
    }

  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
