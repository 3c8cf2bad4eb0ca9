#pragma once
// The range-bearing observation model shared by every estimator: the EKF's predicted
// observation (5.27), the particle filter's likelihood and the smoothers' range-bearing factor
// all call these functions, so they linearise the same model.
#include <Eigen/Core>
#include <cmath>
#include <string>

#include "src/core/angles.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"

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

// A range-bearing sensor whose range scale changes across its field of view (MR.CLAM's barcode
// camera, docs/results.md) reports f(b) times the true range at the bearing b it reports:
//   f(b) = 1 + c0 + c1 b + c2 b^2,   c = (c0, c1 [1/rad], c2 [1/rad^2]),   df/dc = (1, b, b^2).
// One definition for the importer's correction, the range factor and the EKF's and the window's
// calibrated sightings. Templated for automatic differentiation.
template <typename T>
T rangeFactorAt(const T* c, double bearing) {
  return T(1.0) + c[0] + c[1] * T(bearing) + c[2] * T(bearing * bearing);
}
inline Eigen::Vector3d rangeFactorGradient(double bearing) { return Eigen::Vector3d(1.0, bearing, bearing * bearing); }

// The landmark position implied by a pose and a range-bearing observation.
inline Eigen::Vector2d landmarkFromRangeBearing(const Pose2& pose, double range, double bearing) {
  const double phi = pose.theta + bearing;
  return Eigen::Vector2d(pose.x + range * std::cos(phi), pose.y + range * std::sin(phi));
}

// Stereo pixel covariance. A stereo observation's pixel errors are a 4-vector in the order
// (u_left, v_left, u_right, v_right), px; its covariance C (px^2) replaces the thesis's
// Sigma_i = sigma^2 I of (5.28). The frontend's errors are not independent: a corner's sub-pixel
// position error is common to both images (the same geometry is found in both), the stereo
// match adds a smaller disparity error, and the right feature is searched on the left's row.
// Its model is therefore given in (u, v, d), the left column and row and the disparity
// d = u_l - u_r, with u_l = u, v_l = v, u_r = u - d, v_r = v + delta, where delta, the row
// difference, is independent with the small sigma kRowDifferenceSigma (the frontend's rows are
// identical; the floor keeps C invertible, and the residual along v_l - v_r is zero for a
// rectified pair whatever weight it gets). Derivation: docs/estimators.md, "Observation covariance".
inline constexpr double kRowDifferenceSigma = 0.01;  // px

// C from the (u, v, d) model: sigmas in px, corr_ud the correlation of the u and d errors (|.| < 1).
// Throws stereoloc::Error naming the field for a non-positive sigma or |corr_ud| >= 1.
Eigen::Matrix4d stereoPixelCovariance(double sigma_u, double sigma_v, double sigma_d, double corr_ud);
// sigma^2 I: each pixel coordinate independent with the same sigma (the thesis's 5.28).
Eigen::Matrix4d isotropicPixelCovariance(double sigma);
// Throws stereoloc::Error "<where>: ..." unless C is finite, symmetric and positive definite.
void checkPixelCovariance(const Eigen::Matrix4d& C, const std::string& where);

// (5.32) with a full pixel covariance: R = J C J^T, J = d(range, bearing) / d(u_l, v_l, u_r, v_r)
// at the measured pixels (the general form of 5.30, StereoRig::rangeBearing). Throws
// GeometryError when the pixels cannot be triangulated.
Eigen::Matrix2d rangeBearingCovariance(const StereoRig& rig, const StereoPixels& px, double pan,
                                       const Eigen::Matrix4d& pixel_covariance);

}  // namespace stereoloc
