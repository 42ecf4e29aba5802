// pipeline/plan.hpp: after flash photographs, the most informative next photograph is one with the
// light away from the camera, which starts to determine F0; the search is greedy (a photo is not
// proposed twice) and every gain is the real drop of the posterior variance.
#include <doctest/doctest.h>

#include "../render/render_reference.hpp"
#include "anisocap/pipeline/plan.hpp"
#include "anisocap/pipeline/plan_io.hpp"
#include "anisocap/render/configurations.hpp"

using namespace anisocap;
using namespace anisocap::testing;

namespace {

capture flash_capture(int count, int size, std::uint64_t seed) {
  random_generator rng(seed);
  return flash_set(count, rng, size, size);
}

}  // namespace

TEST_CASE("plan_candidates: every distance, elevation and azimuth, flash and lamp, irradiance 1 at the centre") {
  plan_options o;
  const auto all = plan_candidates(o);
  // 2 distances x (4 elevations x 8 azimuths + 1 overhead) x 2 kinds
  CHECK(all.size() == 2 * (4 * 8 + 1) * 2);
  for (const plan_candidate& c : all) {
    const vec3f& l = c.config.light;
    const double r2 = double(l[0]) * l[0] + double(l[1]) * l[1] + double(l[2]) * l[2];
    CHECK(c.config.intensity[0] * (l[2] / std::sqrt(r2)) / (std::numbers::pi * r2) == doctest::Approx(1.0).epsilon(1e-5));
    if (c.flash) CHECK(c.config.light == c.config.camera);
    else CHECK(c.config.light[0] == doctest::Approx(-c.config.camera[0]).epsilon(1e-5).scale(1e-6));
  }
  o.flash = false;
  CHECK(plan_candidates(o).size() == all.size() / 2);
  o.lamp = false;
  CHECK_THROWS_AS(o.validate(), std::invalid_argument);
  o = {};
  o.photos = 5;
  CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("plan_options::photos"), std::invalid_argument);
}

TEST_CASE("plan_photographs: after flash photographs, a lamp photograph (F0 then determined somewhere); greedy and honest gains") {
  const int n = 16;
  material_maps truth = random_maps(n, n, 4);
  const capture cap = flash_capture(6, n, 2);
  const loss_targets targets = make_loss_targets(render(truth, cap));
  plan_options o;
  o.photos = 2;
  o.stride = 2;
  const plan_result plan = plan_photographs(truth, cap, targets, 0.02, o);
  REQUIRE(plan.photos.size() == 2);
  const planned_photo& first = plan.photos[0];
  CHECK_FALSE(first.candidate.flash);  // a flash cannot measure F0
  CHECK(first.determined_before[fresnel_f0] == 0.0);
  CHECK(first.determined_after[fresnel_f0] > 0.0);
  CHECK(plan.photos[1].determined_after[fresnel_f0] >= first.determined_after[fresnel_f0]);
  CHECK(first.reason.find(parameter_name(first.main_parameter)) != std::string::npos);
  CHECK(first.gain > plan.photos[1].gain);  // the second photograph adds less to what the first told
  CHECK(plan.photos[1].gain > 0);
  CHECK_FALSE((plan.photos[1].candidate.config.camera == first.candidate.config.camera &&
               plan.photos[1].candidate.flash == first.candidate.flash));

  // The gain is the drop of the total normalised variance over the sampled texels, recomputed here
  // with the proposed photograph's render added to the capture as an ordinary photograph.
  uncertainty_options uo;
  uo.noise = 0.02;
  uo.calibrated = false;  // the plan weighs the Laplace approximation's variances
  auto total = [&](const capture& c) {
    const uncertainty_result u = texel_uncertainty(truth, c, make_loss_targets(render(truth, c)), uo);
    double sum = 0;
    for (int y = 1; y < n; y += 2)
      for (int x = 1; x < n; x += 2)
        for (int k = 0; k < parameter_count; ++k) {
          const double r = u.sd.at(k, x, y) / uncertainty_prior_sd[std::size_t(k)];
          sum += r * r;
        }
    return sum;
  };
  capture with_first = cap;
  with_first.images.push_back(first.candidate.config);
  const double before = total(cap), after = total(with_first);
  CHECK((before - after) / before == doctest::Approx(first.gain).epsilon(1e-3));

  // Flash photographs alone cannot do it.
  o.lamp = false;
  const plan_result flash_only = plan_photographs(truth, cap, targets, 0.02, o);
  CHECK(flash_only.photos[0].candidate.flash);
  CHECK(flash_only.photos[0].determined_after[fresnel_f0] == 0.0);
  CHECK_THROWS_AS(plan_photographs(truth, cap, targets, 0.0, o), std::invalid_argument);
}

TEST_CASE("plan.json: plan_to_json's photographs read back exactly; a malformed plan is one error naming the file and the entry") {
  const int n = 16;
  const material_maps truth = random_maps(n, n, 4);
  const capture cap = flash_capture(6, n, 2);
  plan_options o;
  o.photos = 3;
  o.stride = 4;
  const plan_result plan = plan_photographs(truth, cap, make_loss_targets(render(truth, cap)), 0.02, o);
  REQUIRE(plan.photos.size() == 3);
  for (double sample_mm : {0.0, 120.0}) {
    const std::string text = plan_to_json(plan, "result", sample_mm);
    CHECK((text.find("camera_mm") != std::string::npos) == (sample_mm > 0));
    const std::vector<plan_candidate> back = parse_plan_photos(text, "plan.json");
    REQUIRE(back.size() == plan.photos.size());
    for (std::size_t i = 0; i < back.size(); ++i) {
      const plan_candidate& c = plan.photos[i].candidate;
      CHECK(back[i].flash == c.flash);
      CHECK(back[i].config.camera == c.config.camera);  // floats survive JSON exactly
      CHECK(back[i].config.light == c.config.light);
      CHECK(back[i].config.intensity == c.config.intensity);
      CHECK(back[i].elevation == c.elevation);
      CHECK(back[i].azimuth == c.azimuth);
    }
  }
  auto refused = [](const std::string& text, const std::string& message) {
    INFO(text);
    CHECK_THROWS_WITH_AS(parse_plan_photos(text, "my/plan.json"), doctest::Contains(message.c_str()), io_error);
    CHECK_THROWS_WITH_AS(parse_plan_photos(text, "my/plan.json"), doctest::Contains("my/plan.json"), io_error);
  };
  refused("{\"photos\": [", "malformed JSON");
  refused("[1, 2]", "expected an object");
  refused("{\"photos\": []}", "non-empty array");
  refused("{\"photos\": [{\"kind\": \"drone\", \"camera\": [0, 0, 2], \"light\": [0, 0, 2]}]}", "photos[0]: \"kind\"");
  refused("{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, 0, 2]}]}", "missing field \"light\"");
  refused("{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, 0, 2], \"light\": [1, 0, -1]}]}", "below the sample's plane");
  refused("{\"photos\": [{\"kind\": \"flash\", \"camera\": [0, 0, 2], \"light\": [1, 0, 1]}]}", "must be its \"camera\"");
  refused("{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, 0, 2], \"light\": [0, 1, 1], \"tilt\": 3}]}", "unknown field \"tilt\"");
  refused("{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, \"a\", 2], \"light\": [0, 1, 1]}]}", "must be a number");
  refused("{\"photos\": [{\"kind\": \"lamp\", \"camera\": [0, 0, 2], \"light\": [0, 1, 1], \"intensity\": [1, 0, 1]}]}",
          "\"intensity\" must be positive");
  CHECK_THROWS_WITH_AS(read_plan_photos("no/such/plan.json"), doctest::Contains("no/such/plan.json"), io_error);
}
