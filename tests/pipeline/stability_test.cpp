// Numerical stability of the capture: the per-texel refine and the pipeline on
// procedural materials under saturated highlights, near-grazing configurations, corrupted inputs
// and intensities scaled by 1e-4 and 1e4. Measured values are in the comments beside each bound;
// studies/stability.cpp prints the same scenarios at 256 x 256 (studies/README.md, "Numerical
// stability").
//
// Not here, because covered elsewhere: extreme parameters and configurations through the fused
// kernel (tests/render/stress_test.cpp); a NaN, infinite or negative pixel in a capture image
// read through load_capture_images, with the file, pixel and image index in the message
// (tests/data/capture_io_test.cpp, tests/data/image_io_test.cpp).
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "../networks/tiny_presets.hpp"
#include "../support/stability_scenes.hpp"
#include "anisocap/core/random.hpp"
#include "anisocap/data/procedural.hpp"
#include "../support/capture_options.hpp"
#include "anisocap/pipeline/capture.hpp"
#include "anisocap/render/evaluate.hpp"
#include "anisocap/pipeline/refine.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

/// A procedural material, a set-alpha capture of it and its rendered photographs.
struct procedural_scene {
  material_maps truth;
  capture cap;
  std::vector<image> photos;
  procedural_scene(std::uint64_t seed, int size, int images = 12)
      : truth(generate_material(seed, size, size)), cap(set_alpha(images, seed, size, size)), photos(render(truth, cap)) {}
};

/// Number of map values that are not finite or lie outside their parameter's range (docs/method.md section 1):
/// albedos and F0 in [0, 1], lobe widths in (0, 1], normal (x, y) inside the unit disc, alpha in
/// [-pi/2, pi/2].
std::size_t invalid_values(const material_maps& m) {
  std::size_t bad = 0;
  const float half_pi = std::numbers::pi_v<float> / 2;
  for (std::size_t i = 0; i < m.texel_count(); ++i) {
    for (int k = 0; k < parameter_count; ++k) bad += !std::isfinite(m.plane(k)[i]);
    for (int k : {diffuse_r, diffuse_g, diffuse_b, specular_r, specular_g, specular_b, fresnel_f0})
      bad += !(m.plane(k)[i] >= 0.0f && m.plane(k)[i] <= 1.0f);
    for (int k : {lobe_x, lobe_y}) bad += !(m.plane(k)[i] > 0.0f && m.plane(k)[i] <= 1.0f);
    const float nx = m.plane(normal_x)[i], ny = m.plane(normal_y)[i];
    bad += !(nx * nx + ny * ny < 1.0f);
    bad += !(std::abs(m.plane(rotation)[i]) <= half_pi * (1 + 1e-6f));
  }
  return bad;
}

bool all_finite(const std::vector<double>& values) {
  return std::all_of(values.begin(), values.end(), [](double v) { return std::isfinite(v); });
}

/// Fraction of pixel values of the photographs that are at or above `level`.
double fraction_at_or_above(const std::vector<image>& photos, float level) {
  std::size_t n = 0, total = 0;
  for (const image& p : photos)
    for (int c = 0; c < p.channels(); ++c)
      for (std::size_t i = 0; i < p.pixel_count(); ++i, ++total) n += p.plane(c)[i] >= level;
  return double(n) / double(total);
}

/// Runs the pipeline with fresh tiny networks (same seeds each call, so runs are comparable).
capture_result run_tiny(const capture& cap, const std::vector<image>& photos, const capture_options& o) {
  estimation_network<estimator_tiny> estimator(1);
  auto_encoder<autoencoder_tiny> autoencoder(2);
  return capture_once(cap, photos, estimator, autoencoder, o);
}

/// Largest difference per parameter group between two map sets, for messages and checks.
struct group_differences {
  double diffuse, specular, lobes, fresnel, normal, alpha;  // (not `rotation`: that would hide the plane index)
  explicit group_differences(const material_maps& a, const material_maps& b)
      : diffuse(max_difference(a, b, diffuse_r, diffuse_b)), specular(max_difference(a, b, specular_r, specular_b)),
        lobes(max_difference(a, b, lobe_x, lobe_y)), fresnel(max_difference(a, b, fresnel_f0, fresnel_f0)),
        normal(max_difference(a, b, normal_x, normal_y)), alpha(max_difference(a, b, anisocap::rotation, anisocap::rotation)) {}
  double largest() const { return std::max({diffuse, specular, lobes, fresnel, normal, alpha}); }
};

std::ostream& operator<<(std::ostream& out, const group_differences& d) {
  return out << "a_d " << d.diffuse << ", a'_s " << d.specular << ", sigma " << d.lobes << ", F0 " << d.fresnel << ", n "
             << d.normal << ", alpha " << d.alpha;
}


}  // namespace

TEST_CASE("stability: saturated highlights keep the refine finite and the diffuse albedo close to the truth") {
  const procedural_scene s(21, 64);
  // Reference: the same refine on the unclipped photographs.
  refine_options o;
  o.steps = 150;
  material_maps reference = initial_guess(s.cap, s.photos);
  refine(reference, s.cap, make_loss_targets(s.photos), o);
  const double reference_diffuse = compare_maps(reference, s.truth).diffuse;
  INFO("unclipped: diffuse MSE " << reference_diffuse);

  const float q95 = quantile(s.photos, 0.95);
  for (const float level : {1.0f, q95}) {
    CAPTURE(level);
    const std::vector<image> photos = clipped(s.photos, level);
    // The scenario clips something: highlights above 1 exist in a set-alpha capture.
    REQUIRE(fraction_at_or_above(photos, level) >= 0.001);
    material_maps maps = initial_guess(s.cap, photos);
    const refine_result r = refine(maps, s.cap, make_loss_targets(photos), o);
    REQUIRE(all_finite(r.losses));
    REQUIRE(std::isfinite(r.final_loss));
    CHECK(invalid_values(maps) == 0);
    // Measured: 11.75 -> 0.66 (clipped at 1), 11.69 -> 0.61 (at the 95th percentile, 1.63).
    CHECK(r.final_loss < 0.2 * r.losses.front());
    const double diffuse = compare_maps(maps, s.truth).diffuse;
    INFO("clipped at " << level << " (" << fraction_at_or_above(photos, level) << " of the values): diffuse MSE "
                          << diffuse << ", loss " << r.losses.front() << " -> " << r.final_loss);
    // Measured diffuse MSE: 3.5e-6 (clipped at 1, 7.3% of the values), 2.9e-6 (95th percentile),
    // 2.3e-6 unclipped: clipped highlights barely move the diffuse albedo.
    CHECK(diffuse < 2e-5);
  }
}

TEST_CASE("stability: near-grazing cameras and lights only (75 to 88 degrees) keep the refine finite and valid") {
  const int size = 64;
  const material_maps truth = generate_material(22, size, size);
  const capture cap = grazing_capture(12, 22);
  // Angle from the normal of every camera and light at every texel (corners suffice: the angle is
  // monotonic in the horizontal distance).
  double lowest = 90, highest = 0;
  for (const auto& im : cap.images)
    for (const vec3f& p : {im.camera, im.light})
      for (const int x : {0, size - 1})
        for (const int y : {0, size - 1}) {
          const auto t = texel_position(x, y, size, size);
          const double horizontal = std::hypot(double(p[0]) - t[0], double(p[1]) - t[1]);
          const double degrees = std::atan2(horizontal, double(p[2])) * 180 / std::numbers::pi;
          lowest = std::min(lowest, degrees);
          highest = std::max(highest, degrees);
        }
  INFO("grazing capture: " << lowest << " to " << highest << " degrees from the normal");
  REQUIRE(lowest > 70.0);
  REQUIRE(highest < 89.0);
  const std::vector<image> photos = render(truth, cap);
  material_maps maps = initial_guess(cap, photos);
  refine_options o;
  o.steps = 200;
  const refine_result r = refine(maps, cap, make_loss_targets(photos), o);
  REQUIRE(all_finite(r.losses));
  REQUIRE(std::isfinite(r.final_loss));
  CHECK(invalid_values(maps) == 0);
  const double diffuse = compare_maps(maps, truth).diffuse;
  INFO("grazing: loss " << r.losses.front() << " -> " << r.final_loss << ", diffuse MSE " << diffuse);
  // Measured: loss 14.47 -> 2.40, diffuse MSE 1.9e-3 (light reaching the texels at 2 to 18 degrees
  // of elevation pins the albedo less well than the set-alpha captures above do).
  CHECK(r.final_loss < 0.3 * r.losses.front());
  CHECK(diffuse < 1e-2);
}

TEST_CASE("stability: a photograph with a NaN or infinite pixel is refused by the library entries") {
  const procedural_scene s(23, 48, 6);
  for (const float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    CAPTURE(bad);
    std::vector<image> photos = s.photos;
    photos[3].at(2, 17, 5) = bad;
    std::string message;
    try {
      (void)make_loss_targets(photos);
    } catch (const std::invalid_argument& e) {
      message = e.what();
    }
    CHECK(message.find("image 3") != std::string::npos);
    CHECK(message.find("(17, 5)") != std::string::npos);

    estimation_network<estimator_tiny> estimator(1);
    auto_encoder<autoencoder_tiny> autoencoder(2);
    capture_options po = measured_capture_options();
    po.stages = pipeline_stages{false, false, false, true};
    po.refine.steps = 5;
    CHECK_THROWS_AS(capture_once(s.cap, photos, estimator, autoencoder, po), std::invalid_argument);
  }
}

// Scaling a capture's intensities and photographs by one factor must not change its maps: capture_once
// normalises the exposure first (pipeline/exposure.hpp). For a power of two the normalised inputs
// are bit-identical, and so must the maps be. For 1e-4 and 1e4 they agree up to float rounding
// (relative 1e-7), which the optimisers then amplify: Adam's first steps move each variable by
// +-learning_rate whatever the size of its gradient, so where a gradient is rounding noise (alpha
// of a near-isotropic texel, the sigma / a'_s / F0 trade-off) single texels move apart. Measured:
// scaling by 1 + 2^-23 (one ulp) moves the maps as much as scaling by 1e-4 does (refine only,
// largest |difference| 0.19 in sigma and 0.63 rad in alpha for both), so the bounds below are on
// mean squared differences, with the normalisation switched off as the counter-example.
TEST_CASE("stability: intensities and photographs scaled by 1e-4 and 1e4 give the maps of the unscaled capture") {
  const procedural_scene s(24, 48, 8);
  capture_options o = measured_capture_options();
  o.stages = pipeline_stages{false, false, false, true};  // refine from the first guess
  o.refine.steps = 100;
  const capture_result reference = run_tiny(s.cap, s.photos, o);
  REQUIRE(invalid_values(reference.maps) == 0);
  for (const float factor : {0x1p-13f, 0x1p13f}) {
    CAPTURE(factor);
    const auto [cap, photos] = scaled(s.cap, s.photos, factor);
    const capture_result r = run_tiny(cap, photos, o);
    CHECK(r.exposure_scale == reference.exposure_scale / factor);
    CHECK(group_differences(r.maps, reference.maps).largest() == 0.0);
    CHECK(r.stages.back().loss == doctest::Approx(reference.stages.back().loss).epsilon(1e-9));
  }
  for (const float factor : {1e-4f, 1e4f}) {
    CAPTURE(factor);
    const auto [cap, photos] = scaled(s.cap, s.photos, factor);
    const capture_result r = run_tiny(cap, photos, o);
    CHECK(r.exposure_scale == doctest::Approx(reference.exposure_scale / factor).epsilon(1e-6));
    const parameter_errors e = compare_maps(r.maps, reference.maps);
    INFO("refine only, x" << factor << ": largest |difference| " << group_differences(r.maps, reference.maps)
                             << "; loss " << r.stages.back().loss << " against " << reference.stages.back().loss);
    // Measured (MSE against the unscaled run): 1e-4: a_d 1.7e-6, a'_s 1.9e-6, n 1.0e-5,
    // sigma 1.5e-5, alpha 2.3e-4, F0 2.2e-6; 1e4: about half of that.
    CHECK(e.diffuse < 2e-5);
    CHECK(e.specular < 2e-5);
    CHECK(e.normal < 1e-4);
    CHECK(e.lobes < 1e-4);
    CHECK(e.rotation < 2e-3);
    CHECK(e.fresnel < 2e-5);
    CHECK(r.stages.back().loss == doctest::Approx(reference.stages.back().loss).epsilon(0.01));  // measured 0.2%
  }
  // Without the normalisation the 1e-4 capture sinks under the loss's epsilon 0.01 and the maps
  // differ well beyond the bounds above (measured: a_d 1.1e-3, n 0.033, alpha 0.16).
  o.normalise_exposure = false;
  const auto [dark_cap, dark_photos] = scaled(s.cap, s.photos, 1e-4f);
  const capture_result raw = run_tiny(dark_cap, dark_photos, o);
  CHECK(raw.exposure_scale == 1.0);
  const parameter_errors e = compare_maps(raw.maps, reference.maps);
  CHECK(e.diffuse > 2e-4);
  CHECK(e.normal > 5e-3);
}

// The same through every stage with tiny untrained networks: the estimate sees the normalised
// photographs, the fine-tune and refine the normalised loss. Ten fine-tune steps of Adam on the
// decoder amplify rounding more than the refine does: one ulp (1 + 2^-23) gives MSEs after
// refine of a_d 1.3e-3, n 0.012, alpha 0.016, as 1e-4 and 1e4 do.
TEST_CASE("stability: the four-stage pipeline on tiny networks is invariant to the photographs' units") {
  const procedural_scene s(25, 64, 8);
  capture_options o = measured_capture_options();
  o.estimate.window = 64;
  o.estimate.stride = 64;
  o.finetune.steps = 10;
  o.refine.steps = 30;
  const capture_result reference = run_tiny(s.cap, s.photos, o);
  REQUIRE(reference.stages.size() == 4);
  REQUIRE(reference.after_finetune.has_value());
  for (const float factor : {0x1p-13f, 0x1p13f}) {
    CAPTURE(factor);
    const auto [cap, photos] = scaled(s.cap, s.photos, factor);
    const capture_result r = run_tiny(cap, photos, o);
    REQUIRE(r.after_finetune.has_value());
    CHECK(group_differences(*r.after_finetune, *reference.after_finetune).largest() == 0.0);
    CHECK(group_differences(r.maps, reference.maps).largest() == 0.0);
  }
  for (const float factor : {1e-4f, 1e4f}) {
    CAPTURE(factor);
    const auto [cap, photos] = scaled(s.cap, s.photos, factor);
    const capture_result r = run_tiny(cap, photos, o);
    REQUIRE(r.after_finetune.has_value());
    CHECK(invalid_values(r.maps) == 0);
    const parameter_errors fine = compare_maps(*r.after_finetune, *reference.after_finetune);
    const parameter_errors refined = compare_maps(r.maps, reference.maps);
    INFO("all stages, x" << factor << ": largest |difference| after fine-tune "
                            << group_differences(*r.after_finetune, *reference.after_finetune) << "; refined "
                            << group_differences(r.maps, reference.maps));
    // Measured MSE after fine-tune (1e-4): a_d 3.9e-4, a'_s 4.1e-4, n 2.0e-3, sigma 5.1e-4,
    // alpha 4.3e-3, F0 3.1e-4 (1e4: a little less); without normalisation a_d 2.1e-3, n 5.6e-3.
    for (const double v : {fine.diffuse, fine.specular, fine.lobes, fine.fresnel}) CHECK(v < 1.5e-3);
    CHECK(fine.normal < 6e-3);
    CHECK(fine.rotation < 1.5e-2);
    // After refine (1e-4): a_d 1.1e-3, a'_s 5.6e-4, n 0.011, sigma 1.2e-3, alpha 0.014, F0 3.7e-4.
    for (const double v : {refined.diffuse, refined.specular, refined.lobes, refined.fresnel}) CHECK(v < 4e-3);
    CHECK(refined.normal < 0.03);
    CHECK(refined.rotation < 0.05);
  }
}

// Float against double: the whole pipeline (estimate, encode, fine-tune, refine on tiny networks)
// with the loss kernels in float and in double (render_options::double_precision) on the same
// capture. The two runs start identically and differ only by rounding in the image loss and its
// gradient, which the optimisers then amplify as in the exposure test above; so the maps are
// compared by mean squared difference, and each run's error against the truth must agree.
TEST_CASE("stability: the pipeline in float agrees with the pipeline with double-precision loss kernels") {
  const procedural_scene s(27, 64, 8);
  capture_options o = measured_capture_options();
  o.estimate.window = 64;
  o.estimate.stride = 64;
  o.finetune.steps = 10;
  o.refine.steps = 60;
  const capture_result single = run_tiny(s.cap, s.photos, o);
  o.render.double_precision = true;
  const capture_result twice = run_tiny(s.cap, s.photos, o);
  REQUIRE(invalid_values(single.maps) == 0);
  REQUIRE(invalid_values(twice.maps) == 0);
  // Same loss at every stage within 1 %.
  REQUIRE(single.stages.size() == twice.stages.size());
  for (std::size_t i = 0; i < single.stages.size(); ++i) {
    CAPTURE(single.stages[i].name);
    CHECK(single.stages[i].loss == doctest::Approx(twice.stages[i].loss).epsilon(0.01));
  }
  const parameter_errors between = compare_maps(single.maps, twice.maps);
  const parameter_errors e_single = compare_maps(single.maps, s.truth), e_double = compare_maps(twice.maps, s.truth);
  INFO("float vs double MSE: a_d " << between.diffuse << ", a'_s " << between.specular << ", n " << between.normal << ", sigma "
                                   << between.lobes << ", alpha " << between.rotation << ", F0 " << between.fresnel);
  INFO("against the truth, float / double: a_d " << e_single.diffuse << " / " << e_double.diffuse << ", n " << e_single.normal << " / "
                                                 << e_double.normal << ", sigma " << e_single.lobes << " / " << e_double.lobes);
  // Measured MSE between the runs: a_d 5.2e-4, a'_s 2.0e-4, n 4.9e-3, sigma 2.7e-4, alpha 6.6e-3,
  // F0 8.6e-5 (untrained tiny networks, whose own error against the truth is ~0.1: 200x larger).
  for (const double v : {between.diffuse, between.specular, between.lobes, between.fresnel}) CHECK(v < 2e-3);
  CHECK(between.normal < 1.5e-2);
  CHECK(between.rotation < 3e-2);
  auto close = [](double a, double b) { return std::abs(a - b) <= 0.2 * std::max(a, b) + 1e-4; };
  CHECK(close(e_single.diffuse, e_double.diffuse));
  CHECK(close(e_single.specular, e_double.specular));
  CHECK(close(e_single.normal, e_double.normal));
  CHECK(close(e_single.lobes, e_double.lobes));
  CHECK(close(e_single.fresnel, e_double.fresnel));
}
