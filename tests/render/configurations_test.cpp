// Tests for render/configurations.hpp: the geometric promises of each sampler of the paper's
// section 3.6 (grazing Fresnel views, centred mirror highlights, the 90 degree pair), bounds,
// determinism and the composition of the input sets.
#include <doctest/doctest.h>

#include <array>
#include <cmath>
#include <numbers>
#include <stdexcept>

#include "anisocap/render/configurations.hpp"

using namespace anisocap;

namespace {

using vec3d = std::array<double, 3>;

vec3d to_double(const vec3f& v) { return {v[0], v[1], v[2]}; }
vec3d sub(const vec3d& a, const vec3d& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double norm(const vec3d& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }
vec3d unit(const vec3d& a) {
  const double l = norm(a);
  return {a[0] / l, a[1] / l, a[2] / l};
}

/// The plane point whose half vector is vertical (every camera-light pair has one, by the
/// reflection principle): the height-weighted point between their footprints.
vec3d mirror_point(const capture_image& c) {
  const double zc = c.camera[2], zl = c.light[2];
  return {(c.camera[0] * zl + c.light[0] * zc) / (zc + zl), (c.camera[1] * zl + c.light[1] * zc) / (zc + zl), 0.0};
}

/// Horizontal part of the normalised half vector at point p (zero when the highlight is centred on p).
double half_vector_tilt(const capture_image& c, const vec3d& p) {
  const vec3d v = unit(sub(to_double(c.camera), p)), l = unit(sub(to_double(c.light), p));
  const vec3d h = unit({v[0] + l[0], v[1] + l[1], v[2] + l[2]});
  return std::hypot(h[0], h[1]);
}

/// True when the light aims at the mirror point: its intensity is pi * |light - p|^2 for that p.
/// Mirror and anisotropic samplers aim at their mirror point; independent ones at a point of
/// their own below the light, which is not the mirror point except by chance.
bool aims_at_mirror_point(const capture_image& c) {
  const vec3d d = sub(to_double(c.light), mirror_point(c));
  return std::abs(c.intensity[0] / std::numbers::pi / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - 1.0) < 1e-4;
}

bool same(const capture_image& a, const capture_image& b) {
  return a.camera == b.camera && a.light == b.light && a.intensity == b.intensity && a.file == b.file;
}

bool same(const capture& a, const capture& b) {
  if (a.images.size() != b.images.size()) return false;
  for (std::size_t i = 0; i < a.images.size(); ++i)
    if (!same(a.images[i], b.images[i])) return false;
  return true;
}

const int sizes[][2] = {{256, 256}, {1024, 350}, {393, 1024}, {37, 53}};

}  // namespace

TEST_CASE("anisotropic pairs centre the highlight on a material point and rotate by 90 degrees") {
  for (auto [w, h] : sizes) {
    const auto half = material_half_extent(w, h);
    random_generator rng(1);
    for (int k = 0; k < 300; ++k) {
      const auto [a, b] = anisotropic_configuration_pair(rng, w, h);
      const vec3d p = mirror_point(a);
      REQUIRE(std::abs(p[0]) <= half[0] + 1e-6);
      REQUIRE(std::abs(p[1]) <= half[1] + 1e-6);
      CHECK(aims_at_mirror_point(a));  // the light aims at the highlight's point
      CHECK(aims_at_mirror_point(b));
      CHECK(half_vector_tilt(a, p) < 1e-5);
      CHECK(half_vector_tilt(b, p) < 1e-5);  // the rotation is about the vertical through p
      const vec3d pb = mirror_point(b);
      CHECK(std::hypot(pb[0] - p[0], pb[1] - p[1]) < 1e-5);
      // Camera azimuths about p differ by +90 degrees, elevations and distances agree.
      const vec3d va = sub(to_double(a.camera), p), vb = sub(to_double(b.camera), p);
      const double cross = va[0] * vb[1] - va[1] * vb[0], dot = va[0] * vb[0] + va[1] * vb[1];
      CHECK(std::abs(std::atan2(cross, dot) - std::numbers::pi / 2) < 1e-4);
      CHECK(std::abs(norm(va) - norm(vb)) < 1e-5);
      CHECK(std::abs(va[2] - vb[2]) < 1e-6);
      CHECK(std::abs(norm(sub(to_double(a.light), p)) - norm(sub(to_double(b.light), p))) < 1e-5);
      for (const auto* c : {&a, &b}) {
        const double dv = norm(sub(to_double(c->camera), p)), dl = norm(sub(to_double(c->light), p));
        CHECK(dv >= configuration_min_distance - 1e-5);
        CHECK(dv <= configuration_max_distance + 1e-5);
        CHECK(dl >= configuration_min_distance - 1e-5);
        CHECK(dl <= configuration_max_distance + 1e-5);
        CHECK(c->camera[2] > 0.25f);  // zenith <= 75 degrees at distance >= 1
        CHECK(c->light[2] > 0.25f);
        // Intensity pi d^2 gives irradiance pi at normal incidence at p.
        CHECK(c->intensity[0] / (dl * dl) == doctest::Approx(std::numbers::pi).epsilon(1e-5));
        CHECK(c->intensity[0] == c->intensity[1]);
        CHECK(c->intensity[1] == c->intensity[2]);
      }
    }
  }
}

TEST_CASE("mirror configurations centre the highlight on a material point") {
  for (auto [w, h] : sizes) {
    const auto half = material_half_extent(w, h);
    random_generator rng(2);
    for (int k = 0; k < 300; ++k) {
      const capture_image c = mirror_configuration(rng, w, h);
      const vec3d p = mirror_point(c);
      REQUIRE(std::abs(p[0]) <= half[0] + 1e-6);
      REQUIRE(std::abs(p[1]) <= half[1] + 1e-6);
      CHECK(half_vector_tilt(c, p) < 1e-5);
      CHECK(aims_at_mirror_point(c));
      CHECK(c.camera[2] > 0.25f);
      CHECK(c.light[2] > 0.25f);
    }
  }
}

TEST_CASE("cosine-distributed directions: mean cosine 2/3 of the truncated law") {
  // For directions cosine-distributed up to zenith m, E[cos] = (2/3)(1 - cos^3 m) / sin^2 m.
  random_generator rng(3);
  const int n = 20000;
  double sum = 0;
  for (int k = 0; k < n; ++k) {
    const capture_image c = mirror_configuration(rng, 256, 256);
    const vec3d p = mirror_point(c);
    sum += unit(sub(to_double(c.camera), p))[2];
  }
  const double m = configuration_max_zenith;
  const double expected = 2.0 / 3.0 * (1 - std::pow(std::cos(m), 3)) / std::pow(std::sin(m), 2);
  CHECK(sum / n == doctest::Approx(expected).epsilon(0.01));
}

TEST_CASE("Fresnel configurations are grazing, beside the material, light on the opposite side") {
  for (auto [w, h] : sizes) {
    const auto half = material_half_extent(w, h);
    random_generator rng(4);
    int sides[4] = {};
    for (int k = 0; k < 400; ++k) {
      const capture_image c = fresnel_configuration(rng, w, h);
      CHECK(c.camera[2] >= fresnel_min_height - 1e-6);
      CHECK(c.camera[2] <= fresnel_max_height + 1e-6);
      // Beside the material: outside it along exactly one axis, near the other axis's centre line.
      const bool beyond_x = std::abs(c.camera[0]) >= half[0] - 1e-6;
      const bool beyond_y = std::abs(c.camera[1]) >= half[1] - 1e-6;
      REQUIRE(beyond_x != beyond_y);
      const int axis = beyond_x ? 0 : 1;
      CHECK(std::abs(c.camera[1 - axis]) <= fresnel_axis_jitter * half[1 - axis] + 1e-6);
      ++sides[2 * axis + (c.camera[axis] > 0)];
      // The light is on the opposite side, mirroring the camera about a point near the centre.
      CHECK(c.light[axis] * c.camera[axis] < 0);
      const vec3d p = mirror_point(c);
      CHECK(std::abs(p[0]) <= fresnel_axis_jitter * half[0] + 1e-5);
      CHECK(std::abs(p[1]) <= fresnel_axis_jitter * half[1] + 1e-5);
      CHECK(half_vector_tilt(c, p) < 1e-5);
      // Grazing at that point: the camera's elevation is at most 45 degrees (and it is low).
      const vec3d v = unit(sub(to_double(c.camera), p));
      CHECK(std::asin(v[2]) <= fresnel_max_elevation + 1e-5);
      // Unless it had to move out for a narrow material, at most 0.5n beyond the edge.
      if (std::abs(c.camera[axis]) > half[axis] + fresnel_max_distance + 1e-5) {
        CHECK(std::asin(v[2]) == doctest::Approx(fresnel_max_elevation).epsilon(1e-4));
      }
    }
    for (int s : sides) CHECK(s > 50);  // all four sides are used
  }
  // On a square material the view is grazing in the paper's sense: elevation mostly under 30 deg.
  random_generator rng(5);
  int low = 0;
  for (int k = 0; k < 1000; ++k) {
    const capture_image c = fresnel_configuration(rng, 512, 512);
    const vec3d v = unit(sub(to_double(c.camera), mirror_point(c)));
    low += std::asin(v[2]) < 30.0 * std::numbers::pi / 180.0;
  }
  CHECK(low > 700);
}

TEST_CASE("independent configurations stay above their points within the distance bounds") {
  for (auto [w, h] : sizes) {
    const auto half = material_half_extent(w, h);
    random_generator rng(6);
    int mirrors = 0;
    for (int k = 0; k < 300; ++k) {
      const capture_image c = independent_configuration(rng, w, h);
      for (const auto& q : {c.camera, c.light}) {
        CHECK(q[2] >= configuration_min_distance * std::cos(configuration_max_zenith) - 1e-5);
        CHECK(q[2] <= configuration_max_distance + 1e-5);
        // Horizontal offset from the material is at most the distance times sin(max zenith).
        CHECK(std::abs(q[0]) <= half[0] + configuration_max_distance * std::sin(configuration_max_zenith) + 1e-5);
        CHECK(std::abs(q[1]) <= half[1] + configuration_max_distance * std::sin(configuration_max_zenith) + 1e-5);
      }
      // Not a mirror configuration in general: the light aims at a point of its own.
      mirrors += aims_at_mirror_point(c);
      const double d = std::sqrt(c.intensity[0] / std::numbers::pi);
      CHECK(d >= configuration_min_distance - 1e-5);
      CHECK(d <= configuration_max_distance + 1e-5);
    }
    CHECK(mirrors == 0);
  }
}

TEST_CASE("the same seed gives the same sets, a different seed different ones") {
  CHECK(same(set_alpha(12, 7, 553, 822), set_alpha(12, 7, 553, 822)));
  CHECK(same(set_beta(12, 7, 553, 822), set_beta(12, 7, 553, 822)));
  CHECK(same(training_set(7, 256, 256), training_set(7, 256, 256)));
  CHECK(same(render_loss_set(7, 256, 256), render_loss_set(7, 256, 256)));
  CHECK_FALSE(same(set_alpha(12, 7, 553, 822), set_alpha(12, 8, 553, 822)));
  CHECK_FALSE(same(set_beta(12, 7, 553, 822), set_beta(12, 8, 553, 822)));
}

TEST_CASE("set composition: counts, order and file names") {
  auto is_mirror = [](const capture_image& c) { return aims_at_mirror_point(c); };
  auto is_fresnel = [](const capture_image& c) { return c.camera[2] <= fresnel_max_height + 1e-6 && c.light[2] <= fresnel_max_height + 1e-6; };
  for (int n : {4, 5, 8, 10, 11, 12}) {
    const capture a = set_alpha(n, 100 + n, 300, 200);
    REQUIRE(int(a.images.size()) == n);
    CHECK(is_fresnel(a.images[0]));
    CHECK(is_fresnel(a.images[1]));
    const int pairs = (n - 4) / 2;
    for (int i = 0; i < pairs; ++i) {
      const auto& first = a.images[2 + 2 * i];
      const auto& second = a.images[3 + 2 * i];
      CHECK(is_mirror(first));
      CHECK(is_mirror(second));
      CHECK_FALSE(is_fresnel(first));
      const vec3d p = mirror_point(first), q = mirror_point(second);
      CHECK(std::hypot(p[0] - q[0], p[1] - q[1]) < 1e-5);
    }
    for (int i = 2 + 2 * pairs; i < n; ++i) CHECK_FALSE(is_mirror(a.images[i]));  // independent
    CHECK(n - 2 - 2 * pairs == 2 + (n - 4) % 2);
    for (int i = 0; i < n; ++i) CHECK(a.images[i].file == input_file_name(i));

    const capture b = set_beta(n, 200 + n, 300, 200);
    REQUIRE(int(b.images.size()) == n);
    int mirrors = 0;
    for (const auto& c : b.images) {
      mirrors += is_mirror(c);
      CHECK_FALSE(is_fresnel(c));
    }
    CHECK(mirrors == n / 2);
  }
  CHECK(input_file_name(0) == "input_00.exr");
  CHECK(input_file_name(7) == "input_07.exr");
  CHECK(input_file_name(123) == "input_123.exr");

  const capture t = training_set(9, 256, 256);
  REQUIRE(t.images.size() == 5);
  CHECK(is_fresnel(t.images[0]));
  CHECK(is_mirror(t.images[1]));
  CHECK(is_mirror(t.images[2]));
  CHECK_FALSE(is_mirror(t.images[3]));
  CHECK_FALSE(is_mirror(t.images[4]));

  const capture r = render_loss_set(9, 256, 256);
  REQUIRE(r.images.size() == 4);
  CHECK(is_mirror(r.images[0]));
  CHECK(is_mirror(r.images[1]));
  CHECK(is_fresnel(r.images[2]));
  CHECK_FALSE(is_mirror(r.images[3]));

  CHECK_THROWS_AS(set_alpha(3, 1, 256, 256), std::invalid_argument);
  CHECK_THROWS_AS(set_beta(0, 1, 256, 256), std::invalid_argument);
  CHECK_THROWS_AS(set_alpha(8, 1, 0, 256), std::invalid_argument);
}

TEST_CASE("pinned configurations: the same seed gives the same capture on every build") {
  // Produced by this implementation and found bit-identical with GCC 12 at -O0 and -O3 for
  // -march=x86-64, x86-64-v3 and native (AVX-512) and with clang 14: a change here means a seed no
  // longer names the capture it named before (acceptable only as a deliberate, noted change).
  const capture c = set_alpha(12, 1, 553, 822);
  CHECK(c.images[0].camera == vec3f{-0.0149000222f, -0.675475299f, 0.101259798f});
  CHECK(c.images[0].light == vec3f{0.0494837798f, 0.543777704f, 0.101259798f});
  CHECK(c.images[0].intensity[0] == 1.20302367f);
  CHECK(c.images[2].camera == vec3f{-1.03645051f, 0.175684795f, 3.27123523f});
  CHECK(c.images[2].light == vec3f{0.825888634f, 0.777081788f, 2.91177583f});
  CHECK(c.images[11].camera == vec3f{2.34889674f, -0.742452741f, 0.867995262f});
  CHECK(c.images[11].intensity[2] == 31.4511337f);
}

TEST_CASE("set alpha with more, lower Fresnel configurations") {
  const fresnel_options paper;
  CHECK(paper.count == 2);
  CHECK(paper.min_height == fresnel_min_height);
  CHECK(paper.max_height == fresnel_max_height);
  // Pinned: the default set is the paper's set alpha, image for image (values of the sampler
  // before fresnel_options existed).
  const capture a = set_alpha(12, 7, 553, 822, paper);
  struct pinned { int image; std::array<float, 3> camera, light; };
  const pinned values[] = {
      {0, {0.0422995649f, 0.930561304f, 0.15175797f}, {-0.115625985f, -0.783191741f, 0.15175797f}},
      {1, {-0.0305837449f, 0.552632391f, 0.37179336f}, {0.155261308f, -0.554359436f, 0.37179336f}},
      {5, {-0.148891851f, -0.220128059f, 3.72949338f}, {-0.351753205f, -0.181712493f, 3.22108507f}},
      {11, {0.137737215f, 1.39569008f, 1.09274554f}, {-1.64260864f, 0.961853921f, 1.02298641f}},
  };
  for (const pinned& p : values)
    for (int k = 0; k < 3; ++k) {
      CHECK(a.images[std::size_t(p.image)].camera[k] == doctest::Approx(p.camera[k]).epsilon(1e-6));
      CHECK(a.images[std::size_t(p.image)].light[k] == doctest::Approx(p.light[k]).epsilon(1e-6));
    }
  CHECK(same(a, set_alpha(12, 7, 553, 822)));
  for (int count : {0, 4, 6}) {
    const fresnel_options low{count, 0.1, 0.15};
    const capture c = set_alpha(12, 7, 553, 822, low);
    REQUIRE(c.images.size() == 12);
    int fresnel = 0;
    for (int i = 0; i < count; ++i) {
      const auto& im = c.images[std::size_t(i)];
      fresnel += im.camera[2] >= 0.1f - 1e-6f && im.camera[2] <= 0.15f + 1e-6f && im.light[2] == im.camera[2];
    }
    CHECK(fresnel == count);
    // The rest: anisotropic pairs then independent configurations, all above the Fresnel band.
    for (int i = count; i < 12; ++i) CHECK(c.images[std::size_t(i)].camera[2] > 0.2f);
    CHECK(c.images.back().file == "input_11.exr");
  }
  CHECK_THROWS_AS(set_alpha(5, 1, 64, 64, fresnel_options{4, 0.1, 0.2}), std::invalid_argument);
  CHECK_THROWS_AS(set_alpha(8, 1, 64, 64, fresnel_options{-1, 0.1, 0.2}), std::invalid_argument);
  CHECK_THROWS_AS(set_alpha(8, 1, 64, 64, fresnel_options{2, 0.3, 0.2}), std::invalid_argument);
}
