#pragma once
/// @file
/// A pinhole camera and the pose of a flat rectangular sample in front of it, found from the
/// sample's four corners in a photograph (docs/method.md section 4 for the sample's coordinates).
///
/// Sample coordinates, in millimetres: origin at the sample's centre, x along the top edge to the
/// right, y towards the top edge, z out of the surface; the sample is the rectangle
/// [-W/2, W/2] x [-H/2, H/2] in the plane z = 0. Camera coordinates: x right, y down, z forward
/// (the viewing direction). Pixel coordinates: x to the right, y down, pixel centres at integer
/// coordinates (the top-left pixel's centre is (0, 0)), as OpenCV and most corner detectors use.
///
/// The pose comes from the homography between the sample plane and the photograph with known
/// intrinsics (Zhang, "A flexible new technique for camera calibration", 2000, section 3.1:
/// K^-1 H = s [r1 r2 t]), the rotation made orthonormal (nearest rotation by SVD), then refined by
/// Levenberg-Marquardt on the corners' reprojection error.
#include <Eigen/Dense>

#include <array>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace anisocap {

/// A calibration problem with one photograph (bad corners, a sample behind the camera, a light
/// below the surface, a missing focal length). `what()` names the photograph.
class calibration_error : public std::runtime_error {
 public:
  /// Message `photo: problem`.
  calibration_error(const std::string& photo, const std::string& problem) : std::runtime_error(photo + ": " + problem) {}
};

/// Intrinsics of a pinhole camera without lens distortion, in pixels.
struct pinhole_camera {
  double focal_length = 0;                 ///< focal length in pixels (square pixels)
  Eigen::Vector2d principal_point{0, 0};  ///< where the optical axis meets the image, in pixels

  /// The 3 x 3 intrinsic matrix K.
  Eigen::Matrix3d matrix() const {
    Eigen::Matrix3d k;
    k << focal_length, 0, principal_point.x(), 0, focal_length, principal_point.y(), 0, 0, 1;
    return k;
  }
};

/// What a photographer knows about the camera (the "camera" object of photos.json): the focal
/// length either in pixels or in millimetres with the sensor's width; the principal point when
/// it is not the image centre.
struct camera_description {
  std::optional<double> focal_length_px;                  ///< focal length in pixels
  std::optional<double> focal_length_mm;                  ///< focal length in mm (needs sensor_width_mm)
  std::optional<double> sensor_width_mm;                  ///< sensor width in mm, along the image's x
  std::optional<std::array<double, 2>> principal_point_px;///< principal point in pixels (default: centre)
};

/// The intrinsics of a `width` x `height` photograph described by `d`; throws calibration_error
/// naming `photo` when no focal length can be formed or a value is not positive and finite.
inline pinhole_camera make_camera(const camera_description& d, int width, int height, const std::string& photo) {
  auto positive = [&](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0)) throw calibration_error(photo, std::string("camera ") + name + " must be positive, got " + std::to_string(v));
  };
  pinhole_camera c;
  if (d.focal_length_px) {
    positive(*d.focal_length_px, "focal_length_px");
    c.focal_length = *d.focal_length_px;
  } else if (d.focal_length_mm && d.sensor_width_mm) {
    positive(*d.focal_length_mm, "focal_length_mm");
    positive(*d.sensor_width_mm, "sensor_width_mm");
    c.focal_length = *d.focal_length_mm * double(width) / *d.sensor_width_mm;
  } else if (d.focal_length_mm) {
    throw calibration_error(photo, "camera focal_length_mm needs sensor_width_mm too (or give focal_length_px)");
  } else {
    throw calibration_error(photo, "missing focal length: give camera focal_length_px, or focal_length_mm with sensor_width_mm");
  }
  if (d.principal_point_px) {
    const auto& p = *d.principal_point_px;
    if (!std::isfinite(p[0]) || !std::isfinite(p[1])) throw calibration_error(photo, "camera principal_point_px is not finite");
    c.principal_point = {p[0], p[1]};
  } else {
    c.principal_point = {0.5 * (width - 1), 0.5 * (height - 1)};
  }
  return c;
}

/// Rigid transform from sample coordinates (mm) to camera coordinates: X_camera = R X_sample + t.
struct planar_pose {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  ///< R, rows are the camera axes in sample coordinates
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();   ///< t in mm

  /// The camera's centre in sample coordinates, -R^T t.
  Eigen::Vector3d camera_centre() const { return -rotation.transpose() * translation; }
  /// A point given in camera coordinates, in sample coordinates.
  Eigen::Vector3d to_sample(const Eigen::Vector3d& camera_point) const {
    return rotation.transpose() * (camera_point - translation);
  }
};

/// The pose of a camera at `centre` (sample coordinates, mm) looking at `target`, with the image's
/// up direction as close to `up` as possible (camera x = forward x up, y = forward x x).
inline planar_pose look_at(const Eigen::Vector3d& centre, const Eigen::Vector3d& target, const Eigen::Vector3d& up) {
  const Eigen::Vector3d z = (target - centre).normalized();
  Eigen::Vector3d x = z.cross(up);
  if (x.norm() < 1e-9) throw std::invalid_argument("look_at: the up direction is parallel to the viewing direction");
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  planar_pose p;
  p.rotation.row(0) = x.transpose();
  p.rotation.row(1) = y.transpose();
  p.rotation.row(2) = z.transpose();
  p.translation = -p.rotation * centre;
  return p;
}

/// Pixel coordinates of a sample point (mm) seen by `camera` at `pose`.
inline Eigen::Vector2d project(const pinhole_camera& camera, const planar_pose& pose, const Eigen::Vector3d& sample_point) {
  const Eigen::Vector3d c = pose.rotation * sample_point + pose.translation;
  return camera.focal_length * c.head<2>() / c.z() + camera.principal_point;
}

/// The four corners of a width x height (mm) sample in texture order: top-left, top-right,
/// bottom-right, bottom-left, in sample coordinates.
inline std::array<Eigen::Vector3d, 4> sample_corners(double width_mm, double height_mm) {
  const double x = 0.5 * width_mm, y = 0.5 * height_mm;
  return {Eigen::Vector3d(-x, y, 0), Eigen::Vector3d(x, y, 0), Eigen::Vector3d(x, -y, 0), Eigen::Vector3d(-x, -y, 0)};
}

/// Four pixel positions of the sample's corners, in texture order.
using corner_pixels = std::array<Eigen::Vector2d, 4>;

/// Checks that `corners` are finite and form a convex quadrilateral in texture order (top-left,
/// top-right, bottom-right, bottom-left: clockwise on the image, whose y runs down, for a sample
/// seen from the front). Throws calibration_error naming `photo` and what is wrong.
inline void check_corner_order(const corner_pixels& corners, const std::string& photo) {
  for (const auto& c : corners)
    if (!c.allFinite()) throw calibration_error(photo, "a corner coordinate is not finite");
  int clockwise = 0, counter = 0;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d a = corners[(i + 1) % 4] - corners[i], b = corners[(i + 2) % 4] - corners[(i + 1) % 4];
    const double cross = a.x() * b.y() - a.y() * b.x();
    const double scale = a.norm() * b.norm();
    if (!(scale > 0)) throw calibration_error(photo, "two corners coincide");
    if (cross > 1e-9 * scale) ++clockwise;
    else if (cross < -1e-9 * scale) ++counter;
  }
  if (counter == 4)
    throw calibration_error(photo, "the corners run counter-clockwise on the image: give them in texture order "
                                   "(top-left, top-right, bottom-right, bottom-left), or the sample is seen from behind");
  if (clockwise != 4)
    throw calibration_error(photo, "the corners do not form a convex quadrilateral: give them in texture order "
                                   "(top-left, top-right, bottom-right, bottom-left)");
}

/// The homography H (3 x 3, H(2,2) = 1) with to[i] ~ H (from[i], 1) for N >= 4 point pairs
/// (least squares beyond four): the direct linear transform with Hartley's normalisation, the
/// null vector from one SVD. The pose's four corners and the marker frames' many tag corners share
/// it (a fixed-size 8 x 9 decomposition as well would cost the program seconds of compile time).
inline Eigen::Matrix3d homography_dlt(const std::vector<Eigen::Vector2d>& from, const std::vector<Eigen::Vector2d>& to) {
  if (from.size() != to.size() || from.size() < 4)
    throw std::invalid_argument("homography_dlt: needs as many pixels as plane points, at least four (got " +
                                std::to_string(from.size()) + " and " + std::to_string(to.size()) + ")");
  auto normaliser = [](const std::vector<Eigen::Vector2d>& p) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (const auto& q : p) mean += q;
    mean /= double(p.size());
    double spread = 0;
    for (const auto& q : p) spread += (q - mean).norm();
    const double s = std::sqrt(2.0) / (spread / double(p.size()));
    Eigen::Matrix3d t;
    t << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
    return t;
  };
  const Eigen::Matrix3d ta = normaliser(from), tb = normaliser(to);
  Eigen::MatrixXd a(2 * from.size(), 9);
  for (std::size_t i = 0; i < from.size(); ++i) {
    const Eigen::Vector3d p = ta * from[i].homogeneous(), q = tb * to[i].homogeneous();
    const double x = p.x(), y = p.y(), u = q.x(), v = q.y();
    a.row(Eigen::Index(2 * i)) << x, y, 1, 0, 0, 0, -u * x, -u * y, -u;
    a.row(Eigen::Index(2 * i + 1)) << 0, 0, 0, x, y, 1, -v * x, -v * y, -v;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  const Eigen::VectorXd h = svd.matrixV().col(8);
  Eigen::Matrix3d hn;
  hn << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  const Eigen::Matrix3d r = tb.inverse() * hn * ta;
  return r / r(2, 2);
}

/// The homography H (3 x 3, H(2,2) = 1) with pixels ~ H (X, Y, 1) from four plane points
/// (X, Y) to four pixels (homography_dlt).
inline Eigen::Matrix3d homography_from_points(const std::array<Eigen::Vector2d, 4>& plane, const corner_pixels& pixels) {
  return homography_dlt({plane.begin(), plane.end()}, {pixels.begin(), pixels.end()});
}

/// Options of estimate_pose.
struct pose_options {
  int refine_iterations = 20;  ///< Levenberg-Marquardt iterations on the reprojection error (0: Zhang's closed form only)
};

/// The reprojection residuals (8 values: x, y per corner) of `pose`.
inline Eigen::Matrix<double, 8, 1> reprojection_residuals(const pinhole_camera& camera, const planar_pose& pose,
                                                          const std::array<Eigen::Vector3d, 4>& points, const corner_pixels& pixels) {
  Eigen::Matrix<double, 8, 1> r;
  for (int i = 0; i < 4; ++i) r.segment<2>(2 * i) = project(camera, pose, points[i]) - pixels[i];
  return r;
}

/// The pose of a width x height (mm) sample whose corners appear at `corners` (texture order) in
/// a photograph taken with `camera`. Checks the corner order, and that the whole sample lies in
/// front of the camera and is seen from its front; throws calibration_error naming `photo`.
inline planar_pose estimate_pose(const pinhole_camera& camera, const corner_pixels& corners, double width_mm, double height_mm,
                                 const std::string& photo, const pose_options& options = {}) {
  if (!(width_mm > 0 && height_mm > 0 && std::isfinite(width_mm) && std::isfinite(height_mm)))
    throw calibration_error(photo, "the sample's width and height must be positive");
  check_corner_order(corners, photo);
  const auto points = sample_corners(width_mm, height_mm);
  std::array<Eigen::Vector2d, 4> plane;
  for (int i = 0; i < 4; ++i) plane[i] = points[i].head<2>();
  const Eigen::Matrix3d h = homography_from_points(plane, corners);
  // Zhang 2000, section 3.1: K^-1 H = s [r1 r2 t]; the sign of s puts the sample in front (t_z > 0).
  const Eigen::Matrix3d m = camera.matrix().inverse() * h;
  double s = 2.0 / (m.col(0).norm() + m.col(1).norm());
  if (m(2, 2) * s < 0) s = -s;
  Eigen::Matrix3d r;
  r.col(0) = s * m.col(0);
  r.col(1) = s * m.col(1);
  r.col(2) = r.col(0).cross(r.col(1));
  // The nearest rotation, through the same dynamic-size SVD as homography_dlt (one decomposition
  // for the compiler to instantiate).
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(Eigen::MatrixXd(r), Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d u = svd.matrixU(), v = svd.matrixV();
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (u * v.transpose()).determinant() < 0 ? -1 : 1;
  planar_pose pose;
  pose.rotation = u * d * v.transpose();
  pose.translation = s * m.col(2);

  // Levenberg-Marquardt over a rotation increment w (R <- exp([w]x) R) and t, forward-difference
  // Jacobian: 8 residuals, 6 unknowns.
  auto apply = [](const planar_pose& p, const Eigen::Matrix<double, 6, 1>& delta) {
    planar_pose q = p;
    const double angle = delta.head<3>().norm();
    if (angle > 0) q.rotation = Eigen::AngleAxisd(angle, delta.head<3>() / angle).toRotationMatrix() * p.rotation;
    q.translation = p.translation + delta.tail<3>();
    return q;
  };
  double lambda = 1e-3;
  Eigen::Matrix<double, 8, 1> residual = reprojection_residuals(camera, pose, points, corners);
  for (int iteration = 0; iteration < options.refine_iterations; ++iteration) {
    Eigen::Matrix<double, 8, 6> jacobian;
    const double depth = std::max(1.0, pose.translation.norm());
    for (int k = 0; k < 6; ++k) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      const double step = k < 3 ? 1e-7 : 1e-7 * depth;
      delta(k) = step;
      jacobian.col(k) = (reprojection_residuals(camera, apply(pose, delta), points, corners) - residual) / step;
    }
    const Eigen::Matrix<double, 6, 6> normal = jacobian.transpose() * jacobian;
    const Eigen::Matrix<double, 6, 1> gradient = jacobian.transpose() * residual;
    bool improved = false;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      Eigen::Matrix<double, 6, 6> damped = normal;
      damped.diagonal() += lambda * normal.diagonal().cwiseMax(1e-12);
      const Eigen::Matrix<double, 6, 1> step = -damped.ldlt().solve(gradient);
      const planar_pose candidate = apply(pose, step);
      const Eigen::Matrix<double, 8, 1> r = reprojection_residuals(camera, candidate, points, corners);
      if (r.squaredNorm() < residual.squaredNorm()) {
        pose = candidate;
        residual = r;
        lambda = std::max(lambda * 0.1, 1e-12);
        improved = true;
      } else {
        lambda *= 10;
      }
    }
    if (!improved || residual.norm() < 1e-12) break;
  }

  for (int i = 0; i < 4; ++i)
    if (!((pose.rotation * points[i] + pose.translation).z() > 0))
      throw calibration_error(photo, "the sample lies (partly) behind the camera; check the corners and the focal length");
  if (!(pose.camera_centre().z() > 0))
    throw calibration_error(photo, "the camera sees the sample from behind; check the corner order");
  return pose;
}

}  // namespace anisocap
