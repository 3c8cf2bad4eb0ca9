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
#include <ceres/autodiff_cost_function.h>

#include <Eigen/Core>

#include "src/core/angles.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

struct RangeBearingCalibrationFactor {
  static constexpr int kCalibrationSize = 4;  // c0, c1, c2, d_b

  RangeBearingCalibrationFactor(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                const Eigen::Matrix2d& sqrt_information_upper)
      : landmark_(landmark), z_(z), S_(sqrt_information_upper) {}

  template <typename T>
  bool operator()(const T* pose, const T* k, T* residual) const {
    const T dx = T(landmark_[0]) - pose[0], dy = T(landmark_[1]) - pose[1];
    if (dx * dx + dy * dy < T(kMinSquaredRange)) return false;
    const T l[2] = {T(landmark_[0]), T(landmark_[1])};
    T h[2];
    predictRangeBearingT(pose, l, h);
    const double b = z_[1];
    const T scale = T(1.0) + k[0] + k[1] * T(b) + k[2] * T(b * b);
    const T e0 = scale * h[0] - T(z_[0]);
    const T e1 = wrapAngle<T>(h[1] + k[3] - T(z_[1]));
    residual[0] = T(S_(0, 0)) * e0 + T(S_(0, 1)) * e1;
    residual[1] = T(S_(1, 1)) * e1;  // S is upper triangular
    return true;
  }

  // landmark (mm), z = (range mm, bearing rad), covariance R of z.
  static ceres::CostFunction* Create(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                     const Eigen::Matrix2d& covariance) {
    return new ceres::AutoDiffCostFunction<RangeBearingCalibrationFactor, 2, 3, kCalibrationSize>(
        new RangeBearingCalibrationFactor(landmark, z, sqrtInformationUpper<2>(covariance, "range-bearing covariance R")));
  }

  static constexpr double kMinSquaredRange = 1e-12;  // mm^2, as in predictRangeBearing

 private:
  Eigen::Vector2d landmark_;
  Eigen::Vector2d z_;
  Eigen::Matrix2d S_;
};

}  // namespace stereoloc
