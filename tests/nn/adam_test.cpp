// Adam (nn/adam.hpp) against a hand-computed update, its schedules, frozen parameters, and
// convergence on a small least-squares problem through the tape and a linear layer.
#include <doctest/doctest.h>

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "anisocap/nn/adam.hpp"
#include "anisocap/nn/layers.hpp"
#include "layer_check.hpp"

using namespace anisocap;

TEST_CASE("adam: two steps against the formula") {
  // 19 values: more than one SIMD register, so the body and the tail are both checked.
  nn::basic_parameter<double> p("p", {19});
  nn::random_generator g(41);
  std::vector<double> value(19), m(19, 0), v(19, 0);
  for (int i = 0; i < 19; ++i) value[i] = p.value[i] = g.symmetric_uniform();
  nn::basic_adam<double> adam(nn::learning_rate_schedule::constant(0.01), 0.8, 0.95, 1e-6);
  adam.add(p);
  for (int t = 1; t <= 2; ++t) {
    for (int i = 0; i < 19; ++i) p.grad[i] = g.symmetric_uniform() * 3;
    for (int i = 0; i < 19; ++i) {
      const double grad = p.grad[i];
      m[i] = 0.8 * m[i] + 0.2 * grad;
      v[i] = 0.95 * v[i] + 0.05 * grad * grad;
      const double mhat = m[i] / (1 - std::pow(0.8, t)), vhat = v[i] / (1 - std::pow(0.95, t));
      value[i] -= 0.01 * mhat / (std::sqrt(vhat) + 1e-6);
    }
    adam.step();
    for (int i = 0; i < 19; ++i) {
      CHECK(p.value[i] == doctest::Approx(value[i]).epsilon(1e-12));
      CHECK(p.grad[i] == 0.0);
    }
  }
  CHECK(adam.steps() == 2);
}

TEST_CASE("adam: frozen parameters are skipped; schedules") {
  nn::parameter a("a", {3}), b("b", {3});
  a.value[0] = b.value[0] = 1;
  a.grad[0] = b.grad[0] = 1;
  b.frozen = true;
  nn::adam adam(nn::learning_rate_schedule::constant(0.1));
  adam.add(a);
  adam.add(b);
  adam.step();
  CHECK(a.value[0] == doctest::Approx(0.9f));
  CHECK(b.value[0] == 1.0f);
  CHECK(b.grad[0] == 1.0f);  // untouched

  auto s = nn::learning_rate_schedule::step_decay(1.0, 10, 0.5);
  CHECK(s(0) == 1.0);
  CHECK(s(9) == 1.0);
  CHECK(s(10) == 0.5);
  CHECK(s(25) == 0.25);
  auto e = nn::learning_rate_schedule::exponential_decay(2.0, 0.5, 4);
  CHECK(e(0) == 2.0);
  CHECK(e(2) == doctest::Approx(2.0 * std::sqrt(0.5)));
  CHECK(e(8) == doctest::Approx(0.5));
  // Warm-up: linear ramp over the first steps, then the schedule as before.
  auto w = e.with_warmup(4);
  CHECK(w(0) == doctest::Approx(0.25 * 2.0));
  CHECK(w(2) == doctest::Approx(0.75 * 2.0 * std::sqrt(0.5)));
  CHECK(w(3) == doctest::Approx(e(3)));
  CHECK(w(8) == doctest::Approx(e(8)));
  CHECK(nn::learning_rate_schedule::constant(1.0).with_warmup(0)(0) == 1.0);
  CHECK_THROWS_AS(e.with_warmup(-1), std::invalid_argument);
  // Cosine decay: constant up to step 10, half a cosine down to 0.1 x the rate at step 20, then kept.
  auto c = nn::learning_rate_schedule::cosine_decay(2.0, 10, 20, 0.1);
  CHECK(c(0) == 2.0);
  CHECK(c(10) == 2.0);
  CHECK(c(15) == doctest::Approx(2.0 * (0.1 + 0.9 * 0.5)));
  CHECK(c(20) == doctest::Approx(0.2));
  CHECK(c(1000) == doctest::Approx(0.2));
  for (long k = 10; k < 20; ++k) CHECK(c(k + 1) < c(k));  // strictly falling inside the decay
  CHECK(c(11) == doctest::Approx(2.0 * (0.1 + 0.9 * 0.5 * (1 + std::cos(3.14159265358979323846 / 10)))));
  CHECK(nn::learning_rate_schedule::cosine_decay(1.0, 0, 4, 0.0)(4) == 0.0);
  CHECK_THROWS_AS(nn::learning_rate_schedule::cosine_decay(1.0, 5, 5, 0.1), std::invalid_argument);
  CHECK_THROWS_AS(nn::learning_rate_schedule::cosine_decay(1.0, -1, 5, 0.1), std::invalid_argument);
  CHECK_THROWS_AS(nn::learning_rate_schedule::cosine_decay(1.0, 0, 5, 1.5), std::invalid_argument);
}

TEST_CASE("adam: a snapshot restores values, moments and counters exactly") {
  nn::parameter a("a", {37}), b("b", {5});
  for (std::size_t i = 0; i < a.size(); ++i) a.value[i] = float(i) * 0.1f;
  nn::adam adam(nn::learning_rate_schedule::constant(0.05));
  adam.add(a);
  adam.add(b);
  auto step = [&](float g) {
    for (auto& x : a.grad) x = g;
    for (auto& x : b.grad) x = -g;
    adam.step();
  };
  step(1.0f);
  const auto snap = adam.take_snapshot();
  const std::vector<float> a_then(a.value.begin(), a.value.end());
  step(0.5f);  // what follows the snapshot, remembered
  const std::vector<float> a_next(a.value.begin(), a.value.end());
  step(-3.0f);
  step(2.0f);
  adam.restore(snap);
  CHECK(adam.steps() == 1);
  for (std::size_t i = 0; i < a.size(); ++i) REQUIRE(a.value[i] == a_then[i]);
  step(0.5f);  // same moments and counts: the same update as the first time
  for (std::size_t i = 0; i < a.size(); ++i) REQUIRE(a.value[i] == a_next[i]);
  nn::adam other;
  other.add(a);
  CHECK_THROWS_AS(other.restore(snap), std::invalid_argument);

  // A snapshot taken into an earlier one's buffers holds the new state, in the same storage.
  auto reused = snap;
  const float* storage = reused.buffers[0].data();
  step(4.0f);
  adam.take_snapshot(reused);
  CHECK(reused.buffers[0].data() == storage);
  CHECK(reused.steps == adam.steps());
  const std::vector<float> a_now(a.value.begin(), a.value.end());
  step(-1.0f);
  adam.restore(reused);
  for (std::size_t i = 0; i < a.size(); ++i) REQUIRE(a.value[i] == a_now[i]);
  CHECK(reused.counts == std::vector<long>{3, 3});

  // save_state borrows the moments and copies only the update counts.
  nn::safetensors_file file;
  adam.save_state(file);
  CHECK(file.data_bytes() == (2 * (37 + 5)) * sizeof(float) + 2 * sizeof(std::int64_t));
  CHECK(file.data().size() == 2 * sizeof(std::int64_t));
  REQUIRE(file.find("adam.m.a") != nullptr);
  const void* moments_of_a = nullptr;
  adam.for_each_state([&](nn::parameter& p, auto& m, auto&, long) {
    if (&p == &a) moments_of_a = m.data();
  });
  CHECK(static_cast<const void*>(file.bytes(*file.find("adam.m.a")).data()) == moments_of_a);
}

TEST_CASE("adam: converges on least squares through the tape") {
  // Fit y = A x + c with a linear layer: the optimum is exact, so the loss must go to ~0.
  nn::random_generator g(42);
  auto x = test_nn::random_tensor<5, float>(g, 1, 8, 8);
  float a[2][5], c[2] = {0.3f, -0.7f};
  for (auto& row : a)
    for (auto& e : row) e = float(g.symmetric_uniform());
  tensor<2> y(1, 8, 8);
  for (int r = 0; r < 8; ++r)
    for (int i = 0; i < 8; ++i)
      for (int o = 0; o < 2; ++o) {
        float s = c[o];
        for (int k = 0; k < 5; ++k) s += a[o][k] * x(0, r, i, k);
        y(0, r, i, o) = s;
      }
  nn::linear<5, 2> fc("fc", 9);
  nn::adam adam(nn::learning_rate_schedule::exponential_decay(0.05, 0.1, 1000));
  adam.add_parameters(fc);
  ad::tape t;
  double loss = 0, first = 0;
  for (int step = 0; step < 600; ++step) {
    t.clear();
    auto out = fc(t, t.leaf(x));
    loss = 0;
    for (std::size_t i = 0; i < out.value.size(); ++i) {
      const float d = out.value.data()[i] - y.data()[i];
      out.grad.data()[i] = d / 64;
      loss += 0.5 * double(d) * d / 64;
    }
    if (step == 0) first = loss;
    t.backward();
    adam.step();
  }
  CHECK(first > 0.1);
  CHECK(loss < 1e-6);
  for (int k = 0; k < 5; ++k) CHECK(fc.weight.value[k] == doctest::Approx(a[0][k]).epsilon(1e-3));
  CHECK(fc.bias.value[1] == doctest::Approx(c[1]).epsilon(1e-3));
}

TEST_CASE("adam: state can be saved and restored exactly (checkpoints)") {
  // Two optimisers: one runs 3 steps; the other runs 1, takes a copy of the first's state after 1,
  // and must then follow the same trajectory.
  nn::parameter a("a", {5}), b("b", {5});
  for (int i = 0; i < 5; ++i) a.value[i] = b.value[i] = float(i) - 2;
  nn::adam first(nn::learning_rate_schedule::step_decay(0.1, 2, 0.5)), second(nn::learning_rate_schedule::step_decay(0.1, 2, 0.5));
  first.add(a);
  second.add(b);
  auto gradient = [](nn::parameter& p) { for (std::size_t i = 0; i < p.size(); ++i) p.grad[i] = p.value[i] * p.value[i] - 1; };
  gradient(a);
  first.step();
  // Restore into `second` from `first`: values, moments, per-parameter and global step counts.
  std::copy(a.value.begin(), a.value.end(), b.value.begin());
  std::vector<float> m, v;
  long steps = 0;
  first.for_each_state([&](nn::parameter&, auto& mm, auto& vv, long& s) { m.assign(mm.begin(), mm.end()); v.assign(vv.begin(), vv.end()); steps = s; });
  second.for_each_state([&](nn::parameter&, auto& mm, auto& vv, long& s) { std::copy(m.begin(), m.end(), mm.begin()); std::copy(v.begin(), v.end(), vv.begin()); s = steps; });
  second.set_steps(first.steps());
  for (int k = 0; k < 2; ++k) {
    gradient(a);
    gradient(b);
    first.step();
    second.step();
  }
  for (int i = 0; i < 5; ++i) CHECK(a.value[i] == b.value[i]);
  CHECK(second.learning_rate() == first.learning_rate());
}

TEST_CASE("adam: parameters of every size, chunked over threads, update as in a serial pass") {
  // Sizes around the register width and the work-item size (nn::adam::chunk_size), each with a
  // tail; two optimisers over equal parameters, one run on one thread and one on two, must agree
  // bit for bit, and both with the formula.
  const std::vector<int> sizes = {3, 17, 16384, 16385, 40000, 70001};
  std::vector<nn::parameter> serial_p, parallel_p;
  nn::random_generator g(7);
  for (std::size_t k = 0; k < sizes.size(); ++k) {
    serial_p.emplace_back(std::string("p") + std::to_string(k), std::vector<int>{sizes[k]});
    parallel_p.emplace_back(std::string("p") + std::to_string(k), std::vector<int>{sizes[k]});
    for (int i = 0; i < sizes[k]; ++i) serial_p[k].value[i] = parallel_p[k].value[i] = float(g.symmetric_uniform());
  }
  nn::adam serial(nn::learning_rate_schedule::constant(0.01)), parallel(nn::learning_rate_schedule::constant(0.01));
  for (auto& p : serial_p) serial.add(p);
  for (auto& p : parallel_p) parallel.add(p);
  std::vector<std::vector<float>> start;
  for (auto& p : serial_p) start.emplace_back(p.value.begin(), p.value.end());
  std::vector<std::vector<float>> first_grad;
  const int threads_before = omp_get_max_threads();
  for (int t = 0; t < 2; ++t) {
    for (std::size_t k = 0; k < sizes.size(); ++k)
      for (int i = 0; i < sizes[k]; ++i) serial_p[k].grad[i] = parallel_p[k].grad[i] = float(g.symmetric_uniform());
    if (t == 0)
      for (auto& p : serial_p) first_grad.emplace_back(p.grad.begin(), p.grad.end());
    omp_set_num_threads(1);
    serial.step();
    omp_set_num_threads(2);
    parallel.step();
  }
  omp_set_num_threads(threads_before);
  bool equal = true, zeroed = true;
  for (std::size_t k = 0; k < sizes.size(); ++k)
    for (int i = 0; i < sizes[k]; ++i) {
      equal &= serial_p[k].value[i] == parallel_p[k].value[i];
      zeroed &= parallel_p[k].grad[i] == 0.0f;
    }
  CHECK(equal);
  CHECK(zeroed);
  // The first step moves every value by the rate against the gradient's sign (m / sqrt(v) = +-1).
  bool first_step_right = true;
  nn::parameter once("once", {sizes.back()});
  std::copy(start.back().begin(), start.back().end(), once.value.begin());
  std::copy(first_grad.back().begin(), first_grad.back().end(), once.grad.begin());
  nn::adam single(nn::learning_rate_schedule::constant(0.01));
  single.add(once);
  single.step();
  for (int i = 0; i < sizes.back(); ++i) {
    const float gr = first_grad.back()[i];
    const float expected = start.back()[i] - (gr > 0 ? 0.01f : gr < 0 ? -0.01f : 0.0f);
    first_step_right &= std::abs(once.value[i] - expected) < 1e-5f;
  }
  CHECK(first_step_right);
}
