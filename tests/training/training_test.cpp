// Training (training/training.hpp): a run stopped half-way and resumed from its checkpoint ends
// with exactly the weights of an uninterrupted run; the auto-encoder's shapes; the loss terms.
#include <doctest/doctest.h>

#include <filesystem>
#include <algorithm>
#include <fstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "anisocap/training/training.hpp"
#include "../networks/tiny_presets.hpp"
#include "../support/temp_folders.hpp"
#include "tiny_options.hpp"

using namespace anisocap;
namespace fs = std::filesystem;
using anisocap::testing::all_weights;
using anisocap::testing::fresh_folder;
using anisocap::testing::tiny_options;


TEST_CASE("training: estimator stopped after k/2 steps and resumed equals k steps straight") {
  const fs::path a = fresh_folder("networks_straight"), b = fresh_folder("networks_resumed");
  estimation_network<testing::estimator_tiny> straight(3);
  training::train_estimator(tiny_options(a, 64), straight);
  {
    estimation_network<testing::estimator_tiny> killed(3);
    auto o = tiny_options(b, 64);
    o.stop_after = 2;
    training::train_estimator(o, killed);
  }
  estimation_network<testing::estimator_tiny> resumed(99);  // different initial weights: all must come from the checkpoint
  auto o = tiny_options(b, 64);
  o.resume = true;
  training::train_estimator(o, resumed);
  const auto wa = all_weights(straight), wb = all_weights(resumed);
  REQUIRE(wa.size() == wb.size());
  CHECK(std::equal(wa.begin(), wa.end(), wb.begin()));
  estimation_network<testing::estimator_tiny> initial(3);
  const auto w0 = all_weights(initial);
  CHECK_FALSE(std::equal(wa.begin(), wa.end(), w0.begin()));  // training changed the weights
  // Both runs logged the same validation rows (the resumed one rewrote none twice).
  std::ifstream ca(a / "validation.csv"), cb(b / "validation.csv");
  std::string sa((std::istreambuf_iterator<char>(ca)), {}), sb((std::istreambuf_iterator<char>(cb)), {});
  CHECK(sa == sb);
  CHECK(std::count(sa.begin(), sa.end(), '\n') == 3);
  CHECK(fs::exists(a / "estimator.safetensors"));
  // Resuming without a checkpoint is a clear error naming the file, and creates no folder.
  auto missing = tiny_options(fresh_folder("networks_missing"), 64);
  missing.resume = true;
  CHECK_THROWS_WITH_AS(training::train_estimator(missing, resumed), doctest::Contains("checkpoint.json"), std::runtime_error);
  CHECK_FALSE(fs::exists(missing.out_dir));
  fs::remove_all(a);
  fs::remove_all(b);
}

TEST_CASE("training: --init starts a doubled-angle estimator from a tanh estimator's weights, and refuses an auto-encoder's") {
  const fs::path a = fresh_folder("networks_init_source"), b = fresh_folder("networks_init_variant"),
                 c = fresh_folder("networks_init_wrong");
  estimation_network<testing::estimator_tiny> source(3);
  training::train_estimator(tiny_options(a, 64), source);
  std::vector<std::string> log;
  auto o = tiny_options(b, 64);
  o.init_weights = a / "estimator.safetensors";
  o.steps = 1;
  o.log = [&](const std::string& line) { log.push_back(line); };
  estimation_network<testing::estimator_tiny_doubled_angle> variant(4);
  training::train_estimator(o, variant);
  CHECK(std::any_of(log.begin(), log.end(), [](const std::string& line) {
    return line.find("initialised afresh: track2.reduce2.weight, track2.reduce2.bias") != std::string::npos;
  }));
  // The layers before the last one start from the file (one step of Adam moves each weight by at
  // most about the learning rate).
  for (std::size_t i = 0; i < variant.enc1.weight.size(); ++i)
    REQUIRE(std::abs(variant.enc1.weight.value[i] - source.enc1.weight.value[i]) < 2e-3f);
  auto_encoder<testing::autoencoder_tiny> ae(5);
  training::train_autoencoder(tiny_options(c, 64), ae);
  auto wrong = tiny_options(fresh_folder("networks_init_wrong_target"), 64);
  wrong.init_weights = c / "autoencoder.safetensors";
  estimation_network<testing::estimator_tiny> target(6);
  CHECK_THROWS_WITH_AS(training::train_estimator(wrong, target), doctest::Contains("not estimator weights"), std::runtime_error);
  CHECK_FALSE(fs::exists(wrong.out_dir));
  for (const auto& d : {a, b, c}) fs::remove_all(d);
}

TEST_CASE("training: auto-encoder resume is exact too (batch-norm running statistics included)") {
  const fs::path a = fresh_folder("networks_ae_straight"), b = fresh_folder("networks_ae_resumed");
  auto_encoder<testing::autoencoder_tiny> straight(3);
  training::train_autoencoder(tiny_options(a, 32), straight);
  {
    auto_encoder<testing::autoencoder_tiny> killed(3);
    auto o = tiny_options(b, 32);
    o.stop_after = 2;
    training::train_autoencoder(o, killed);
  }
  auto_encoder<testing::autoencoder_tiny> resumed(42);
  auto o = tiny_options(b, 32);
  o.resume = true;
  training::train_autoencoder(o, resumed);
  const auto wa = all_weights(straight), wb = all_weights(resumed);
  REQUIRE(wa.size() == wb.size());
  CHECK(std::equal(wa.begin(), wa.end(), wb.begin()));
  fs::remove_all(a);
  fs::remove_all(b);
}

TEST_CASE("training: the auto-encoder's size is checked against its preset's latent cell") {
  // Four stride-2 levels: 48 x 48 texels is 3 x 3 cells, and training runs; five levels refuse it.
  const fs::path a = fresh_folder("networks_ae_cell_four"), b = fresh_folder("networks_ae_cell_five");
  auto_encoder<testing::autoencoder_tiny_four_levels> four(3);
  const auto before = all_weights(four);
  training::train_autoencoder(tiny_options(a, 48), four);
  CHECK(fs::exists(a / "autoencoder.safetensors"));
  CHECK(all_weights(four) != before);
  auto_encoder<testing::autoencoder_tiny> five(3);
  CHECK_THROWS_WITH_AS(training::train_autoencoder(tiny_options(b, 48), five), doctest::Contains("multiple of 32"), std::invalid_argument);
  CHECK_FALSE(fs::exists(b / "autoencoder.safetensors"));
  auto_encoder<testing::autoencoder_tiny_four_levels> odd(3);
  CHECK_THROWS_WITH_AS(training::train_autoencoder(tiny_options(b, 40), odd), doctest::Contains("multiple of 16"), std::invalid_argument);
  fs::remove_all(a);
  fs::remove_all(b);
}

TEST_CASE("training: --trainable encoder keeps the decoder of the --init weights, trains the encoder, resumes exactly") {
  const fs::path src = fresh_folder("networks_enc_source"), a = fresh_folder("networks_enc_straight"),
                 b = fresh_folder("networks_enc_resumed");
  auto_encoder<testing::autoencoder_tiny> source(3);
  training::train_autoencoder(tiny_options(src, 32), source);
  auto options = [&](const fs::path& dir) {
    auto o = tiny_options(dir, 32);
    o.init_weights = src / "autoencoder.safetensors";
    o.encoder_only = true;
    o.seed = 8;
    return o;
  };
  auto_encoder<testing::autoencoder_tiny> straight(11);
  training::train_autoencoder(options(a), straight);
  std::vector<float> decoder_before, decoder_after;
  source.for_each_decoder_parameter([&](nn::basic_parameter<float>& p) { decoder_before.insert(decoder_before.end(), p.value.data(), p.value.data() + p.size()); });
  straight.for_each_decoder_parameter([&](nn::basic_parameter<float>& p) { decoder_after.insert(decoder_after.end(), p.value.data(), p.value.data() + p.size()); });
  REQUIRE(decoder_before.size() == decoder_after.size());
  CHECK(decoder_before == decoder_after);  // bit for bit
  int encoder_changed = 0;
  for (std::size_t i = 0; i < straight.enc<0>().weight.size(); ++i) encoder_changed += straight.enc<0>().weight.value[i] != source.enc<0>().weight.value[i];
  CHECK(encoder_changed > int(straight.enc<0>().weight.size()) / 2);
  // The saved file holds the same decoder.
  auto_encoder<testing::autoencoder_tiny> saved(12);
  nn::load_weights(a / "autoencoder.safetensors", saved);
  CHECK(saved.dec<4>().weight.value[0] == source.dec<4>().weight.value[0]);
  // Stopped and resumed, the run ends with the straight run's weights (the decoder stays frozen).
  {
    auto_encoder<testing::autoencoder_tiny> killed(11);
    auto o = options(b);
    o.stop_after = 2;
    training::train_autoencoder(o, killed);
  }
  auto_encoder<testing::autoencoder_tiny> resumed(13);
  auto o = options(b);
  o.resume = true;
  o.encoder_only = false;  // a resume must keep what the run trains
  CHECK_THROWS_WITH_AS(training::train_autoencoder(o, resumed), doctest::Contains("resume it with train_options::encoder_only true"), std::runtime_error);
  o.encoder_only = true;
  o.init_weights.clear();  // a resume needs no --init
  training::train_autoencoder(o, resumed);
  const auto wa = all_weights(straight), wb = all_weights(resumed);
  REQUIRE(wa.size() == wb.size());
  CHECK(std::equal(wa.begin(), wa.end(), wb.begin()));
  // Without weights to start from there is no decoder worth keeping: refused, no folder.
  auto fresh = tiny_options(fresh_folder("networks_enc_no_init"), 32);
  fresh.encoder_only = true;
  auto_encoder<testing::autoencoder_tiny> none(14);
  CHECK_THROWS_WITH_AS(training::train_autoencoder(fresh, none), doctest::Contains("train_options::init_weights"), std::invalid_argument);
  CHECK_FALSE(fs::exists(fresh.out_dir));
  for (const auto& d : {src, a, b}) fs::remove_all(d);
}

TEST_CASE("training: an auto-encoder step reads the inputs it is given, and compares with the truth") {
  training::train_options o = tiny_options(fresh_folder("networks_inputs_unused"), 32);
  const std::vector<training::sample> samples = training::make_batch(o, 0, false);
  auto loss = [&](const std::vector<tensor<parameter_count>>* inputs) {
    auto_encoder<testing::autoencoder_tiny> net(3);
    nn::adam opt;
    opt.add_parameters(net);
    ad::tape t;
    return training::autoencoder_step(t, net, opt, samples, o, 0, inputs).total;
  };
  std::vector<tensor<parameter_count>> truth, other;
  for (const auto& x : samples) {
    truth.push_back(x.truth_net.clone());
    other.push_back(x.truth_net.clone());
    for (std::size_t i = 0; i < other.back().size(); ++i) other.back().data()[i] *= 0.5f;
  }
  CHECK(loss(&truth) == loss(nullptr));  // the true maps given as inputs: the same step
  CHECK(loss(&other) != loss(nullptr));
  other.pop_back();
  CHECK_THROWS_AS(loss(&other), std::invalid_argument);
}

TEST_CASE("training: an auto-encoder on the estimator's estimates keeps its decoder, validates on estimates, resumes only as such") {
  const fs::path src = fresh_folder("networks_est_in_source"), a = fresh_folder("networks_est_in_straight"),
                 b = fresh_folder("networks_est_in_resumed");
  auto_encoder<testing::autoencoder_tiny> source(3);
  training::train_autoencoder(tiny_options(src, 64), source);
  estimation_network<testing::estimator_tiny> estimator(4);
  auto options = [&](const fs::path& dir) {
    auto o = tiny_options(dir, 64);
    o.init_weights = src / "autoencoder.safetensors";
    o.encoder_only = true;
    return o;
  };
  auto_encoder<testing::autoencoder_tiny> straight(11);
  training::train_autoencoder(options(a), straight, estimator);
  CHECK(straight.dec<2>().weight.value[7] == source.dec<2>().weight.value[7]);
  CHECK(straight.enc<1>().weight.value[7] != source.enc<1>().weight.value[7]);
  CHECK(training::read_checkpoint_description(a).at("inputs") == "estimates");
  // The CSV's validation is of D(E(estimate)): recompute its first material's L1 term.
  {
    training::train_options o = options(a);
    const training::sample x = training::make_sample(training::validation_seed(0), 64, true, training::material_options_for_seed(o, training::validation_seed(0)));
    const tensor<parameter_count> e = training::estimator_output(estimator, x);
    const tensor<parameter_count> through_estimate = training::autoencoder_output(straight, x, &e), through_truth = training::autoencoder_output(straight, x);
    std::vector<training::sample> one{x};
    const double l1_estimate = training::map_losses(through_estimate, one, nullptr).l1, l1_truth = training::map_losses(through_truth, one, nullptr).l1;
    std::ifstream csv(a / "validation.csv");
    std::string line, last;
    while (std::getline(csv, line)) last = line;
    const double logged = std::stod(last.substr(last.find(',', last.find(',', last.find(',') + 1) + 1) + 1));  // val_l1
    CHECK(logged == doctest::Approx(l1_estimate).epsilon(1e-4));
    CHECK(l1_estimate != doctest::Approx(l1_truth).epsilon(1e-4));
  }
  {
    auto_encoder<testing::autoencoder_tiny> killed(11);
    auto o = options(b);
    o.stop_after = 2;
    training::train_autoencoder(o, killed, estimator);
  }
  auto_encoder<testing::autoencoder_tiny> resumed(13);
  auto o = options(b);
  o.resume = true;
  CHECK_THROWS_WITH_AS(training::train_autoencoder(o, resumed), doctest::Contains("resume it with train_options::inputs_are_estimates true"), std::runtime_error);
  training::train_autoencoder(o, resumed, estimator);
  const auto wa = all_weights(straight), wb = all_weights(resumed);
  REQUIRE(wa.size() == wb.size());
  CHECK(std::equal(wa.begin(), wa.end(), wb.begin()));
  // The estimator's sizes: a multiple of 64.
  auto small = options(fresh_folder("networks_est_in_small"));
  small.size = 32;
  CHECK_THROWS_WITH_AS(training::train_autoencoder(small, resumed, estimator), doctest::Contains("multiple of 64"), std::invalid_argument);
  CHECK_FALSE(fs::exists(small.out_dir));
  for (const auto& d : {src, a, b}) fs::remove_all(d);
}

TEST_CASE("training: loss terms are zero for the truth and positive otherwise; seeds are disjoint") {
  std::vector<training::sample> s;
  s.push_back(training::make_sample(training::validation_seed(0), 32, true));
  CHECK(s[0].photos.size() == 5);
  CHECK(s[0].loss_configurations.images.size() == 4);
  const auto exact = training::map_losses(s[0].truth_net, s, nullptr);
  CHECK(exact.l1 < 1e-6);
  CHECK(exact.render < 2e-3);  // only the lobe clamp and float rounding
  tensor<parameter_count> off(1, 32, 32), grad(1, 32, 32);
  for (std::size_t i = 0; i < off.size(); ++i) off.data()[i] = s[0].truth_net.data()[i] * 0.5f;
  const auto l = training::map_losses(off, s, &grad);
  CHECK(l.l1 > 0.01);
  CHECK(l.render > 0.01);
  CHECK(l.total == doctest::Approx(l.l1 + l.render));
  // The render loss's weight scales its value in the total and its part of the gradient, nothing else.
  tensor<parameter_count> grad0(1, 32, 32), grad3(1, 32, 32);
  const auto l0 = training::map_losses(off, s, &grad0, {.render = 0.0});
  const auto l3 = training::map_losses(off, s, &grad3, {.render = 3.0});
  CHECK(l0.total == doctest::Approx(l.l1));
  CHECK(l3.total == doctest::Approx(l.l1 + 3 * l.render));
  CHECK(l0.render == doctest::Approx(l.render));
  double render_part = 0;  // |grad(1) - grad(0)|: the render loss's own gradient
  for (std::size_t i = 0; i < grad.size(); ++i) {
    const double r = double(grad.data()[i]) - grad0.data()[i];
    render_part += std::abs(r);
    CHECK(grad3.data()[i] == doctest::Approx(grad0.data()[i] + 3 * r).epsilon(1e-4).scale(1e-6));
  }
  CHECK(render_part > 0);
  // The lobe weight scales the lobe widths' and rotation's L1 in the total and their gradient
  // channels; the other channels' gradient and the unweighted terms stay.
  tensor<parameter_count> grad_lobe(1, 32, 32);
  const auto l_lobe = training::map_losses(off, s, &grad_lobe, {.lobe = 2.5});
  CHECK(l.lobe > 0);
  CHECK(l.lobe < l.l1);
  CHECK(l_lobe.l1 == doctest::Approx(l.l1));
  CHECK(l_lobe.lobe == doctest::Approx(l.lobe));
  CHECK(l_lobe.total == doctest::Approx(l.l1 + 1.5 * l.lobe + l.render));
  const std::size_t texels = std::size_t(32) * 32;
  const float l1_step = float(1.0 / (double(texels) * parameter_count));
  int lobe_channels_moved = 0;
  for (std::size_t t = 0; t < texels; ++t)
    for (int k = 0; k < parameter_count; ++k) {
      const std::size_t i = t * parameter_count + k;
      const double diff = double(grad_lobe.data()[i]) - grad.data()[i];
      if (k == lobe_x || k == lobe_y || k == rotation) {
        // The L1 part of the lobe channels' gradient is a multiple of one step: x 2.5 adds 1.5 of it.
        CHECK(std::abs(diff) <= 1.5 * l1_step * 1.0001 + 1e-5 * std::abs(grad.data()[i]));
        lobe_channels_moved += std::abs(diff) > 1.4 * l1_step;
      } else {
        CHECK(diff == doctest::Approx(0).scale(1e-9));
      }
    }
  CHECK(lobe_channels_moved > int(texels));
  // The squared-error terms: 0 for the truth and reported unweighted; a weight adds weight x term
  // to the total and changes its own channels' gradient only (sigma: the lobe widths; mse: every
  // channel but the lobe widths and the rotation).
  struct squared_term {
    training::loss_weights weights;
    double weight;
    double training::loss_terms::*term;
    bool (*moves)(int channel);
  };
  const squared_term squared_terms[] = {
      {{.sigma = 4.0}, 4.0, &training::loss_terms::sigma, [](int k) { return k == lobe_x || k == lobe_y; }},
      {{.mse = 3.0}, 3.0, &training::loss_terms::mse, [](int k) { return k != lobe_x && k != lobe_y && k != rotation; }}};
  for (const auto& t : squared_terms) {
    CHECK(exact.*t.term < 1e-10);
    CHECK(l.*t.term > 0);
    tensor<parameter_count> grad_w(1, 32, 32);
    const auto lw = training::map_losses(off, s, &grad_w, t.weights);
    CHECK(lw.*t.term == doctest::Approx(l.*t.term));
    CHECK(lw.total == doctest::Approx(l.l1 + t.weight * l.*t.term + l.render));
    int moved = 0;
    for (std::size_t i = 0; i < grad.size(); ++i) {
      const int k = int(i % parameter_count);
      const double diff = double(grad_w.data()[i]) - grad.data()[i];
      if (t.moves(k)) moved += diff != 0;
      else CHECK(diff == 0);
    }
    int channels = 0;
    for (int k = 0; k < parameter_count; ++k) channels += t.moves(k);
    CHECK(moved > (channels - 1) * int(texels));
  }
  for (long step = 0; step < 50; ++step) CHECK(training::training_seed(1, step, 0) < training::validation_seed_base);
}

TEST_CASE("training: the a_d and normal weights scale those maps' L1 and squared error in the total and in their own channels' gradient only") {
  std::vector<training::sample> s;
  s.push_back(training::make_sample(training::validation_seed(2), 32, false));
  tensor<parameter_count> off(1, 32, 32);
  for (std::size_t i = 0; i < off.size(); ++i) off.data()[i] = s[0].truth_net.data()[i] * 0.5f + 0.05f;
  const auto is_diffuse = [](int k) { return k == diffuse_r || k == diffuse_g || k == diffuse_b; };
  const auto is_normal = [](int k) { return k == normal_x || k == normal_y; };
  const std::size_t texels = std::size_t(32) * 32;
  const float l1_step = float(1.0 / (double(texels) * parameter_count));
  tensor<parameter_count> grad(1, 32, 32), grad_w(1, 32, 32);
  const auto l = training::map_losses(off, s, &grad);
  const auto lw = training::map_losses(off, s, &grad_w, {.diffuse = 2.5, .normal = 0.5});
  // The parts: unweighted, each within l1, and a_d's is the mean |du| over its three channels.
  double diffuse_l1 = 0, normal_l1 = 0;
  for (std::size_t i = 0; i < off.size(); ++i) {
    const double d = std::abs(double(off.data()[i]) - s[0].truth_net.data()[i]);
    diffuse_l1 += is_diffuse(int(i % parameter_count)) ? d : 0;
    normal_l1 += is_normal(int(i % parameter_count)) ? d : 0;
  }
  CHECK(l.diffuse == doctest::Approx(diffuse_l1 / double(off.size())));
  CHECK(l.normal == doctest::Approx(normal_l1 / double(off.size())));
  CHECK(l.diffuse > 0);
  CHECK(l.normal > 0);
  CHECK(l.diffuse + l.normal < l.l1);
  CHECK(lw.l1 == doctest::Approx(l.l1));
  CHECK(lw.diffuse == doctest::Approx(l.diffuse));
  CHECK(lw.total == doctest::Approx(l.l1 + 1.5 * l.diffuse - 0.5 * l.normal + l.render));
  int diffuse_moved = 0, normal_moved = 0;
  for (std::size_t i = 0; i < grad.size(); ++i) {
    const int k = int(i % parameter_count);
    const double diff = double(grad_w.data()[i]) - grad.data()[i];
    if (is_diffuse(k)) {
      CHECK(std::abs(diff) <= 1.5 * l1_step * 1.0001 + 1e-5 * std::abs(grad.data()[i]));
      diffuse_moved += std::abs(diff) > 1.4 * l1_step;
    } else if (is_normal(k)) {
      CHECK(std::abs(diff) <= 0.5 * l1_step * 1.0001 + 1e-5 * std::abs(grad.data()[i]));
      normal_moved += std::abs(diff) > 0.4 * l1_step;
    } else {
      CHECK(diff == 0);
    }
  }
  CHECK(diffuse_moved > 2 * int(texels));
  CHECK(normal_moved > int(texels));
  // With the squared error: its a_d and normal parts are compare_maps' (the normal's without the z
  // term), and the weights multiply them in the total and in the gradient of those channels only.
  const material_maps maps = network_space::network_to_maps(off, 0);
  CHECK(l.mse_diffuse == doctest::Approx(compare_maps(maps, s[0].truth).diffuse));
  CHECK(l.mse_normal > 0);
  CHECK(l.mse_diffuse + l.mse_normal < l.mse);
  tensor<parameter_count> grad_m(1, 32, 32), grad_mw(1, 32, 32);
  const auto lm = training::map_losses(off, s, &grad_m, {.mse = 3.0});
  const auto lmw = training::map_losses(off, s, &grad_mw, {.mse = 3.0, .diffuse = 2.0, .normal = 4.0});
  CHECK(lmw.total == doctest::Approx(lm.total + l.diffuse + 3 * l.normal + 3 * (l.mse_diffuse + 3 * l.mse_normal)));
  for (std::size_t i = 0; i < grad.size(); ++i) {
    const int k = int(i % parameter_count);
    if (!is_diffuse(k) && !is_normal(k)) CHECK(grad_mw.data()[i] == grad_m.data()[i]);
  }
}

TEST_CASE("training: the lobe widths' squared error is compare_maps' sigma error, uses lobe_l1's form, and its gradient matches finite differences") {
  float q[parameter_count] = {}, p[parameter_count] = {};
  q[lobe_x] = 0.6f, q[lobe_y] = -0.2f, q[rotation] = 0.3f;
  std::copy_n(q, parameter_count, p);
  p[lobe_x] = 0.5f, p[lobe_y] = -0.1f;
  int form = -1;
  training::lobe_l1(p, q, nullptr, 1, &form);
  CHECK(form == 0);
  const double e = training::lobe_width_squared_error(p, q, form, nullptr, 1);
  // The same error through the original ranges and compare_maps (one texel; sigma's error is the
  // mean over the two widths).
  material_maps truth(1, 1), estimate(1, 1);
  for (int k = 0; k < parameter_count; ++k) {
    truth.at(k, 0, 0) = float(network_space::from_network(k, q[k]));
    estimate.at(k, 0, 0) = float(network_space::from_network(k, p[k]));
  }
  CHECK(e / 2 == doctest::Approx(compare_maps(estimate, truth).lobes).epsilon(1e-4));
  // The swapped estimate (widths exchanged, rotation + pi/2) takes the truth's swapped form: error 0.
  float r[parameter_count];
  std::copy_n(q, parameter_count, r);
  r[lobe_x] = q[lobe_y], r[lobe_y] = q[lobe_x], r[rotation] = q[rotation] - 1;
  training::lobe_l1(r, q, nullptr, 1, &form);
  CHECK(form == 1);
  CHECK(training::lobe_width_squared_error(r, q, form, nullptr, 1) < 1e-10);
  // Gradient against central differences (form fixed).
  float g[parameter_count] = {};
  training::lobe_width_squared_error(p, q, 0, g, 1);
  for (int k : {int(lobe_x), int(lobe_y)}) {
    const float h = 1e-3f;
    float plus[parameter_count], minus[parameter_count];
    std::copy_n(p, parameter_count, plus);
    std::copy_n(p, parameter_count, minus);
    plus[k] += h, minus[k] -= h;
    const double fd = (training::lobe_width_squared_error(plus, q, 0, nullptr, 1) - training::lobe_width_squared_error(minus, q, 0, nullptr, 1)) / (2 * h);
    CHECK(g[k] == doctest::Approx(fd).epsilon(1e-3));
    CHECK(std::abs(fd) > 1e-4);
  }
  CHECK(g[rotation] == 0);
}

TEST_CASE("training: the maps' squared error is compare_maps' a_d, a'_s, F0 and normal x, y errors, and its gradient matches finite differences") {
  const auto truth = training::make_sample(training::validation_seed(1), 16, false).truth;
  material_maps estimate = truth;
  nn::random_generator rng(5);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < truth.texel_count(); ++i) estimate.plane(k)[i] += float(0.05 * rng.normal());
  // compare_maps' normal error less its z term, from the same maps.
  double z = 0;
  for (std::size_t i = 0; i < truth.texel_count(); ++i) {
    auto nz = [&](const material_maps& m) { return std::sqrt(std::max(0.0, 1.0 - std::pow(m.plane(normal_x)[i], 2) - std::pow(m.plane(normal_y)[i], 2))); };
    z += std::pow(nz(estimate) - nz(truth), 2);
  }
  const parameter_errors e = compare_maps(estimate, truth);
  const double expected = e.diffuse + e.specular + e.fresnel + e.normal - z / (3 * double(truth.texel_count()));
  const training::map_squared_errors errors = training::map_squared_error(estimate, truth, nullptr, 1);
  CHECK(errors.total == doctest::Approx(expected).epsilon(1e-6));
  const training::map_squared_errors none = training::map_squared_error(truth, truth, nullptr, 1);
  CHECK(none.total == 0);
  CHECK(none.diffuse == 0);
  CHECK(none.normal == 0);
  // The parts: a_d's is compare_maps' diffuse error, the normal's its normal error without the z term.
  CHECK(errors.diffuse == doctest::Approx(e.diffuse).epsilon(1e-6));
  CHECK(errors.normal == doctest::Approx(e.normal - z / (3 * double(truth.texel_count()))).epsilon(1e-6));
  // Gradient against central differences, on every plane it covers; zero on the lobes and the rotation.
  material_maps g(16, 16);
  training::map_squared_error(estimate, truth, &g, 2.0);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i : {std::size_t(0), std::size_t(37), std::size_t(255)}) {
      const float h = 1e-3f, keep = estimate.plane(k)[i];
      estimate.plane(k)[i] = keep + h;
      const double plus = training::map_squared_error(estimate, truth, nullptr, 1).total;
      estimate.plane(k)[i] = keep - h;
      const double minus = training::map_squared_error(estimate, truth, nullptr, 1).total;
      estimate.plane(k)[i] = keep;
      const double fd = 2.0 * (plus - minus) / (2 * h);
      if (k == lobe_x || k == lobe_y || k == rotation) {
        CHECK(g.plane(k)[i] == 0);
      } else {
        CHECK(g.plane(k)[i] == doctest::Approx(fd).epsilon(2e-2).scale(1e-7));
        CHECK(std::abs(fd) > 1e-7);
      }
    }
  // diffuse_scale and normal_scale multiply those planes' gradient, and no other plane's.
  material_maps gs(16, 16);
  training::map_squared_error(estimate, truth, &gs, 2.0, 3.0, 0.5);
  for (int k = 0; k < parameter_count; ++k) {
    const double factor = (k == diffuse_r || k == diffuse_g || k == diffuse_b) ? 3.0 : (k == normal_x || k == normal_y) ? 0.5 : 1.0;
    for (std::size_t i = 0; i < truth.texel_count(); ++i) CHECK(gs.plane(k)[i] == doctest::Approx(factor * g.plane(k)[i]).epsilon(1e-5));
  }
}

TEST_CASE("training: the lobe L1 respects the lobe's symmetries and its gradient matches finite differences") {
  float q[parameter_count] = {}, p[parameter_count] = {};
  q[lobe_x] = 0.2f, q[lobe_y] = -0.4f, q[rotation] = 0.9f;  // anisotropic: full rotation weight
  // The truth and its equivalent form (sigma_x, sigma_y swapped, alpha + pi/2) are both at distance 0.
  std::copy_n(q, parameter_count, p);
  CHECK(training::lobe_l1(p, q, nullptr, 1) == 0);
  p[lobe_x] = q[lobe_y], p[lobe_y] = q[lobe_x], p[rotation] = q[rotation] - 1;  // 0.9 + 1 wraps to -0.1
  CHECK(training::lobe_l1(p, q, nullptr, 1) < 1e-6);
  // Rotation differences are taken modulo pi: 0.95 and -0.95 are 0.1 apart, not 1.9.
  std::copy_n(q, parameter_count, p);
  q[rotation] = 0.95f, p[rotation] = -0.95f;
  CHECK(training::lobe_l1(p, q, nullptr, 1) == doctest::Approx(0.1).epsilon(1e-5));
  // Gradient against central differences at a point away from the kinks.
  p[lobe_x] = 0.05f, p[lobe_y] = -0.3f, p[rotation] = 0.6f;
  float g[parameter_count] = {};
  training::lobe_l1(p, q, g, 1);
  for (int k : {int(lobe_x), int(lobe_y), int(rotation)}) {
    const float h = 1e-3f;
    float plus[parameter_count], minus[parameter_count];
    std::copy_n(p, parameter_count, plus);
    std::copy_n(p, parameter_count, minus);
    plus[k] += h, minus[k] -= h;
    const double fd = (training::lobe_l1(plus, q, nullptr, 1) - training::lobe_l1(minus, q, nullptr, 1)) / (2 * h);
    CHECK(g[k] == doctest::Approx(fd).epsilon(1e-3));
  }
  // An isotropic truth has no rotation to learn: no rotation term and no rotation gradient.
  q[lobe_y] = q[lobe_x];
  std::fill_n(g, parameter_count, 0.0f);
  const double a = training::lobe_l1(p, q, g, 1);
  p[rotation] = -0.2f;
  CHECK(training::lobe_l1(p, q, nullptr, 1) == doctest::Approx(a));
  CHECK(g[rotation] == 0);
  CHECK(g[lobe_x] != 0);
}

TEST_CASE("training: a network output in the truth's equivalent lobe form has no L1 loss") {
  std::vector<training::sample> s;
  s.push_back(training::make_sample(training::validation_seed(3), 32, false));
  tensor<parameter_count> swapped = s[0].truth_net;
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 32; ++x) {
      float* p = swapped.pixel(0, y, x);
      std::swap(p[lobe_x], p[lobe_y]);
      p[rotation] = p[rotation] > 0 ? p[rotation] - 1 : p[rotation] + 1;  // alpha + pi/2, kept in [-1, 1]
    }
  const auto exact = training::map_losses(s[0].truth_net, s, nullptr);
  const auto other = training::map_losses(swapped, s, nullptr);
  CHECK(other.l1 < 1e-6);
  CHECK(std::abs(other.render - exact.render) < 1e-3);  // the same lobes render the same
}

TEST_CASE("training materials: the held-out families never appear among training or validation samples") {
  for (material_mix mix : {material_mix::original, material_mix::training}) {
    const procedural_options options = training::training_material_options(mix);
    int seen[material_kind_count] = {};
    for (std::uint64_t run : {1ULL, 5ULL, 12345ULL})
      for (long step = 0; step < 2000; ++step)
        for (int b = 0; b < 4; ++b) ++seen[int(draw_procedural_parameters(training::training_seed(run, step, b), options).kind)];
    for (int i = 0; i < 500; ++i) ++seen[int(draw_procedural_parameters(training::validation_seed(i), options).kind)];
    for (material_kind k : held_out_kinds) CHECK(seen[int(k)] == 0);
    // The training mix does draw every other kind, the new ones included.
    if (mix == material_mix::training)
      for (int k = 0; k < material_kind_count; ++k)
        if (!is_held_out(static_cast<material_kind>(k))) CHECK(seen[k] > 100);
  }
  // make_sample itself draws from the same options: its truth is the forced-kind material of that seed.
  const std::uint64_t seed = training::training_seed(7, 3, 1);
  const training::sample s = training::make_sample(seed, 32, false, material_mix::training);
  procedural_options forced;
  forced.mix = material_mix::training;
  const material_maps expected = generate_material(seed, 32, 32, forced);
  CHECK(std::equal(s.truth.plane(0), s.truth.plane(0) + 32 * 32, expected.plane(0)));
  CHECK_FALSE(is_held_out(draw_procedural_parameters(seed, forced).kind));
  // The extended mix (held-out families included) is refused before anything is written.
  CHECK_THROWS_AS(training::training_material_options(material_mix::extended), std::invalid_argument);
  const fs::path dir = fresh_folder("networks_extended");
  auto o = tiny_options(dir, 64);
  o.mix = material_mix::extended;
  estimation_network<testing::estimator_tiny> net(3);
  CHECK_THROWS_AS(training::train_estimator(o, net), std::invalid_argument);
  CHECK_FALSE(fs::exists(dir));
}

TEST_CASE("training materials: a run resumes only on the mix it started with") {
  const fs::path dir = fresh_folder("networks_mix_resume");
  {
    auto_encoder<testing::autoencoder_tiny> net(3);
    auto o = tiny_options(dir, 32);
    o.mix = material_mix::training;
    o.stop_after = 2;
    training::train_autoencoder(o, net);
  }
  auto_encoder<testing::autoencoder_tiny> net(3);
  auto o = tiny_options(dir, 32);
  o.resume = true;  // mix left at original
  CHECK_THROWS_WITH_AS(training::train_autoencoder(o, net), doctest::Contains("resume it with train_options::mix training"), std::runtime_error);
  o.mix = material_mix::training;
  training::train_autoencoder(o, net);
  CHECK(fs::exists(dir / "autoencoder.safetensors"));
  fs::remove_all(dir);
}

TEST_CASE("training materials: an emphasis draws its share of the materials from its families, the rest from the mix") {
  training::train_options o;
  o.mix = material_mix::training;
  // The fraction of metals (brushed or spun) and of brushed metal among 4000 training or validation seeds.
  auto metal_fraction = [&](std::vector<material_kind> emphasis, double share, bool validation) {
    o.emphasis = std::move(emphasis);
    o.emphasis_share = share;
    int metal = 0, brushed = 0;
    for (int i = 0; i < 4000; ++i) {
      const std::uint64_t seed = validation ? training::validation_seed(i) : training::training_seed(12, i / 2, i % 2);
      const material_kind k = draw_procedural_parameters(seed, training::material_options_for_seed(o, seed)).kind;
      CHECK_FALSE(is_held_out(k));
      metal += is_metal(k);
      brushed += k == material_kind::brushed_metal;
    }
    return std::pair{metal / 4000.0, brushed / 4000.0};
  };
  const std::vector<material_kind> metals = {material_kind::brushed_metal, material_kind::spun_metal};
  for (bool validation : {false, true}) {
    // Without an emphasis the mix alone: brushed and spun are 28 of the training mix's 85 weights.
    const double mix_only = metal_fraction({}, 0.5, validation).first;
    CHECK(mix_only == doctest::Approx(28.0 / 85).epsilon(0.15));
    // share + (1 - share) * 28/85, the two metals alike.
    const auto [half, brushed_half] = metal_fraction(metals, 0.5, validation);
    CHECK(half == doctest::Approx(0.5 + 0.5 * 28.0 / 85).epsilon(0.06));
    CHECK(brushed_half == doctest::Approx(half / 2).epsilon(0.15));
    CHECK(metal_fraction(metals, 1.0, validation).first == 1.0);
    // Share 0 draws exactly what the mix alone draws, seed by seed.
    CHECK(metal_fraction(metals, 0.0, validation).first == mix_only);
  }
  // A held-out family, or a share outside [0, 1], is refused before anything is written.
  const fs::path dir = fresh_folder("networks_emphasis_refused");
  auto bad = tiny_options(dir, 32);
  bad.emphasis = {material_kind::leather};
  auto_encoder<testing::autoencoder_tiny> net(3);
  CHECK_THROWS_WITH_AS(training::train_autoencoder(bad, net), doctest::Contains("held-out family 'leather'"), std::invalid_argument);
  bad.emphasis = {material_kind::spun_metal};
  bad.emphasis_share = 1.5;
  CHECK_THROWS_WITH_AS(training::train_autoencoder(bad, net), doctest::Contains("train_options::emphasis_share"), std::invalid_argument);
  CHECK_FALSE(fs::exists(dir));
}

TEST_CASE("training materials: a run resumes only with the emphasis it started with") {
  const fs::path dir = fresh_folder("networks_emphasis_resume");
  {
    auto_encoder<testing::autoencoder_tiny> net(3);
    auto o = tiny_options(dir, 32);
    o.emphasis = {material_kind::brushed_metal, material_kind::spun_metal};
    o.emphasis_share = 0.5;
    o.stop_after = 2;
    training::train_autoencoder(o, net);
  }
  CHECK(training::read_checkpoint_description(dir).at("emphasis") == "brushed,spun");
  auto_encoder<testing::autoencoder_tiny> net(3);
  auto o = tiny_options(dir, 32);
  o.resume = true;  // no emphasis
  CHECK_THROWS_WITH_AS(training::train_autoencoder(o, net), doctest::Contains("resume it with train_options::emphasis brushed,spun"), std::runtime_error);
  o.emphasis = {material_kind::brushed_metal, material_kind::spun_metal};
  o.emphasis_share = 0.25;
  CHECK_THROWS_WITH_AS(training::train_autoencoder(o, net), doctest::Contains("resume it with train_options::emphasis_share 0.5"), std::runtime_error);
  o.emphasis_share = 0.5;
  training::train_autoencoder(o, net);
  CHECK(fs::exists(dir / "autoencoder.safetensors"));
  fs::remove_all(dir);
}

namespace {

std::string file_text(const fs::path& file) {
  std::ifstream in(file);
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

/// The tiny auto-encoder's widths under another preset name: its weights fit the tiny one's.
struct autoencoder_tiny_renamed : testing::autoencoder_tiny {
  static constexpr const char* name = "tiny_renamed";
};

bool any_line_contains(const std::vector<std::string>& lines, const std::string& part) {
  return std::any_of(lines.begin(), lines.end(), [&](const std::string& l) { return l.find(part) != std::string::npos; });
}

/// Runs the tiny estimator run `o` (from a network of seed 3) and stops it after `steps` steps, at
/// one of its check-points.
void stopped_estimator_run(training::train_options o, long steps) {
  estimation_network<testing::estimator_tiny> net(3);
  o.stop_after = steps;
  training::train_estimator(o, net);
}

/// What a resumed tiny estimator run ends with: its weights and its log.
struct resumed_estimator_run {
  std::vector<float> weights;
  std::vector<std::string> log;
};

/// Resumes the run in o.out_dir with the options `o` (a network of another seed, which the
/// check-point's weights replace).
resumed_estimator_run resume_estimator_run(training::train_options o) {
  resumed_estimator_run r;
  estimation_network<testing::estimator_tiny> net(99);
  o.resume = true;
  o.log = [&](const std::string& line) { r.log.push_back(line); };
  training::train_estimator(o, net);
  r.weights = all_weights(net);
  return r;
}

}  // namespace

TEST_CASE("training: a resume with another network, preset, seed, size, batch or loss weight is refused, naming checkpoint.json and the saved value") {
  const fs::path dir = fresh_folder("networks_resume_settings");
  {
    auto_encoder<testing::autoencoder_tiny> net(3);
    auto o = tiny_options(dir, 32);
    o.stop_after = 2;
    training::train_autoencoder(o, net);
  }
  const std::string saved = file_text(dir / "checkpoint.json");
  auto resume = [&] {
    auto o = tiny_options(dir, 32);
    o.resume = true;
    return o;
  };
  auto_encoder<testing::autoencoder_tiny> net(3);
  auto refused = [](auto train, const std::string& message) {
    CHECK_THROWS_WITH_AS(train(), doctest::Contains("checkpoint.json"), std::runtime_error);
    CHECK_THROWS_WITH_AS(train(), doctest::Contains(message.c_str()), std::runtime_error);
  };
  auto o = resume();
  o.batch = 4;
  refused([&] { training::train_autoencoder(o, net); }, "trained with batch 2, not 4; resume it with train_options::batch 2");
  o = resume();
  o.seed = 6;
  refused([&] { training::train_autoencoder(o, net); }, "trained with seed 5, not 6; resume it with train_options::seed 5");
  o = resume();
  o.size = 64;
  refused([&] { training::train_autoencoder(o, net); }, "trained with size 32, not 64; resume it with train_options::size 32");
  o = resume();
  o.render_weight = 0.25;
  refused([&] { training::train_autoencoder(o, net); }, "trained with render_weight 1, not 0.25; resume it with train_options::render_weight 1");
  o = resume();
  o.sigma_weight = 2;
  refused([&] { training::train_autoencoder(o, net); }, "trained with sigma_weight 0, not 2; resume it with train_options::sigma_weight 0");
  o = resume();
  o.mse_weight = 4;
  refused([&] { training::train_autoencoder(o, net); }, "trained with mse_weight 0, not 4; resume it with train_options::mse_weight 0");
  o = resume();
  o.lobe_weight = 3;
  refused([&] { training::train_autoencoder(o, net); }, "trained with lobe_weight 1, not 3; resume it with train_options::lobe_weight 1");
  o = resume();
  o.diffuse_weight = 2;
  refused([&] { training::train_autoencoder(o, net); }, "trained with diffuse_weight 1, not 2; resume it with train_options::diffuse_weight 1");
  o = resume();
  o.normal_weight = 0.5;
  refused([&] { training::train_autoencoder(o, net); }, "trained with normal_weight 1, not 0.5; resume it with train_options::normal_weight 1");
  o = resume();
  o.lr_warmup = 3;
  refused([&] { training::train_autoencoder(o, net); }, "trained with lr_warmup 0, not 3; resume it with train_options::lr_warmup 0");
  auto_encoder<autoencoder_tiny_renamed> renamed(3);
  o = resume();
  refused([&] { training::train_autoencoder(o, renamed); }, "trained with preset tiny, not tiny_renamed; resume it with the preset tiny");
  estimation_network<testing::estimator_tiny> estimator(3);
  o = resume();
  o.size = 64;
  refused([&] { training::train_estimator(o, estimator); }, "trains the autoencoder, not the estimator; resume it with train_autoencoder");
  // Refused resumes change nothing; the run's own settings resume it to the end.
  CHECK(file_text(dir / "checkpoint.json") == saved);
  training::train_autoencoder(resume(), net);
  CHECK(training::read_checkpoint_description(dir).at("step").get<long>() == 4);
  fs::remove_all(dir);
}

TEST_CASE("training: a resume keeps the saved learning rate, or logs, records and uses another one") {
  const fs::path straight = fresh_folder("networks_rate_straight"), kept = fresh_folder("networks_rate_kept"),
                 lowered = fresh_folder("networks_rate_lowered");
  estimation_network<testing::estimator_tiny> reference(3);
  training::train_estimator(tiny_options(straight, 64), reference);  // 1e-3 throughout
  for (const fs::path& dir : {kept, lowered}) {
    estimation_network<testing::estimator_tiny> killed(3);
    auto o = tiny_options(dir, 64);
    o.stop_after = 2;
    training::train_estimator(o, killed);
  }
  std::vector<std::string> log;
  auto resume = [&](const fs::path& dir, double rate) {
    auto o = tiny_options(dir, 64);
    o.resume = true;
    o.learning_rate = rate;
    o.log = [&](const std::string& line) { log.push_back(line); };
    return o;
  };
  // Without --lr the run keeps its saved 1e-3 (not the estimator's default 5e-5): the straight run's weights.
  estimation_network<testing::estimator_tiny> same(99);
  training::train_estimator(resume(kept, 0), same);
  const auto w = all_weights(reference), w_same = all_weights(same);
  REQUIRE(w.size() == w_same.size());
  CHECK(std::equal(w.begin(), w.end(), w_same.begin()));
  CHECK_FALSE(any_line_contains(log, "learning rate"));
  json description = training::read_checkpoint_description(kept);
  CHECK(description.at("learning_rate").get<double>() == 1e-3);
  CHECK_FALSE(description.contains("learning_rate_changes"));
  // Another rate is logged, recorded in checkpoint.json and used.
  estimation_network<testing::estimator_tiny> slower(99);
  log.clear();
  training::train_estimator(resume(lowered, 3e-4), slower);
  CHECK(any_line_contains(log, "estimator: learning rate 0.001 -> 0.0003 from step 2"));
  description = training::read_checkpoint_description(lowered);
  CHECK(description.at("learning_rate").get<double>() == 3e-4);
  REQUIRE(description.at("learning_rate_changes").size() == 1);
  const json change = description.at("learning_rate_changes")[0];
  CHECK(change.at("step").get<long>() == 2);
  CHECK(change.at("from").get<double>() == 1e-3);
  CHECK(change.at("to").get<double>() == 3e-4);
  const auto w_slower = all_weights(slower);
  CHECK_FALSE(std::equal(w.begin(), w.end(), w_slower.begin()));
  // Resuming again at the new rate, given or not, is no change: nothing logged, the record kept.
  for (double rate : {3e-4, 0.0}) {
    log.clear();
    auto o = resume(lowered, rate);
    o.steps += rate > 0 ? 1 : 2;
    training::train_estimator(o, slower);
    CHECK_FALSE(any_line_contains(log, "learning rate"));
    description = training::read_checkpoint_description(lowered);
    CHECK(description.at("learning_rate").get<double>() == 3e-4);
    CHECK(description.at("learning_rate_changes").size() == 1);
  }
  fs::remove_all(straight);
  fs::remove_all(kept);
  fs::remove_all(lowered);
}

TEST_CASE("training: a learning-rate decay resumes exactly, is kept on resume, and can be added to a constant run") {
  const fs::path straight = fresh_folder("networks_decay_straight"), resumed = fresh_folder("networks_decay_resumed"),
                 added = fresh_folder("networks_decay_added"), constant = fresh_folder("networks_decay_constant");
  auto decaying = [](const fs::path& dir) {
    auto o = tiny_options(dir, 64);
    o.lr_decay_from = 2;
    o.lr_decay_to = 4;
    o.lr_end = 0.1;
    return o;
  };
  estimation_network<testing::estimator_tiny> reference(3);
  training::train_estimator(decaying(straight), reference);
  json description = training::read_checkpoint_description(straight);
  REQUIRE(description.contains("lr_decay"));
  CHECK(description.at("lr_decay") == json::array({2, 4, 0.1}));
  CHECK(description.at("learning_rate").get<double>() == 1e-3);  // the base rate, not the decayed one
  // Stopped after 2 steps and resumed without the decay options: the saved decay goes on, and the
  // weights are the uninterrupted run's.
  stopped_estimator_run(decaying(resumed), 2);
  auto o = tiny_options(resumed, 64);
  o.learning_rate = 0;
  const auto continued = resume_estimator_run(o);
  const auto w = all_weights(reference);
  REQUIRE(w.size() == continued.weights.size());
  CHECK(std::equal(w.begin(), w.end(), continued.weights.begin()));
  CHECK_FALSE(any_line_contains(continued.log, "decays"));
  CHECK(training::read_checkpoint_description(resumed).at("lr_decay") == json::array({2, 4, 0.1}));
  // The decay changes the result: a constant-rate run of the same seed ends elsewhere.
  estimation_network<testing::estimator_tiny> flat(3);
  training::train_estimator(tiny_options(constant, 64), flat);
  const auto w_flat = all_weights(flat);
  CHECK_FALSE(std::equal(w.begin(), w.end(), w_flat.begin()));
  // A constant run resumed with a decay that starts where it stopped: logged, recorded, and the same
  // weights as a run that had the decay from the start (the schedule is a function of the step).
  stopped_estimator_run(tiny_options(added, 64), 2);
  const auto second_half = resume_estimator_run(decaying(added));
  CHECK(any_line_contains(second_half.log, "estimator: learning rate decays from step 2 to 0.1 of itself at step 4"));
  CHECK(training::read_checkpoint_description(added).at("lr_decay") == json::array({2, 4, 0.1}));
  CHECK(std::equal(w.begin(), w.end(), second_half.weights.begin()));
  // Impossible decays are refused before anything is written.
  auto bad = decaying(fresh_folder("networks_decay_bad"));
  bad.lr_decay_to = 2;
  estimation_network<testing::estimator_tiny> unused(3);
  CHECK_THROWS_WITH_AS(training::train_estimator(bad, unused), doctest::Contains("train_options::lr_decay_to"), std::invalid_argument);
  CHECK_FALSE(fs::exists(bad.out_dir));
  bad.lr_decay_to = 4;
  bad.lr_end = 2;
  CHECK_THROWS_WITH_AS(training::train_estimator(bad, unused), doctest::Contains("train_options::lr_end"), std::invalid_argument);
  for (const fs::path& dir : {straight, resumed, added, constant}) fs::remove_all(dir);
}

TEST_CASE("training: a learning-rate warm-up ramps the schedule's first steps, resumes exactly and is recorded") {
  // The schedule: step s < N at (s + 1) / N of the rate, on top of a decay, and the decay's rates after it.
  training::train_options o;
  o.lr_warmup = 4;
  o.lr_decay_from = 2;
  o.lr_decay_to = 10;
  o.lr_end = 0.1;
  const auto warm = training::training_schedule(1e-3, o);
  o.lr_warmup = 0;
  const auto cold = training::training_schedule(1e-3, o);
  for (long s = 0; s < 12; ++s) CHECK(warm(s) == doctest::Approx(cold(s) * (s < 4 ? double(s + 1) / 4 : 1.0)).epsilon(1e-12));
  CHECK(warm(0) == doctest::Approx(2.5e-4));
  CHECK(warm(11) == doctest::Approx(1e-4));

  const fs::path straight = fresh_folder("networks_warmup_straight"), resumed = fresh_folder("networks_warmup_resumed"),
                 cold_dir = fresh_folder("networks_warmup_cold");
  auto warming = [](const fs::path& dir) {
    auto t = tiny_options(dir, 64);
    t.lr_warmup = 3;
    return t;
  };
  estimation_network<testing::estimator_tiny> reference(3);
  training::train_estimator(warming(straight), reference);
  CHECK(training::read_checkpoint_description(straight).at("lr_warmup").get<long>() == 3);
  // checkpoint.json keeps the base rate, not the warm-up's first step's.
  CHECK(training::read_checkpoint_description(straight).at("learning_rate").get<double>() == 1e-3);
  stopped_estimator_run(warming(resumed), 2);  // inside the warm-up
  // Resumed without --lr: the saved base rate and warm-up go on.
  auto t = warming(resumed);
  t.learning_rate = 0;
  const auto continued = resume_estimator_run(t);
  CHECK_FALSE(any_line_contains(continued.log, "learning rate"));
  CHECK_FALSE(training::read_checkpoint_description(resumed).contains("learning_rate_changes"));
  const auto w = all_weights(reference);
  REQUIRE(w.size() == continued.weights.size());
  CHECK(std::equal(w.begin(), w.end(), continued.weights.begin()));
  // The warm-up changes the result: a run of the same seed without it ends elsewhere.
  estimation_network<testing::estimator_tiny> flat(3);
  training::train_estimator(tiny_options(cold_dir, 64), flat);
  const auto w_flat = all_weights(flat);
  CHECK_FALSE(std::equal(w.begin(), w.end(), w_flat.begin()));
  // A negative warm-up is refused before anything is written.
  auto bad = warming(fresh_folder("networks_warmup_bad"));
  bad.lr_warmup = -1;
  estimation_network<testing::estimator_tiny> unused(3);
  CHECK_THROWS_WITH_AS(training::train_estimator(bad, unused), doctest::Contains("train_options::lr_warmup"), std::invalid_argument);
  CHECK_FALSE(fs::exists(bad.out_dir));
  for (const fs::path& dir : {straight, resumed, cold_dir}) fs::remove_all(dir);
}

TEST_CASE("training: a re-warm-up ramps the rate again from a given step, resumes exactly and is kept on resume") {
  // The schedule: step s in [S, S + N) at (s - S + 1) / N of the rate, on top of the first warm-up
  // and the decay; the steps outside the window as without it.
  training::train_options o;
  o.lr_warmup = 2;
  o.lr_decay_from = 6;
  o.lr_decay_to = 10;
  o.lr_end = 0.1;
  const auto plain = training::training_schedule(1e-3, o);
  o.lr_rewarmup_from = 5;
  o.lr_rewarmup = 4;
  const auto again = training::training_schedule(1e-3, o);
  for (long s = 0; s < 14; ++s)
    CHECK(again(s) == doctest::Approx(plain(s) * (s >= 5 && s < 9 ? double(s - 4) / 4 : 1.0)).epsilon(1e-12));
  CHECK(again(0) == doctest::Approx(5e-4));  // the first warm-up is untouched
  CHECK(again(5) == doctest::Approx(2.5e-4));
  CHECK(again(9) == doctest::Approx(plain(9)).epsilon(1e-12));

  const fs::path straight = fresh_folder("networks_rewarmup_straight"), resumed = fresh_folder("networks_rewarmup_resumed"),
                 added = fresh_folder("networks_rewarmup_added"), flat_dir = fresh_folder("networks_rewarmup_flat");
  auto rewarming = [](const fs::path& dir) {
    auto t = tiny_options(dir, 64);
    t.lr_rewarmup_from = 1;
    t.lr_rewarmup = 3;
    t.checkpoint_every = 1;  // so that a run can stop after its first step
    return t;
  };
  estimation_network<testing::estimator_tiny> reference(3);
  training::train_estimator(rewarming(straight), reference);
  CHECK(training::read_checkpoint_description(straight).at("lr_rewarmup") == json::array({1, 3}));
  const auto w = all_weights(reference);
  // Stopped inside the re-warm-up and resumed without naming it: the saved one goes on, and the
  // weights are the uninterrupted run's.
  stopped_estimator_run(rewarming(resumed), 2);
  {
    auto t = tiny_options(resumed, 64);
    t.learning_rate = 0;
    const auto continued = resume_estimator_run(t);
    CHECK_FALSE(any_line_contains(continued.log, "warms up again"));
    CHECK(training::read_checkpoint_description(resumed).at("lr_rewarmup") == json::array({1, 3}));
    REQUIRE(w.size() == continued.weights.size());
    CHECK(std::equal(w.begin(), w.end(), continued.weights.begin()));
  }
  // A constant run stopped after its first step and resumed with the re-warm-up from there: logged,
  // recorded, and the same weights as the run that had it from the start.
  {
    auto t = tiny_options(added, 64);
    t.checkpoint_every = 1;
    stopped_estimator_run(t, 1);
    const auto rest = resume_estimator_run(rewarming(added));
    CHECK(any_line_contains(rest.log, "estimator: learning rate warms up again from step 1 over 3 steps"));
    CHECK(training::read_checkpoint_description(added).at("lr_rewarmup") == json::array({1, 3}));
    CHECK(std::equal(w.begin(), w.end(), rest.weights.begin()));
  }
  // The re-warm-up changes the result: the same run without it ends elsewhere.
  estimation_network<testing::estimator_tiny> flat(3);
  training::train_estimator(tiny_options(flat_dir, 64), flat);
  const auto w_flat = all_weights(flat);
  CHECK_FALSE(std::equal(w.begin(), w.end(), w_flat.begin()));
  // A re-warm-up without its first step, or a negative one, is refused before anything is written.
  auto bad = tiny_options(fresh_folder("networks_rewarmup_bad"), 64);
  bad.lr_rewarmup = 3;
  estimation_network<testing::estimator_tiny> unused(3);
  CHECK_THROWS_WITH_AS(training::train_estimator(bad, unused), doctest::Contains("train_options::lr_rewarmup_from"), std::invalid_argument);
  CHECK_FALSE(fs::exists(bad.out_dir));
  bad.lr_rewarmup = -1;
  bad.lr_rewarmup_from = 0;
  CHECK_THROWS_WITH_AS(training::train_estimator(bad, unused), doctest::Contains("train_options::lr_rewarmup"), std::invalid_argument);
  CHECK_FALSE(fs::exists(bad.out_dir));
  // A saved re-warm-up or decay whose step numbers are not integers, or that lacks one, is refused on
  // a resume that does not name its own, naming checkpoint.json; the check-point stays as it was.
  const json good = training::read_checkpoint_description(resumed);
  for (const auto& [key, value] : {std::pair<std::string, json>{"lr_rewarmup", json::array({1.5, 3})},
                                   std::pair<std::string, json>{"lr_decay", json::array({2, 4})},
                                   std::pair<std::string, json>{"lr_decay", json::array({2, "4", 0.1})}}) {
    const std::string shown = value.dump();  // a named copy: Clang 14's CAPTURE cannot refer to a structured binding
    CAPTURE(shown);
    json broken = good;
    broken[key] = value;
    std::ofstream(resumed / "checkpoint.json") << broken.dump(2);
    auto t = tiny_options(resumed, 64);
    t.learning_rate = 0;
    const std::string message = "checkpoint.json: malformed \"" + key + "\"";
    CHECK_THROWS_WITH_AS(resume_estimator_run(t), doctest::Contains(message.c_str()), std::runtime_error);
    CHECK(training::read_checkpoint_description(resumed) == broken);
  }
  for (const fs::path& dir : {straight, resumed, added, flat_dir}) fs::remove_all(dir);
}

TEST_CASE("training: checkpoints as earlier versions wrote them resume with their own settings") {
  // The seed written as 4.0, the rate as 3e-04, and (older still) no "materials" (the original mix)
  // and no "render_weight" (1).
  const json saved = parse_json(R"({"network": "estimator", "preset": "compact", "seed": 4.0, "size": 128, "batch": 2,
                                    "learning_rate": 3e-04, "step": 11952, "optimizer_steps": 11952, "file": "c.safetensors"})",
                                "checkpoint.json");
  json given = {{"network", "estimator"}, {"preset", "compact"}, {"seed", 4.0}, {"size", 128}, {"batch", 2},
                {"learning_rate", 3e-4}, {"materials", "original"}, {"render_weight", 1.0}};
  CHECK_NOTHROW(training::detail::check_resume_settings(saved, given, "checkpoint.json"));
  given["render_weight"] = 0.1;
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(saved, given, "checkpoint.json"),
                       doctest::Contains("resume it with train_options::render_weight 1"), std::runtime_error);
  given["render_weight"] = 1.0;
  given["materials"] = "training";
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(saved, given, "checkpoint.json"),
                       doctest::Contains("resume it with train_options::mix original"), std::runtime_error);
  given["materials"] = "original";
  given["emphasis"] = "brushed";
  given["emphasis_share"] = 0.5;
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(saved, given, "checkpoint.json"),
                       doctest::Contains("resume it without train_options::emphasis"), std::runtime_error);
  given["emphasis"] = "";
  given["emphasis_share"] = 0.0;
  CHECK_NOTHROW(training::detail::check_resume_settings(saved, given, "checkpoint.json"));
  // A checkpoint without input noise trained on exact renders: a resume with noise is another run.
  given["shot_noise"] = 0.02;
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(saved, given, "checkpoint.json"),
                       doctest::Contains("trained with shot_noise 0, not 0.02; resume it with train_options::input_noise.shot 0"), std::runtime_error);
  json noisy = saved;
  noisy["read_noise"] = 0.002;
  given["shot_noise"] = 0.0;
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(noisy, given, "checkpoint.json"),
                       doctest::Contains("resume it with train_options::input_noise.read 0.002"), std::runtime_error);
  given["read_noise"] = 0.002;
  CHECK_NOTHROW(training::detail::check_resume_settings(noisy, given, "checkpoint.json"));
  given.erase("read_noise");
  json wrong = saved;
  wrong["seed"] = "4";
  CHECK_THROWS_WITH_AS(training::detail::check_resume_settings(wrong, given, "checkpoint.json"), doctest::Contains("malformed \"seed\""),
                       std::runtime_error);
}
