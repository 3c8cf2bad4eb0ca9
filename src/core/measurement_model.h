#pragma once
// The range-bearing observation model shared by every estimator: the EKF's predicted
// observation (5.27), the particle filter's likelihood and the smoothers' range-bearing factor
// all call these functions, so they linearise the same model.
#include <Eigen/Core>
#include <cmath>

#include "src/core/angles.h"
#include "src/core/pose2.h"

namespace stereoloc {

// (5.27): z = (|l - t|, atan2(l_y - y, l_x - x) - theta), bearing wrapped to [-pi, pi).
// pose = [x, y, theta] (mm, rad), landmark = [x, y] (mm). Templated for automatic differentiation.
template <typename T>
void predictRangeBearingT(const T* pose, const T* landmark, T* z) {
  using std::atan2;
  using std::sqrt;
  const T dx = landmark[0] - pose[0];
  const T dy = landmark[1] - pose[1];
  z[0] = sqrt(dx * dx + dy * dy);
  z[1] = wrapAngle<T>(atan2(dy, dx) - pose[2]);
}

// The same with the analytic Jacobian w.r.t. the pose (convention of src/core/pose2.h).
// Throws GeometryError when the landmark coincides with the robot (the bearing is undefined).
Eigen::Vector2d predictRangeBearing(const Pose2& pose, const Eigen::Vector2d& landmark,
                                    Matrix23d* J_z_pose = nullptr);

// z_measured [-] z_predicted: range difference and wrapped bearing difference.
inline Eigen::Vector2d rangeBearingInnovation(const Eigen::Vector2d& measured, const Eigen::Vector2d& predicted) {
  return Eigen::Vector2d(measured.x() - predicted.x(), angleDiff(measured.y(), predicted.y()));
}

// The landmark position implied by a pose and a range-bearing observation.
inline Eigen::Vector2d landmarkFromRangeBearing(const Pose2& pose, double range, double bearing) {
  const double phi = pose.theta + bearing;
  return Eigen::Vector2d(pose.x + range * std::cos(phi), pose.y + range * std::sin(phi));
}

}  // namespace stereoloc
