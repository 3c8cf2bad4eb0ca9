#pragma once
// Odometry between-factor with the wheel calibration as parameters (self-calibration, thesis
// appendix B with the wheel scales and the wheel base unknown).
//
//   r = S (betweenT(p_{k-1}, p_k) [-] u(c_l d_l, c_r d_r, w))                   3 residuals
//
// p_{k-1}, p_k: poses (x, y, theta), world frame (mm, mm, rad). c = (c_l, c_r, w): calibration
// block, c_l and c_r the true distance per mm of encoder reading of each wheel (dimensionless,
// nominally 1; a wheel whose true radius is r (1 + e) has c = 1 + e), w the effective wheel base
// (mm). d_l, d_r: the encoder readings of step k (mm). u: (B.4), (B.5) with alpha = (B.1) and
// v = (B.2) of the corrected increments, evaluated with the series of src/core/odometry_model.h
// near alpha = 0 so that it stays smooth on straight lines. [-] wraps the angle difference.
// S: upper square-root information of U_k = controlCovariance(d_l, d_r) (B.10) at the nominal
// calibration; a 1 % change of c changes U by about 2 %, which the weighting need not follow.
// With c = (1, 1, w_nominal) this is OdometryFactor (factors/odometry_factor.h).
#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>
#include <cmath>

#include "src/core/angles.h"
#include "src/core/gaussian.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"

namespace stereoloc {

// (B.4), (B.5): the control vector of wheel increments d_l, d_r (mm) and wheel base w (mm),
// templated for Ceres. sin(a)/a and (1 - cos a)/a use their Taylor series for |a| < 1e-3
// (error < 1e-16 relative).
template <typename T>
void controlVectorT(const T& d_left, const T& d_right, const T& wheel_base, T* u) {
  using std::cos;
  using std::sin;
  const T alpha = (d_right - d_left) / wheel_base;  // (B.1)
  const T v = 0.5 * (d_right + d_left);             // (B.2)
  T sinc, cosc;                                     // sin(a)/a, (1 - cos a)/a
  using std::abs;
  if (abs(alpha) < T(1e-3)) {  // compares the value part of a Jet
    const T a2 = alpha * alpha;
    sinc = T(1.0) - a2 / 6.0 + a2 * a2 / 120.0;
    cosc = alpha * (T(0.5) - a2 / 24.0 + a2 * a2 / 720.0);
  } else {
    sinc = sin(alpha) / alpha;
    cosc = (T(1.0) - cos(alpha)) / alpha;
  }
  u[0] = v * sinc;
  u[1] = v * cosc;
  u[2] = alpha;
}

struct OdometryCalibrationFactor {
  OdometryCalibrationFactor(double d_left, double d_right, const Eigen::Matrix3d& sqrt_information_upper)
      : d_left_(d_left), d_right_(d_right), S_(sqrt_information_upper) {}

  template <typename T>
  bool operator()(const T* prev, const T* curr, const T* calib, T* residual) const {
    if (!(calib[2] > T(0.0))) return false;  // a wheel base must stay positive
    T rel[3], u[3];
    betweenT(prev, curr, rel);
    controlVectorT(calib[0] * T(d_left_), calib[1] * T(d_right_), calib[2], u);
    const T e[3] = {rel[0] - u[0], rel[1] - u[1], wrapAngle<T>(rel[2] - u[2])};
    for (int i = 0; i < 3; ++i) residual[i] = T(S_(i, 0)) * e[0] + T(S_(i, 1)) * e[1] + T(S_(i, 2)) * e[2];
    return true;
  }

  // Blocks: previous pose (3), current pose (3), calibration (c_l, c_r, w) (3).
  static ceres::CostFunction* Create(double d_left, double d_right, const OdometryParams& params) {
    return new ceres::AutoDiffCostFunction<OdometryCalibrationFactor, 3, 3, 3, 3>(new OdometryCalibrationFactor(
        d_left, d_right, sqrtInformationUpper<3>(controlCovariance(d_left, d_right, params), "odometry covariance U")));
  }

 private:
  double d_left_, d_right_;
  Eigen::Matrix3d S_;
};

}  // namespace stereoloc
