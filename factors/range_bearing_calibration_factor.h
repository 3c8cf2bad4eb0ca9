#pragma once
// Range-bearing factor with the sensor's own calibration as a parameter block: a range sensor
// whose scale depends on where the landmark is in its field of view (a camera reading range
// from a target's apparent size through a lens that shrinks the image's edges: MR.CLAM's
// barcode camera, docs/results.md), and whose bearings are offset.
//
//   r = S ( (1 + c0 + c1 b + c2 b^2) h_r(p, l) - z_r ,  wrap(h_b(p, l) + d_b - z_b) )   2 residuals
//
// p: robot pose (x, y, theta), world frame (mm, mm, rad). l: landmark (x, y), world frame, mm.
// z = (range mm, bearing rad) in the robot frame; b = z_b, the measured bearing (a constant of
// the factor: the scale is a function of where the sensor saw the landmark). h: (5.27), as
// RangeBearingFactor. k = (c0, c1 [1/rad], c2 [1/rad^2], d_b [rad]): the range factor's
// coefficients (those of `import mrclam --range-correction`, which divides a range by the same
// factor) and the bearing offset; nominal 0. S: upper square-root information of R.
// Evaluation fails when the pose coincides with the landmark (bearing undefined).
#include <ceres/cost_function.h>

#include <Eigen/Core>

#include "factors/range_bearing_factor.h"
#include "src/core/angles.h"
#include "src/core/gaussian.h"

namespace stereoloc {

struct RangeBearingCalibrationFactor {
  static constexpr int kCalibrationSize = 4;  // c0, c1, c2, d_b

  RangeBearingCalibrationFactor(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                const Eigen::Matrix2d& sqrt_information_upper)
      : landmark_(landmark), z_(z), S_(sqrt_information_upper) {}

  template <typename T>
  bool operator()(const T* pose, const T* k, T* residual) const {
    T h[2];
    if (!range_bearing::predict(pose, landmark_, h)) return false;
    const T f = rangeFactorAt(k, z_[1]);
    range_bearing::whiten(S_, f * h[0] - T(z_[0]), wrapAngle<T>(h[1] + k[3] - T(z_[1])), residual);
    return true;
  }

  // landmark (mm), z = (range mm, bearing rad), covariance R of z.
  static ceres::CostFunction* Create(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                     const Eigen::Matrix2d& covariance);

 private:
  Eigen::Vector2d landmark_;
  Eigen::Vector2d z_;
  Eigen::Matrix2d S_;
};

}  // namespace stereoloc
