// Planar pose from four corners: recovery against known poses, corner order and bad-input errors.
#include <doctest/doctest.h>

#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "anisocap/calibration/camera.hpp"
#include "anisocap/core/random.hpp"

using namespace anisocap;

namespace {

/// Angle in degrees of the rotation between two rotation matrices.
double rotation_error_degrees(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(Eigen::Matrix3d(a.transpose() * b)).angle() * 180.0 / std::numbers::pi;
}

/// A random camera above a 100 x 80 mm sample: distance 150-400 mm, up to 70 degrees from the
/// vertical, aimed near the centre, with a random roll.
planar_pose random_pose(random_generator& rng) {
  const double theta = rng.uniform(0.0, 70.0) * std::numbers::pi / 180, phi = rng.uniform(0.0, 2 * std::numbers::pi);
  const double d = rng.uniform(150.0, 400.0);
  const Eigen::Vector3d centre(d * std::sin(theta) * std::cos(phi), d * std::sin(theta) * std::sin(phi), d * std::cos(theta));
  const Eigen::Vector3d target(rng.uniform(-10.0, 10.0), rng.uniform(-10.0, 10.0), 0);
  const double roll = rng.uniform(0.0, 2 * std::numbers::pi);
  const Eigen::Vector3d up(std::cos(roll), std::sin(roll), 0.3);
  return look_at(centre, target, up);
}

corner_pixels project_corners(const pinhole_camera& camera, const planar_pose& pose, double w, double h) {
  corner_pixels c;
  const auto points = sample_corners(w, h);
  for (int i = 0; i < 4; ++i) c[std::size_t(i)] = project(camera, pose, points[std::size_t(i)]);
  return c;
}

}  // namespace

TEST_CASE("intrinsics from the focal length in pixels or in millimetres with the sensor width") {
  camera_description d;
  d.focal_length_mm = 4.25;
  d.sensor_width_mm = 5.6;
  const pinhole_camera c = make_camera(d, 4000, 3000, "IMG_1.jpg");
  CHECK(c.focal_length == doctest::Approx(4.25 * 4000 / 5.6));
  CHECK(c.principal_point.x() == doctest::Approx(1999.5));
  CHECK(c.principal_point.y() == doctest::Approx(1499.5));
  d.principal_point_px = std::array<double, 2>{2010, 1490};
  CHECK(make_camera(d, 4000, 3000, "IMG_1.jpg").principal_point.x() == 2010);
  d.focal_length_px = 3000;
  CHECK(make_camera(d, 4000, 3000, "IMG_1.jpg").focal_length == 3000);
}

TEST_CASE("a missing or impossible focal length is an error naming the photo") {
  camera_description d;
  CHECK_THROWS_WITH_AS(make_camera(d, 100, 100, "IMG_7.jpg"), doctest::Contains("IMG_7.jpg: missing focal length"), calibration_error);
  d.focal_length_mm = 4;
  CHECK_THROWS_WITH_AS(make_camera(d, 100, 100, "IMG_7.jpg"), doctest::Contains("sensor_width_mm"), calibration_error);
  d.focal_length_px = -3;
  CHECK_THROWS_WITH_AS(make_camera(d, 100, 100, "IMG_7.jpg"), doctest::Contains("must be positive"), calibration_error);
}

TEST_CASE("pose from exact corners recovers known poses") {
  random_generator rng(11);
  const pinhole_camera camera{2000, {1999.5, 1499.5}};
  for (int trial = 0; trial < 50; ++trial) {
    const planar_pose truth = random_pose(rng);
    const corner_pixels corners = project_corners(camera, truth, 100, 80);
    const planar_pose pose = estimate_pose(camera, corners, 100, 80, "photo");
    CHECK((pose.camera_centre() - truth.camera_centre()).norm() < 1e-6);
    CHECK(rotation_error_degrees(pose.rotation, truth.rotation) < 1e-6);
  }
}

TEST_CASE("pose from corners located to a tenth of a pixel: under 0.5 mm and 0.1 degree") {
  // A 12-megapixel phone photo (f = 3000 px) of a 100 x 80 mm sample from 150-400 mm; corner
  // detectors (AprilTag's, a careful click) are accurate to about 0.1 px.
  random_generator rng(5);
  const pinhole_camera camera{3000, {1999.5, 1499.5}};
  double worst_mm = 0, worst_degrees = 0;
  for (int trial = 0; trial < 50; ++trial) {
    const planar_pose truth = random_pose(rng);
    corner_pixels corners = project_corners(camera, truth, 100, 80);
    for (auto& c : corners) c += Eigen::Vector2d(rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1));
    const planar_pose pose = estimate_pose(camera, corners, 100, 80, "photo");
    worst_mm = std::max(worst_mm, (pose.camera_centre() - truth.camera_centre()).norm());
    worst_degrees = std::max(worst_degrees, rotation_error_degrees(pose.rotation, truth.rotation));
  }
  MESSAGE("worst camera position error " << worst_mm << " mm, rotation " << worst_degrees << " degrees");
  CHECK(worst_mm < 0.5);
  CHECK(worst_degrees < 0.1);
}

TEST_CASE("the refinement lowers the reprojection error of noisy corners") {
  random_generator rng(3);
  const pinhole_camera camera{1500, {799.5, 599.5}};
  const planar_pose truth = random_pose(rng);
  corner_pixels corners = project_corners(camera, truth, 100, 80);
  for (auto& c : corners) c += Eigen::Vector2d(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
  const auto points = sample_corners(100, 80);
  const double closed_form = reprojection_residuals(camera, estimate_pose(camera, corners, 100, 80, "p", {0}), points, corners).norm();
  const double refined = reprojection_residuals(camera, estimate_pose(camera, corners, 100, 80, "p"), points, corners).norm();
  CHECK(refined <= closed_form);
}

TEST_CASE("corners out of texture order or not convex are errors naming the photo") {
  const pinhole_camera camera{1000, {499.5, 499.5}};
  const planar_pose truth = look_at({20, -30, 300}, {0, 0, 0}, {0, 1, 0});
  const corner_pixels good = project_corners(camera, truth, 100, 80);
  // Top-down with the image's up along +y: top-left is at the image's upper left.
  CHECK(good[0].x() < good[1].x());
  CHECK(good[0].y() < good[3].y());
  CHECK_NOTHROW(estimate_pose(camera, good, 100, 80, "IMG_2.jpg"));
  const corner_pixels reversed{good[0], good[3], good[2], good[1]};
  CHECK_THROWS_WITH_AS(estimate_pose(camera, reversed, 100, 80, "IMG_2.jpg"),
                       doctest::Contains("IMG_2.jpg: the corners run counter-clockwise"), calibration_error);
  const corner_pixels crossed{good[0], good[2], good[1], good[3]};
  CHECK_THROWS_WITH_AS(estimate_pose(camera, crossed, 100, 80, "IMG_2.jpg"),
                       doctest::Contains("IMG_2.jpg: the corners do not form a convex quadrilateral"), calibration_error);
  const corner_pixels repeated{good[0], good[0], good[2], good[3]};
  CHECK_THROWS_AS(estimate_pose(camera, repeated, 100, 80, "IMG_2.jpg"), calibration_error);
  corner_pixels nan = good;
  nan[1].x() = std::nan("");
  CHECK_THROWS_WITH_AS(estimate_pose(camera, nan, 100, 80, "IMG_2.jpg"), doctest::Contains("not finite"), calibration_error);
}

TEST_CASE("look_at and project agree with the axis conventions") {
  // Camera straight above the centre, image up along the sample's +y (towards its top edge).
  const planar_pose p = look_at({0, 0, 500}, {0, 0, 0}, {0, 1, 0});
  const pinhole_camera camera{1000, {500, 400}};
  const Eigen::Vector2d centre = project(camera, p, {0, 0, 0});
  CHECK(centre.x() == doctest::Approx(500));
  CHECK(centre.y() == doctest::Approx(400));
  const Eigen::Vector2d right = project(camera, p, {10, 0, 0}), top = project(camera, p, {0, 10, 0});
  CHECK(right.x() > 500);  // sample +x is image right
  CHECK(top.y() < 400);    // sample +y (top edge) is image up
  CHECK(p.camera_centre().z() == doctest::Approx(500));
}

TEST_CASE("homography_dlt maps four or many plane points onto their images, and refuses fewer than four") {
  random_generator rng(17);
  for (int trial = 0; trial < 20; ++trial) {
    const pinhole_camera camera{rng.uniform(800.0, 3000.0), {999.5, 749.5}};
    const planar_pose pose = random_pose(rng);
    for (const int n : {4, 12}) {
      std::vector<Eigen::Vector2d> plane, pixels;
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d p(rng.uniform(-50.0, 50.0), rng.uniform(-40.0, 40.0), 0);
        plane.push_back(p.head<2>());
        pixels.push_back(project(camera, pose, p));
      }
      const Eigen::Matrix3d h = homography_dlt(plane, pixels);
      CHECK(h(2, 2) == doctest::Approx(1.0));
      // Every pair, and a point that took no part in the fit, land where the camera sees them (to a
      // millionth of their pixel coordinates).
      plane.emplace_back(rng.uniform(-50.0, 50.0), rng.uniform(-40.0, 40.0));
      pixels.push_back(project(camera, pose, Eigen::Vector3d(plane.back().x(), plane.back().y(), 0)));
      for (std::size_t i = 0; i < plane.size(); ++i) CHECK((h * plane[i].homogeneous()).hnormalized().isApprox(pixels[i], 1e-6));
    }
  }
  const std::vector<Eigen::Vector2d> three(3, Eigen::Vector2d(1, 2)), four(4, Eigen::Vector2d(1, 2));
  CHECK_THROWS_WITH_AS(homography_dlt(three, three), doctest::Contains("at least four"), std::invalid_argument);
  CHECK_THROWS_WITH_AS(homography_dlt(four, three), doctest::Contains("got 4 and 3"), std::invalid_argument);
}
