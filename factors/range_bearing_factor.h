#pragma once
// Range-bearing factor to a known landmark (thesis 5.26-5.32 as a factor).
//
//   r = S (h(p, l) [-] z),   h = predictRangeBearingT (5.27)                  2 residuals
//
// p: robot pose (x, y, theta), world frame (mm, mm, rad). l: landmark (x, y), world frame, mm.
// z = (range mm, bearing rad): the observation in the robot frame C0; [-] subtracts the range
// and wraps the bearing difference. S: upper square-root information of R (2x2, mm^2 / rad^2,
// from the stereo model 5.32 or the dataset's sigmas). h is the same function the EKF
// linearises, so the factor and the EKF update share one model. Evaluation fails (returns
// false, Ceres then shrinks the step) when the pose coincides with the landmark, where the
// bearing is undefined.
#include <ceres/cost_function.h>

#include <Eigen/Core>

#include "src/core/angles.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

// Shared by the range-bearing factors (this one, range_bearing_calibration_factor.h).
namespace range_bearing {

constexpr double kMinSquaredRange = 1e-12;  // mm^2, as in predictRangeBearing

// h(p, l) (5.27); false where the pose coincides with the landmark (the bearing is undefined).
template <typename T>
bool predict(const T* pose, const Eigen::Vector2d& landmark, T* h) {
  const T dx = T(landmark[0]) - pose[0], dy = T(landmark[1]) - pose[1];
  if (dx * dx + dy * dy < T(kMinSquaredRange)) return false;
  const T l[2] = {T(landmark[0]), T(landmark[1])};
  predictRangeBearingT(pose, l, h);
  return true;
}

// r = S e for the upper-triangular square-root information S of (range, bearing).
template <typename T>
void whiten(const Eigen::Matrix2d& S, const T& e_range, const T& e_bearing, T* r) {
  r[0] = T(S(0, 0)) * e_range + T(S(0, 1)) * e_bearing;
  r[1] = T(S(1, 1)) * e_bearing;
}

}  // namespace range_bearing

struct RangeBearingFactor {
  RangeBearingFactor(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                     const Eigen::Matrix2d& sqrt_information_upper)
      : landmark_(landmark), z_(z), S_(sqrt_information_upper) {}

  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    T h[2];
    if (!range_bearing::predict(pose, landmark_, h)) return false;
    range_bearing::whiten(S_, h[0] - T(z_[0]), wrapAngle<T>(h[1] - T(z_[1])), residual);
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
