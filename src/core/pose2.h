#pragma once
// Pose2: a planar robot pose (x, y in mm, theta in rad) and its group operations.
//
// THE Jacobian convention of stereoloc (stated once, used everywhere):
//   * The state is the vector (x, y, theta) on R^2 x SO(2), tangent order (x, y, theta).
//   * Perturbations are applied on the right of that product manifold:
//       p [+] d = (x + dx, y + dy, wrap(theta + dtheta)),   a [-] b = (xa-xb, ya-yb, wrap(ta-tb)).
//     For R^2 x SO(2) "right" and "left" coincide, so this is additive in world-frame x, y and
//     in theta. It is the parametrisation of the thesis's EKF (eqs. 5.6, B.18, B.19) and of the
//     smoothers' Ceres manifold, which is what makes "window W = 1 equals the EKF" exact.
//   * A Jacobian named J_out_in is d(out)/d(in) under that perturbation.
#include <Eigen/Core>
#include <cmath>

#include "src/core/angles.h"

namespace stereoloc {

using Matrix3d = Eigen::Matrix3d;
using Vector3d = Eigen::Vector3d;
using Vector2d = Eigen::Vector2d;
using Matrix2d = Eigen::Matrix2d;
using Matrix23d = Eigen::Matrix<double, 2, 3>;

struct Pose2 {
  double x = 0.0;      // mm
  double y = 0.0;      // mm
  double theta = 0.0;  // rad, kept in [-pi, pi)

  Pose2() = default;
  Pose2(double x_mm, double y_mm, double theta_rad) : x(x_mm), y(y_mm), theta(wrapAngle(theta_rad)) {}

  Vector3d vector() const { return Vector3d(x, y, theta); }
  static Pose2 fromVector(const Vector3d& v) { return Pose2(v.x(), v.y(), v.z()); }
  Vector2d translation() const { return Vector2d(x, y); }
  Matrix2d rotation() const;
  bool isFinite() const { return std::isfinite(x) && std::isfinite(y) && std::isfinite(theta); }
};

// a (+) b: b expressed in a's frame, composed onto a (B.16). J_out_a is (B.18), J_out_b is (B.19).
Pose2 compose(const Pose2& a, const Pose2& b, Matrix3d* J_out_a = nullptr, Matrix3d* J_out_b = nullptr);

// The pose p^-1 such that compose(p, inverse(p)) is the identity.
Pose2 inverse(const Pose2& p, Matrix3d* J_out_p = nullptr);

// a^-1 (+) b: the pose of b in the frame of a (the odometry measurement from a to b).
Pose2 between(const Pose2& a, const Pose2& b, Matrix3d* J_out_a = nullptr, Matrix3d* J_out_b = nullptr);

// Right-perturbation retraction and its inverse on R^2 x SO(2) (see the header comment).
Pose2 plus(const Pose2& p, const Vector3d& delta);
Vector3d minus(const Pose2& a, const Pose2& b);

// A world point in the robot frame, R(theta)^T (q - t).
Vector2d transformToLocal(const Pose2& p, const Vector2d& world, Matrix23d* J_out_p = nullptr,
                          Matrix2d* J_out_world = nullptr);
// A robot-frame point in the world frame, R(theta) q + t.
Vector2d transformToWorld(const Pose2& p, const Vector2d& local);

// Templated forms for automatic differentiation (T = double or ceres::Jet). Poses are
// arrays [x, y, theta].
template <typename T>
void composeT(const T* a, const T* b, T* out) {
  using std::cos;
  using std::sin;
  const T c = cos(a[2]), s = sin(a[2]);
  out[0] = a[0] + c * b[0] - s * b[1];
  out[1] = a[1] + s * b[0] + c * b[1];
  out[2] = wrapAngle<T>(a[2] + b[2]);
}

template <typename T>
void betweenT(const T* a, const T* b, T* out) {
  using std::cos;
  using std::sin;
  const T c = cos(a[2]), s = sin(a[2]);
  const T dx = b[0] - a[0], dy = b[1] - a[1];
  out[0] = c * dx + s * dy;
  out[1] = -s * dx + c * dy;
  out[2] = wrapAngle<T>(b[2] - a[2]);
}

}  // namespace stereoloc
