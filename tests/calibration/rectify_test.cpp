// Rectification: filtering, the footprint's margin and the texels' confidence, masks, axis
// conventions, photos.json errors, and the round trip rectify(photograph(material)) against the
// texture-space renderer.
#include <doctest/doctest.h>

#include <cmath>
#include <fstream>
#include <numbers>
#include <random>

#include "anisocap/calibration/photo_synthesis.hpp"
#include "anisocap/calibration/rectify.hpp"
#include "anisocap/data/photo_io.hpp"
#include "anisocap/data/procedural.hpp"
#include "anisocap/render/configurations.hpp"
#include "data/test_folder.hpp"

using namespace anisocap;

namespace {

/// A material whose parameters vary slowly (periods of 16 texels and more), so that a texel's
/// footprint in a photo renders as its centre does and the round trip measures rectification.
material_maps smooth_material(int w, int h) {
  material_maps m(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double a = 2 * std::numbers::pi * x / 32.0, b = 2 * std::numbers::pi * y / 24.0;
      m.at(diffuse_r, x, y) = float(0.4 + 0.2 * std::sin(a));
      m.at(diffuse_g, x, y) = float(0.3 + 0.1 * std::cos(b));
      m.at(diffuse_b, x, y) = float(0.2 + 0.1 * std::sin(a + b));
      for (int c = 0; c < 3; ++c) m.at(specular_r + c, x, y) = float(0.15 + 0.05 * std::cos(a - b));
      m.at(lobe_x, x, y) = float(0.25 + 0.05 * std::sin(b));
      m.at(lobe_y, x, y) = float(0.4 + 0.05 * std::cos(a));
      m.at(fresnel_f0, x, y) = 0.5f;
      m.at(normal_x, x, y) = float(0.1 * std::sin(a));
      m.at(normal_y, x, y) = float(0.1 * std::cos(b));
      m.at(rotation, x, y) = float(0.3 * std::sin(0.5 * a));
    }
  return m;
}

/// A frontal camera 300 mm above a 100 x 80 mm sample, image up along the sample's top edge.
struct frontal_view {
  pinhole_camera camera{1200, {319.5, 239.5}};
  planar_pose pose = look_at({0, 0, 300}, {0, 0, 0}, {0, 1, 0});
};

}  // namespace

TEST_CASE("area averaging: a checkerboard finer than a texel rectifies to its mean, without aliasing") {
  // One-pixel checkerboard; the 100 mm side spans 400 px, so a 50-texel texture has 8 x 8 pixels per texel.
  const frontal_view v;
  image photo(640, 480, 3);
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x)
      for (int c = 0; c < 3; ++c) photo.at(c, x, y) = float((x + y) % 2);
  const rectified_photo r = rectify_photo(photo, image(), v.camera, v.pose, 50, 40, 100);
  double worst = 0;
  for (int c = 0; c < 3; ++c)
    for (std::size_t i = 0; i < r.radiance.pixel_count(); ++i) worst = std::max(worst, std::abs(r.radiance.plane(c)[i] - 0.5));
  CHECK(worst < 0.02);
  CHECK(r.outside_fraction == 0);
}

TEST_CASE("footprint statistics: the median keeps a black texel black under sensor noise clipped at black, the mean does not; automatic takes each where it is right") {
  // A frontal photo of a uniform sample, 8 x 8 photo pixels per texel, with Gaussian noise of
  // standard deviation sigma clipped at 0 as a sensor reports it: the area average of such pixels
  // is biased up by about sigma / sqrt(2 pi) where the sample is black; their median is not.
  const frontal_view v;
  const double sigma = 0.01;
  std::mt19937 gen(11);
  std::normal_distribution<double> noise(0.0, sigma);
  auto photo_of = [&](double value) {
    image photo(640, 480, 3);
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < photo.pixel_count(); ++k) photo.plane(c)[k] = float(std::max(0.0, value + noise(gen)));
    return photo;
  };
  auto mean_texel = [&](const image& photo, footprint_statistic statistic) {
    resampling_options o;
    o.statistic = statistic;
    const rectified_photo r = rectify_photo(photo, image(), v.camera, v.pose, 50, 40, 100, o);
    double sum = 0;
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < r.radiance.pixel_count(); ++k) sum += r.radiance.plane(c)[k];
    return sum / double(3 * r.radiance.pixel_count());
  };
  const image black = photo_of(0.0), grey = photo_of(0.3);
  const double bias = sigma / std::sqrt(2 * std::numbers::pi);
  CHECK(mean_texel(black, footprint_statistic::mean) == doctest::Approx(bias).epsilon(0.05));
  CHECK(mean_texel(black, footprint_statistic::median) < 0.3 * bias);  // even counts average the two middle values
  // Well above the noise both are unbiased.
  CHECK(mean_texel(grey, footprint_statistic::mean) == doctest::Approx(0.3).epsilon(0.002));
  CHECK(mean_texel(grey, footprint_statistic::median) == doctest::Approx(0.3).epsilon(0.002));
  // automatic, the default: the median in the dark, the area average above dark_level.
  CHECK(mean_texel(black, footprint_statistic::automatic) == mean_texel(black, footprint_statistic::median));
  CHECK(mean_texel(grey, footprint_statistic::automatic) == mean_texel(grey, footprint_statistic::mean));
  CHECK(resampling_options{}.statistic == footprint_statistic::automatic);
  // Sparse bright pixels finer than a texel (every other pixel of every other row): the median
  // drops them, the area average and automatic keep their share.
  image sparse(640, 480, 3);
  for (int y = 0; y < 480; ++y)
    for (int x = 0; x < 640; ++x)
      for (int c = 0; c < 3; ++c) sparse.at(c, x, y) = float(x % 2 == 0 && y % 2 == 0);
  CHECK(mean_texel(sparse, footprint_statistic::median) == 0.0);
  CHECK(mean_texel(sparse, footprint_statistic::mean) == doctest::Approx(0.25).epsilon(0.05));
  CHECK(mean_texel(sparse, footprint_statistic::automatic) == mean_texel(sparse, footprint_statistic::mean));
  // Without noise, the median of a uniform footprint is its value exactly.
  image flat(640, 480, 3);
  for (int c = 0; c < 3; ++c) std::fill_n(flat.plane(c), flat.pixel_count(), 0.125f);
  resampling_options o;
  o.statistic = footprint_statistic::median;
  const rectified_photo r = rectify_photo(flat, image(), v.camera, v.pose, 50, 40, 100, o);
  for (int c = 0; c < 3; ++c)
    for (std::size_t k = 0; k < r.radiance.pixel_count(); ++k) REQUIRE(r.radiance.plane(c)[k] == 0.125f);
}

TEST_CASE("the footprint leaves out its margin: texels with sharp borders rectify to their own value") {
  // Each texel a patch of its own random albedo (nearest lookup), seen obliquely at 2-4 photo
  // pixels per texel: pixels on a texel's border record its neighbours as well.
  const int n = 32;
  material_maps maps(n, n);
  const float grey[parameter_count] = {0.3f, 0.3f, 0.3f, 0, 0, 0, 0.3f, 0.3f, 1, 0, 0, 0};
  maps.fill(grey);
  std::mt19937 gen(7);
  std::uniform_real_distribution<float> albedo(0.05f, 0.9f);
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x)
      for (int c = 0; c < 3; ++c) maps.at(diffuse_r + c, x, y) = albedo(gen);
  photo_setup setup;
  setup.pose = look_at({0, -150, 220}, {0, 0, 0}, {0, 0, 1});
  setup.camera = {330, {159.5, 119.5}};
  setup.light_mm = {40, -60, 250};
  setup.intensity = {6, 6, 6};
  const image photo = render_photograph(maps, 100, setup, 320, 240, 4, texture_lookup::nearest);
  capture direct;
  capture_image config;
  const Eigen::Vector3d centre = setup.pose.camera_centre() / 100;
  config.camera = {float(centre.x()), float(centre.y()), float(centre.z())};
  config.light = {0.4f, -0.6f, 2.5f};
  config.intensity = setup.intensity;
  direct.images.push_back(config);
  const image truth = render(maps, direct)[0];
  auto error = [&](const resampling_options& o) {
    const rectified_photo r = rectify_photo(photo, image(), setup.camera, setup.pose, n, n, 100, o);
    double difference = 0, total = 0;
    for (int c = 0; c < 3; ++c)
      for (std::size_t k = 0; k < truth.pixel_count(); ++k) {
        REQUIRE(r.mask.plane(0)[k] == 1);
        difference += std::abs(r.radiance.plane(c)[k] - truth.plane(c)[k]);
        total += truth.plane(c)[k];
      }
    return difference / total;
  };
  resampling_options whole;
  whole.margin_px = 0;
  const double with_margin = error({}), without = error(whole);
  MESSAGE("mean relative error: " << with_margin << " with the default margin, " << without << " over the whole texel");
  CHECK(with_margin < 0.6 * without);
  CHECK(with_margin < 0.06);
}

TEST_CASE("confidence: 1 where a texel spans enough photo pixels, (d / full)^2 where it spans fewer; the mask file carries it; the share under one pixel") {
  const int w = 40, h = 32;
  image photo(960, 480, 3);
  for (int c = 0; c < 3; ++c) std::fill_n(photo.plane(c), photo.pixel_count(), 0.25f);
  // Frontal: 400 px across 40 texels, 10 px per texel: full confidence everywhere.
  const frontal_view v;
  const rectified_photo frontal = rectify_photo(photo, image(), {1200, {479.5, 239.5}}, v.pose, w, h, 100);
  for (std::size_t k = 0; k < frontal.confidence.pixel_count(); ++k) REQUIRE(frontal.confidence.plane(0)[k] == 1.0f);
  REQUIRE(frontal.outside_fraction == 0);
  // Grazing, from beyond the bottom edge: the far (top) rows span a pixel or less along y.
  const pinhole_camera camera{800, {479.5, 239.5}};
  const planar_pose pose = look_at({0, -160, 25}, {0, 0, 0}, {0, 0, 1});
  const resampling_options o;
  const rectified_photo r = rectify_photo(photo, image(), camera, pose, w, h, 100, o);
  // The texel's extent in pixels along each axis, from the projections of its edges' midpoints.
  auto span_through = [&](const pinhole_camera& lens, int x, int y) {
    auto at = [&](double u, double v) { return project(lens, pose, texture_to_sample(u, v, w, h, 100)); };
    return std::min((at(x + 1.0, y + 0.5) - at(x, y + 0.5)).norm(), (at(x + 0.5, y + 1.0) - at(x + 0.5, y)).norm());
  };
  auto span = [&](int x, int y) { return span_through(camera, x, y); };
  REQUIRE(r.outside_fraction == 0);
  CHECK(span(20, 0) < 1.5);
  CHECK(span(20, h - 1) > o.full_confidence_px);
  for (int y = 0; y < h; ++y) {
    CAPTURE(y);
    const double d = span(20, y);
    const double expected = std::pow(std::min(1.0, d / o.full_confidence_px), 2);
    CHECK(r.confidence.at(0, 20, y) == doctest::Approx(expected).epsilon(1e-4));
    if (y > 0) CHECK(r.confidence.at(0, 20, y) >= r.confidence.at(0, 20, y - 1));  // nearer rows: more confident
  }
  CHECK(r.confidence.at(0, 20, 0) < 0.4);
  CHECK(r.confidence.at(0, 20, h - 1) == 1.0f);
  // The under-resolved share counts the texels that span less than a pixel: none from the front,
  // the far rows through a wider lens from the same place.
  CHECK(frontal.underresolved_fraction == 0);
  const pinhole_camera wide{400, {479.5, 239.5}};
  const rectified_photo far = rectify_photo(photo, image(), wide, pose, w, h, 100, o);
  REQUIRE(far.outside_fraction == 0);
  std::size_t under = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) under += span_through(wide, x, y) < 1.0;
  REQUIRE(under > 0);
  REQUIRE(under < std::size_t(w) * h);
  // (one texel either way: the library projects through the homography, the test through the pose)
  CHECK(std::abs(far.underresolved_fraction * (w * h) - double(under)) <= 1.0);
  // Written as the mask's weights (8-bit codes) and read back by the capture's reader.
  rectified_capture capture_out;
  capture_out.width = w;
  capture_out.height = h;
  capture_image im;
  im.file = "rectified_00.exr";
  im.mask = "mask_00.png";
  im.camera = {0, -1.6f, 0.3f};
  im.light = {0, 0, 2};
  capture_out.configurations.images.push_back(im);
  capture_out.photos.push_back(r);
  testing::test_folder dir;
  write_rectified_capture(capture_out, dir.path());
  const image back = read_mask(dir / "mask_00.png", w, h);
  for (std::size_t k = 0; k < back.pixel_count(); ++k) {
    CAPTURE(k);
    if (r.mask.plane(0)[k] == 0) CHECK(back.plane(0)[k] == 0.0f);
    else CHECK(std::abs(back.plane(0)[k] - std::max(r.confidence.plane(0)[k], 1.0f / 255)) <= 0.5f / 255 + 1e-6f);
  }
}

TEST_CASE("texels outside the photo and texels on clipped pixels are masked") {
  const frontal_view v;
  image photo(640, 480, 3);
  for (int c = 0; c < 3; ++c) std::fill_n(photo.plane(c), photo.pixel_count(), 0.25f);
  image usable(640, 480, 1);
  std::fill_n(usable.plane(0), usable.pixel_count(), 1.0f);
  // Clip a block of pixels around the image of sample point (20, -10) mm.
  const Eigen::Vector2d p = project(v.camera, v.pose, {20, -10, 0});
  for (int y = int(p.y()) - 10; y <= int(p.y()) + 10; ++y)
    for (int x = int(p.x()) - 10; x <= int(p.x()) + 10; ++x) usable.at(0, x, y) = 0;
  // The camera moved to the left: the sample moves right and its right part leaves the frame.
  planar_pose shifted = v.pose;
  shifted.translation.x() += 60;  // the sample moves right in camera coordinates
  const rectified_photo r = rectify_photo(photo, usable, v.camera, v.pose, 100, 80, 100);
  const rectified_photo s = rectify_photo(photo, image(), v.camera, shifted, 100, 80, 100);
  // Texel of sample point (20, -10): x = 20 + 50, y = 40 + 10.
  CHECK(r.mask.at(0, 70, 50) == 0);
  CHECK(r.radiance.at(0, 70, 50) == doctest::Approx(0.25));  // clipped: kept for the estimator
  CHECK(s.radiance.at(0, 99, 40) == 0);                      // outside the photo: 0
  CHECK(r.mask.at(0, 10, 10) == 1);
  CHECK(r.radiance.at(0, 10, 10) == doctest::Approx(0.25));
  CHECK(r.clipped_fraction > 0);
  CHECK(r.clipped_fraction < 0.05);
  CHECK(s.outside_fraction > 0.2);
  CHECK(s.mask.at(0, 99, 40) == 0);
  CHECK(s.mask.at(0, 5, 40) == 1);
}

TEST_CASE("a clipped pixel masks only the texel whose footprint it lies in, and reaches no used texel") {
  // Frontal: 4 photo pixels per texel. One pixel, at texel (30, 20)'s centre, is clipped and holds
  // a value far above its surroundings.
  const frontal_view v;
  image photo(640, 480, 3);
  for (int c = 0; c < 3; ++c) std::fill_n(photo.plane(c), photo.pixel_count(), 0.25f);
  image usable(640, 480, 1);
  std::fill_n(usable.plane(0), usable.pixel_count(), 1.0f);
  const Eigen::Vector2d p = project(v.camera, v.pose, texture_to_sample(30.5, 20.5, 100, 80, 100));
  const int px = int(std::lround(p.x())), py = int(std::lround(p.y()));
  for (int c = 0; c < 3; ++c) photo.at(c, px, py) = 100.0f;
  usable.at(0, px, py) = 0.0f;
  const rectified_photo r = rectify_photo(photo, usable, v.camera, v.pose, 100, 80, 100);
  CHECK(r.mask.at(0, 30, 20) == 0);
  CHECK(r.radiance.at(0, 30, 20) > 0.25f);  // kept (clipped) for the estimator, left out of the loss
  std::size_t masked = 0;
  for (int y = 0; y < 80; ++y)
    for (int x = 0; x < 100; ++x) {
      if (r.mask.at(0, x, y) == 0) {
        ++masked;
        continue;
      }
      for (int c = 0; c < 3; ++c) REQUIRE(r.radiance.at(c, x, y) == doctest::Approx(0.25f).epsilon(1e-6));
    }
  CHECK(masked == 1);
  CHECK(r.clipped_fraction == doctest::Approx(1.0 / 8000));
}

TEST_CASE("texture rows run from the sample's top edge: a marked corner lands at texel (0, 0)") {
  // A material with a red top-left quadrant, photographed obliquely and rectified back.
  material_maps maps(32, 32);
  const float grey[parameter_count] = {0.3f, 0.3f, 0.3f, 0.02f, 0.02f, 0.02f, 0.3f, 0.3f, 1, 0, 0, 0};
  maps.fill(grey);
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) { maps.at(diffuse_r, x, y) = 0.8f; maps.at(diffuse_g, x, y) = 0.05f; maps.at(diffuse_b, x, y) = 0.05f; }
  capture configurations;
  capture_image config;
  config.file = "a.exr";
  config.camera = {0.8f, -0.6f, 1.2f};
  config.light = {0.5f, -0.8f, 1.5f};
  config.intensity = {3, 3, 3};
  configurations.images.push_back(config);
  photo_synthesis_options o;
  o.white_fraction = 1;
  o.width = 320;
  o.height = 240;
  const synthetic_photographs s = photograph_capture(maps, configurations, o);
  testing::test_folder dir;
  write_synthetic_photographs(s, dir.path());
  rectify_options ro;
  ro.resolution = 32;
  const rectified_capture r = rectify(read_photos_description(dir / "photos.json"), dir.path(), ro);
  const image& t = r.photos[0].radiance;
  CHECK(t.at(0, 4, 4) > 3 * t.at(1, 4, 4));     // top-left: red
  CHECK(t.at(0, 27, 27) < 1.5 * t.at(1, 27, 27));  // bottom-right: grey
  CHECK(t.at(0, 27, 4) < 1.5 * t.at(1, 27, 4));    // top-right: grey
}

TEST_CASE("round trip: rectify(photograph(material)) matches the texture-space renderer") {
  const int w = 64, h = 48;
  const material_maps maps = smooth_material(w, h);
  const capture configurations = set_alpha(6, 21, w, h);
  for (bool flash : {false, true}) {
    CAPTURE(flash);
    photo_synthesis_options o;
    o.width = 480;
    o.height = 360;
    o.flash = flash;
    o.white_fraction = 0.995;
    o.jpeg_quality = flash ? 90 : 95;  // stb stores the colour at half resolution at 90, in full at 95
    const synthetic_photographs s = photograph_capture(maps, configurations, o);
    testing::test_folder dir;
    write_synthetic_photographs(s, dir.path());
    rectify_options ro;
    ro.resolution = w;
    const photos_description description = read_photos_description(dir / "photos.json");
    const rectified_capture r = rectify(description, dir.path(), ro);
    REQUIRE(r.width == w);
    REQUIRE(r.height == h);
    const std::vector<image> direct = render(maps, s.texture_capture);
    for (std::size_t i = 0; i < r.photos.size(); ++i) {
      CAPTURE(i);
      // The recovered pose and the capture's positions match the truth.
      const photo_setup& truth = s.setups[i];
      CHECK((r.photos[i].pose.camera_centre() - truth.pose.camera_centre()).norm() < 0.5);
      CHECK(Eigen::AngleAxisd(Eigen::Matrix3d(r.photos[i].pose.rotation.transpose() * truth.pose.rotation)).angle() * 180 / std::numbers::pi < 0.1);
      for (int k = 0; k < 3; ++k) {
        CHECK(r.configurations.images[i].camera[k] == doctest::Approx(s.texture_capture.images[i].camera[k]).epsilon(1e-3));
        CHECK(r.configurations.images[i].light[k] == doctest::Approx(s.texture_capture.images[i].light[k]).epsilon(1e-3));
      }
      CHECK(r.configurations.images[i].encoding == (flash ? photo_encoding::jpeg_subsampled : photo_encoding::jpeg));  // kept from the source
      // The rectified image over exposure against the direct render, away from the edges, where the
      // mask keeps the texel and the direct render is visible (not below 8-bit black).
      const double exposure = s.exposures[i];
      double difference = 0, total = 0;
      int used = 0;
      for (int y = 2; y < h - 2; ++y)
        for (int x = 2; x < w - 2; ++x) {
          if (r.photos[i].mask.at(0, x, y) == 0) continue;
          for (int c = 0; c < 3; ++c) {
            const double a = r.photos[i].radiance.at(c, x, y) / exposure, b = direct[i].at(c, x, y);
            difference += std::abs(a - b);
            total += b;
          }
          ++used;
        }
      const double relative = difference / total;
      MESSAGE("photo " << i << std::string(flash ? " (flash)" : "") << ": mean relative error " << relative << " over " << used << " texels");
      CHECK(used > (w - 4) * (h - 4) / 2);
      CHECK(relative < 0.03);
    }
  }
}

TEST_CASE("photos.json errors name the file, the photo and the problem") {
  testing::test_folder dir;
  const auto path = dir / "photos.json";
  auto parse = [&](const std::string& text) { return parse_photos_description(text, path); };
  const std::string sample = R"("sample": {"width_mm": 100, "height_mm": 80}, "camera": {"focal_length_px": 1000})";
  const std::string corners = R"("corners": [[100, 100], [500, 100], [500, 400], [100, 400]])";
  CHECK_THROWS_WITH_AS(parse("{"), doctest::Contains("malformed JSON"), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": [], "extra": 1})"), doctest::Contains("unknown field \"extra\" (expected \"sample\", \"camera\", \"photos\")"), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": []})"), doctest::Contains("non-empty array"), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": [{"file": "a.jpg", )" + corners + "}]}"),
                       doctest::Contains("photos[0] (\"a.jpg\"): missing field \"light\""), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": [{"file": "a.jpg", "light": {"position_mm": [0, 0, 1], "flash_offset_mm": [0, 0, 0]}}]})"),
                       doctest::Contains("exactly one of"), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": [{"file": "a.jpg", "corners": [[1, 2]], "light": {"position_mm": [0, 0, 1]}}]})"),
                       doctest::Contains("4 points"), io_error);
  CHECK_THROWS_WITH_AS(parse("{" + sample + R"(, "photos": [{"file": "a.jpg", "intensity": -1, "light": {"position_mm": [0, 0, 1]}}]})"),
                       doctest::Contains("positive"), io_error);
  // A valid description reads back unchanged.
  const photos_description d = parse("{" + sample + R"(, "photos": [{"file": "a.jpg", )" + corners +
                                     R"(, "light": {"flash_offset_mm": [10, -5, 0]}, "intensity": [1, 2, 3]}]})");
  const photos_description again = parse(photos_description_to_json(d));
  CHECK(again.photos[0].intensity == vec3f{1, 2, 3});
  CHECK((*again.photos[0].corners)[2] == Eigen::Vector2d(500, 400));
  CHECK((*again.photos[0].light.flash_offset_mm)[0] == 10);
}

TEST_CASE("rectify errors: missing photo, missing corners, light below the surface, wrong corner order") {
  testing::test_folder dir;
  // A grey 640 x 480 JPEG of a frontal view.
  const frontal_view v;
  photos_description d;
  d.width_mm = 100;
  d.height_mm = 80;
  d.camera.focal_length_px = v.camera.focal_length;
  photo_entry e;
  e.file = "missing.jpg";
  corner_pixels c;
  const auto points = sample_corners(100, 80);
  for (int k = 0; k < 4; ++k) c[std::size_t(k)] = project(v.camera, v.pose, points[std::size_t(k)]);
  e.corners = c;
  e.light.position_mm = std::array<double, 3>{0, 0, 200};
  d.photos.push_back(e);
  CHECK_THROWS_WITH_AS(rectify(d, dir.path()), doctest::Contains("missing.jpg: file not found"), io_error);
  image grey(640, 480, 3);
  for (int ch = 0; ch < 3; ++ch) std::fill_n(grey.plane(ch), grey.pixel_count(), 0.2f);
  write_png(grey, dir / "grey.png");
  d.photos[0].file = "grey.png";
  CHECK_NOTHROW(rectify(d, dir.path()));
  d.photos[0].light.position_mm = std::array<double, 3>{0, 0, -5};
  CHECK_THROWS_WITH_AS(rectify(d, dir.path()), doctest::Contains("photos[0] (grey.png): the light is at or below"), calibration_error);
  d.photos[0].light.position_mm = std::array<double, 3>{0, 0, 200};
  d.photos[0].corners = corner_pixels{c[0], c[3], c[2], c[1]};
  CHECK_THROWS_WITH_AS(rectify(d, dir.path()), doctest::Contains("photos[0] (grey.png): the corners run counter-clockwise"), calibration_error);
  d.photos[0].corners.reset();
  CHECK_THROWS_WITH_AS(rectify(d, dir.path()), doctest::Contains("no \"corners\""), calibration_error);
  d.photos[0].corners = c;
  d.camera.focal_length_px.reset();
  CHECK_THROWS_WITH_AS(rectify(d, dir.path()), doctest::Contains("photos[0] (grey.png): missing focal length"), calibration_error);
}

TEST_CASE("the default resolution is what the photos support, and the output is written all together") {
  testing::test_folder dir;
  const frontal_view v;  // 100 mm span 400 px
  image grey(640, 480, 3);
  for (int ch = 0; ch < 3; ++ch) std::fill_n(grey.plane(ch), grey.pixel_count(), 0.2f);
  write_png(grey, dir / "grey.png");
  photos_description d;
  d.width_mm = 100;
  d.height_mm = 80;
  d.camera.focal_length_px = v.camera.focal_length;
  photo_entry e;
  e.file = "grey.png";
  corner_pixels c;
  const auto points = sample_corners(100, 80);
  for (int k = 0; k < 4; ++k) c[std::size_t(k)] = project(v.camera, v.pose, points[std::size_t(k)]);
  e.corners = c;
  e.light.flash_offset_mm = std::array<double, 3>{0, 0, 0};
  d.photos.push_back(e);
  const rectified_capture r = rectify(d, dir.path());
  CHECK(r.width == 400);
  CHECK(r.height == 320);
  // Co-located flash: the light is at the camera, in units of the longest side.
  CHECK(r.configurations.images[0].light[2] == doctest::Approx(3.0));
  CHECK(r.configurations.images[0].camera[2] == doctest::Approx(3.0));
  write_rectified_capture(r, dir / "out");
  const capture written = read_capture(dir / "out" / "capture.json");
  CHECK(written.images[0].mask == "mask_00.png");
  CHECK(written.images[0].file == "rectified_00.exr");
  CHECK(read_image(dir / "out" / "rectified_00.exr").width() == 400);
  CHECK(std::filesystem::exists(dir / "out" / "mask_00.png"));
}
