// The marker frame: drawn with the family's tags, found again in synthetic perspective photos, and
// the corners it gives recover the camera poses.
#include <doctest/doctest.h>

#include <numbers>

#include "anisocap/calibration/markers.hpp"
#include "anisocap/calibration/photo_synthesis.hpp"
#include "anisocap/calibration/rectify.hpp"
#include "data/test_folder.hpp"

using namespace anisocap;

TEST_CASE("the marker frame surrounds the window with distinct tags") {
  const marker_frame f = make_marker_frame(100, 80);
  CHECK(f.markers.size() >= 8);
  for (std::size_t i = 0; i < f.markers.size(); ++i) {
    CHECK(f.markers[i].id == int(i));
    // Every tag lies outside the window, clear of it by the gap.
    const Eigen::Vector2d c = f.markers[i].centre;
    CHECK((std::abs(c.x()) > 50 + f.gap_mm + f.tag_mm / 2 - 1e-9 || std::abs(c.y()) > 40 + f.gap_mm + f.tag_mm / 2 - 1e-9));
  }
  const image sheet = draw_marker_frame(f, 300 / 25.4);
  // The window's centre is grey, a tag's black border is black, the sheet's corner is paper white.
  CHECK(sheet.at(0, sheet.width() / 2, sheet.height() / 2) == 0.5f);
  CHECK(sheet.at(0, 0, 0) == 1.0f);
}

TEST_CASE("corners found from the markers in synthetic photos recover the camera poses") {
  const marker_frame f = make_marker_frame(100, 80);
  auto surround = std::make_shared<printed_surround>();
  surround->albedo = draw_marker_frame(f, 4.0);
  const Eigen::Vector2d half = f.half_sheet();
  surround->width_mm = surround->albedo.width() / 4.0;
  surround->height_mm = surround->albedo.height() / 4.0;
  CHECK(surround->width_mm >= 2 * half.x());
  material_maps maps(50, 40);
  const float grey[parameter_count] = {0.3f, 0.25f, 0.2f, 0.05f, 0.05f, 0.05f, 0.3f, 0.3f, 1, 0, 0, 0};
  maps.fill(grey);
  capture configurations;
  for (const vec3f& camera : {vec3f{0.1f, -0.2f, 2.0f}, vec3f{1.2f, 0.4f, 1.6f}, vec3f{-0.8f, -1.0f, 1.3f}}) {
    capture_image c;
    c.camera = camera;
    c.light = {0.3f, 0.5f, 2.0f};
    c.intensity = {3, 3, 3};
    configurations.images.push_back(c);
  }
  photo_synthesis_options o;
  o.width = 1280;
  o.height = 960;
  o.fill = 0.6;  // the sample in the middle, the frame around it in view
  o.white_fraction = 1;
  o.surround = surround;
  o.longest_mm = 100;
  const synthetic_photographs s = photograph_capture(maps, configurations, o);
  testing::test_folder dir;
  write_synthetic_photographs(s, dir.path());
  photos_description d = read_photos_description(dir / "photos.json");
  for (auto& p : d.photos) p.corners.reset();
  const corner_finder finder = [&](const photo& picture, const photos_description&, const std::string& name) {
    return find_corners_from_markers(picture, f, name);
  };
  rectify_options ro;
  ro.resolution = 50;
  const rectified_capture r = rectify(d, dir.path(), ro, finder);
  for (std::size_t i = 0; i < r.photos.size(); ++i) {
    const double mm = (r.photos[i].pose.camera_centre() - s.setups[i].pose.camera_centre()).norm();
    const double degrees =
        Eigen::AngleAxisd(Eigen::Matrix3d(r.photos[i].pose.rotation.transpose() * s.setups[i].pose.rotation)).angle() * 180 / std::numbers::pi;
    MESSAGE("photo " << i << ": camera " << mm << " mm, rotation " << degrees << " degrees from the truth");
    CHECK(mm < 0.5);
    CHECK(degrees < 0.1);
  }
  // Without markers in view the error names the photo.
  photo blank;
  blank.pixels = image(64, 48, 3);
  CHECK_THROWS_WITH_AS(find_corners_from_markers(blank, f, "IMG_9.jpg"), doctest::Contains("IMG_9.jpg: found 0 of the frame's"), calibration_error);
}
