// pipeline/uncertainty.hpp: the information's and the residual gradient's derivatives against
// finite differences, the remaining Gauss-Newton step finding a texel moved off the photographs'
// fit, the posterior falling back to the prior where the photographs say nothing (F0 under a
// flash), more photographs making parameters surer, and the files' layout.
#include <doctest/doctest.h>

#include <cmath>

#include "../data/test_folder.hpp"
#include "../render/render_reference.hpp"
#include "anisocap/pipeline/uncertainty.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

/// The log radiance derivative of texel (x, y) by central differences, in double.
std::array<double, parameter_count> finite_difference(const material_maps& maps, const capture_image& im, int x, int y, int c) {
  std::array<double, parameter_count> g{};
  for (int i = 0; i < parameter_count; ++i) {
    const double h = 1e-6;
    ward_parameters<double> plus = texel_ward_parameters<double>(maps, x, y), minus = plus;
    auto entry = [i](ward_parameters<double>& p) -> double& {
      if (i <= diffuse_b) return p.diffuse[std::size_t(i)];
      if (i <= specular_b) return p.specular[std::size_t(i - specular_r)];
      if (i == lobe_x) return p.sx;
      if (i == lobe_y) return p.sy;
      if (i == fresnel_f0) return p.f0;
      if (i == normal_x) return p.nx;
      if (i == normal_y) return p.ny;
      return p.alpha;
    };
    entry(plus) += h;
    entry(minus) -= h;
    const double a = texel_radiance<double>(plus, im, x, y, maps.width(), maps.height())[std::size_t(c)];
    const double b = texel_radiance<double>(minus, im, x, y, maps.width(), maps.height())[std::size_t(c)];
    g[std::size_t(i)] = (std::log(a + double(loss_epsilon)) - std::log(b + double(loss_epsilon))) / (2 * h);
  }
  return g;
}

/// `count` flash photographs: the light beside the lens.
capture flash_capture(int count, int size, std::uint64_t seed) {
  random_generator rng(seed);
  return flash_set(count, rng, size, size, {0.05f, 0.0f, 0.0f});
}

}  // namespace

TEST_CASE("texel_information is the Gauss-Newton sum of the log radiance's derivatives, checked by finite differences") {
  const material_maps maps = random_maps(5, 4, 11);
  const capture cap = random_capture(3, 12);
  const std::vector<image> photos = render(maps, cap);
  const loss_targets targets = make_loss_targets(photos);
  for (const auto& [px, py] : {std::pair{0, 0}, std::pair{3, 2}, std::pair{4, 3}}) {
    const int x = px, y = py;  // INFO captures in a lambda, which Clang 14 cannot do with a binding
    Eigen::Matrix<double, parameter_count, parameter_count> expected = Eigen::Matrix<double, parameter_count, parameter_count>::Zero();
    for (std::size_t k = 0; k < cap.images.size(); ++k)
      for (int c = 0; c < 3; ++c) {
        const auto g = finite_difference(maps, cap.images[k], x, y, c);
        for (int i = 0; i < parameter_count; ++i)
          for (int j = 0; j < parameter_count; ++j) expected(i, j) += g[std::size_t(i)] * g[std::size_t(j)];
      }
    const auto h = texel_information(maps, cap, targets, x, y);
    for (int i = 0; i < parameter_count; ++i)
      for (int j = 0; j < parameter_count; ++j) {
        INFO("texel (" << x << ", " << y << "), entry (" << i << ", " << j << ")");
        CHECK(h(i, j) == doctest::Approx(expected(i, j)).epsilon(1e-4).scale(1e-3 * (std::abs(expected(i, i)) + 1)));
      }
  }
  // A masked pixel is no measurement; a render under its image's floor neither.
  std::vector<image> masks(cap.images.size(), image(5, 4, 1));
  for (image& m : masks) std::fill(m.plane(0), m.plane(0) + m.pixel_count(), 1.0f);
  masks[0].at(0, 3, 2) = masks[1].at(0, 3, 2) = masks[2].at(0, 3, 2) = 0.0f;
  CHECK(texel_information(maps, cap, make_loss_targets(photos, masks), 3, 2).isZero());
  CHECK(texel_information(maps, cap, make_loss_targets(photos, {}, std::vector<float>(3, 1e9f)), 0, 0).isZero());
}

TEST_CASE("texel_gauss_newton: the gradient of half the squared log residuals, checked by finite differences") {
  const material_maps truth = random_maps(5, 4, 21);
  const capture cap = random_capture(4, 22);
  std::vector<image> masks(cap.images.size(), image(5, 4, 1));
  for (std::size_t k = 0; k < masks.size(); ++k) std::fill(masks[k].plane(0), masks[k].plane(0) + masks[k].pixel_count(), 0.25f * float(k + 1));
  const loss_targets targets = make_loss_targets(render(truth, cap), masks);
  const material_maps maps = random_maps(5, 4, 23);  // other parameters: the residuals are not 0
  // Half the weighted squared log residuals of texel (x, y), in double.
  auto half_squares = [&](const ward_parameters<double>& p, int x, int y) {
    double sum = 0;
    for (std::size_t k = 0; k < cap.images.size(); ++k) {
      const auto r = texel_radiance<double>(p, cap.images[k], x, y, maps.width(), maps.height());
      for (int c = 0; c < 3; ++c) {
        const double d = std::log(r[std::size_t(c)] + double(loss_epsilon)) - std::log(double(targets.images[k].at(c, x, y)));
        sum += 0.5 * double(masks[k].at(0, x, y)) * d * d;
      }
    }
    return sum;
  };
  for (const auto& [px, py] : {std::pair{1, 1}, std::pair{4, 3}}) {
    const int x = px, y = py;  // INFO captures in a lambda, which Clang 14 cannot do with a binding
    const texel_normal_equations e = texel_gauss_newton(maps, cap, targets, x, y);
    CHECK(e.information.isApprox(texel_information(maps, cap, targets, x, y)));
    CHECK(e.gradient.norm() > 1e-3);
    for (int i = 0; i < parameter_count; ++i) {
      material_maps plus = maps, minus = maps;
      const double h = 1e-6;
      plus.at(i, x, y) = float(maps.at(i, x, y) + h);
      minus.at(i, x, y) = float(maps.at(i, x, y) - h);
      const double step = double(plus.at(i, x, y)) - double(minus.at(i, x, y));  // what float kept of 2h
      const double expected = (half_squares(texel_ward_parameters<double>(plus, x, y), x, y) -
                                half_squares(texel_ward_parameters<double>(minus, x, y), x, y)) / step;
      INFO("texel (" << x << ", " << y << "), parameter " << std::string(parameter_name(i)));
      CHECK(e.gradient[i] == doctest::Approx(expected).epsilon(2e-3).scale(1e-2 * (e.gradient.norm() + 1)));
    }
  }
}

TEST_CASE("texel_uncertainty: the remaining Gauss-Newton step finds a texel the capture left off the photographs' fit") {
  const int n = 8;
  const material_maps truth = random_maps(n, n, 31);
  const capture cap = set_alpha(12, 32, n, n);
  const loss_targets targets = make_loss_targets(render(truth, cap));
  material_maps off = truth;
  const std::array<std::pair<int, float>, 3> moved = {std::pair{diffuse_g, 0.004f}, std::pair{normal_x, -0.003f}, std::pair{specular_r, 0.003f}};
  for (auto [k, d] : moved) off.at(k, 5, 2) += d;
  uncertainty_options o;
  o.calibrated = false;
  o.noise = 0.01;
  const uncertainty_result u = texel_uncertainty(off, cap, targets, o);
  for (int k = 0; k < parameter_count; ++k)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        if (x == 5 && y == 2) continue;
        // A texel at the photographs' fit: nothing left but float rounding.
        INFO(std::string(parameter_name(k)) << " at (" << x << ", " << y << ")");
        REQUIRE(std::abs(u.step.at(k, x, y)) < 1e-2 * u.sd.at(k, x, y) + 1e-5);
      }
  // The moved texel: the step points back by what was moved (the prior damps it a little).
  for (const auto& m : moved) {
    INFO(std::string(parameter_name(m.first)));
    CHECK(u.step.at(m.first, 5, 2) == doctest::Approx(-m.second).epsilon(0.1).scale(0));
  }
}

TEST_CASE("texel_uncertainty: the prior where the photographs say nothing, surer with more photographs") {
  const int n = 16;
  material_maps truth = random_maps(n, n, 5);
  for (std::size_t i = 0; i < truth.texel_count(); ++i) truth.plane(fresnel_f0)[i] = 0.05f;
  const capture flash = flash_capture(8, n, 3);
  const loss_targets flash_targets = make_loss_targets(render(truth, flash));
  uncertainty_options o;
  o.noise = 0.02;
  o.calibrated = false;  // the Laplace approximation's own deviations
  const uncertainty_result u = texel_uncertainty(truth, flash, flash_targets, o);
  CHECK(u.noise == 0.02);
  {  // calibrated: each deviation through the table, the same texels determined
    uncertainty_options c = o;
    c.calibrated = true;
    const uncertainty_result w = texel_uncertainty(truth, flash, flash_targets, c);
    for (int k = 0; k < parameter_count; ++k) {
      CHECK(w.determined_share[std::size_t(k)] == u.determined_share[std::size_t(k)]);
      for (std::size_t i = 0; i < truth.texel_count(); ++i)
        REQUIRE(w.sd.plane(k)[i] == doctest::Approx(uncertainty_calibration.apply(k, u.sd.plane(k)[i], truth.plane(k)[i])).epsilon(1e-5));
    }
    CHECK(w.calibration == photo_encoding::lossless);
    // 8-bit and JPEG photographs: the same Laplace deviations through their encoding's table; for
    // JPEGs wider on average for the diffuse albedo and the normal, and wider still where the
    // colour was subsampled. The lossiest photograph decides.
    const uncertainty_result* before = &w;
    std::vector<uncertainty_result> kept;
    kept.reserve(3);
    for (const photo_encoding e : {photo_encoding::eight_bit, photo_encoding::jpeg, photo_encoding::jpeg_subsampled}) {
      CAPTURE(photo_encoding_name(e));
      capture jpeg = flash;
      jpeg.images[3].encoding = e;
      jpeg.images[5].encoding = photo_encoding::eight_bit;
      CHECK(lossiest_encoding(jpeg) == e);
      const uncertainty_calibration_table& table = calibration_for(e);
      CHECK(&table != &calibration_for(photo_encoding::lossless));
      for (int k = 0; k < parameter_count; ++k) {  // a table widens or narrows, never removes, a deviation
        const auto i = std::size_t(k);
        CHECK(table.scale[i] > 0);
        CHECK(table.floor[i] >= 0);
        CHECK(table.relative[i] >= 0);
      }
      // Stored highlights clip and round alike in every photograph: wider deviations of a'_s than
      // for linear photographs.
      for (const int k : {specular_r, specular_g, specular_b}) CHECK(table.scale[std::size_t(k)] > uncertainty_calibration.scale[std::size_t(k)]);
      const uncertainty_result& j = kept.emplace_back(texel_uncertainty(truth, jpeg, flash_targets, c));
      CHECK(j.calibration == e);
      for (int k = 0; k < parameter_count; ++k) {
        CHECK(j.determined_share[std::size_t(k)] == u.determined_share[std::size_t(k)]);
        for (std::size_t i = 0; i < truth.texel_count(); ++i)
          REQUIRE(j.sd.plane(k)[i] == doctest::Approx(table.apply(k, u.sd.plane(k)[i], truth.plane(k)[i])).epsilon(1e-5));
      }
      auto mean = [](const material_maps& m, int k) {
        double sum = 0;
        for (std::size_t i = 0; i < m.texel_count(); ++i) sum += m.plane(k)[i];
        return sum / double(m.texel_count());
      };
      if (e != photo_encoding::eight_bit) {
        for (const int k : {diffuse_r, diffuse_g, diffuse_b, normal_x, normal_y}) CHECK(mean(j.sd, k) > mean(before->sd, k));
        before = &j;
      }
      CHECK_FALSE(texel_uncertainty(truth, jpeg, flash_targets, o).calibration.has_value());  // not calibrated: no table
    }
  }
  // A flash sees F / F0 = 1: F0 keeps the prior's spread on every texel, the diffuse albedo is measured.
  for (std::size_t i = 0; i < truth.texel_count(); ++i) {
    REQUIRE(u.sd.plane(fresnel_f0)[i] == doctest::Approx(uncertainty_prior_sd[fresnel_f0]).epsilon(0.02));
    REQUIRE(u.sd.plane(diffuse_g)[i] < 0.2 * uncertainty_prior_sd[diffuse_g]);
  }
  CHECK(u.determined_share[fresnel_f0] == 0.0);
  CHECK_FALSE(u.determined(fresnel_f0));
  CHECK(u.determined(diffuse_r));
  CHECK(u.determined_share[diffuse_r] == 1.0);

  // Grazing photographs with the light opposite measure F0; more photographs shrink every spread.
  capture more = flash;
  random_generator rng(9);
  for (int i = 0; i < 4; ++i) more.images.push_back(fresnel_configuration(rng, n, n));
  const uncertainty_result v = texel_uncertainty(truth, more, make_loss_targets(render(truth, more)), o);
  CHECK(v.determined_share[fresnel_f0] > 0.5);
  for (int k = 0; k < parameter_count; ++k)
    for (std::size_t i = 0; i < truth.texel_count(); ++i) REQUIRE(v.sd.plane(k)[i] <= u.sd.plane(k)[i] * (1 + 1e-4f));

  // The noise, when not given, is the residuals' RMS, at least min_noise: maps that render the
  // photographs exactly get min_noise.
  CHECK(texel_uncertainty(truth, flash, flash_targets).noise == uncertainty_options{}.min_noise);
  material_maps off = truth;
  for (std::size_t i = 0; i < off.texel_count(); ++i) off.plane(diffuse_r)[i] *= 1.5f;
  CHECK(texel_uncertainty(off, flash, flash_targets).noise == doctest::Approx(residual_rms(off, flash, flash_targets)));
  CHECK(residual_rms(off, flash, flash_targets) > 0.01);

  o.determined_ratio = 1.5;
  CHECK_THROWS_WITH_AS(texel_uncertainty(truth, flash, flash_targets, o), doctest::Contains("determined_ratio"), std::invalid_argument);
  CHECK_THROWS_AS(texel_uncertainty(random_maps(8, 8, 1), flash, flash_targets), std::invalid_argument);
}

TEST_CASE("write_uncertainty: the map set's files, each channel the standard deviation of the parameter there") {
  const int n = 8;
  const material_maps truth = random_maps(n, n, 2);
  const capture cap = random_capture(4, 6);
  const uncertainty_result u = texel_uncertainty(truth, cap, make_loss_targets(render(truth, cap)));
  test_folder t;
  {
    file_transaction files;
    write_uncertainty(u, t.path() / "uncertainty", files);
    files.commit();
  }
  const image lobes = read_exr(t.path() / "uncertainty/lobes.exr"), normal = read_exr(t.path() / "uncertainty/normal.exr");
  const image fresnel = read_exr(t.path() / "uncertainty/fresnel.exr"), rotation_sd = read_exr(t.path() / "uncertainty/rotation.exr");
  CHECK_FALSE(std::filesystem::exists(t.path() / "uncertainty/height.exr"));
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      REQUIRE(lobes.at(0, x, y) == u.sd.at(lobe_x, x, y));
      REQUIRE(lobes.at(1, x, y) == u.sd.at(lobe_y, x, y));
      REQUIRE(normal.at(1, x, y) == u.sd.at(normal_y, x, y));
      REQUIRE(normal.at(2, x, y) == 0.0f);
      REQUIRE(fresnel.at(2, x, y) == u.sd.at(fresnel_f0, x, y));
      REQUIRE(rotation_sd.at(0, x, y) == u.sd.at(rotation, x, y));
    }
}
