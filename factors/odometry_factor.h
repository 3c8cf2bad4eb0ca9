#pragma once
// Odometry between-factor (thesis appendix B, EKF prediction 5.7/5.9 as a factor).
//
//   r = S (betweenT(p_{k-1}, p_k) [-] u_k)                                     3 residuals
//
// p_{k-1}, p_k: poses (x, y, theta) in the world frame (mm, mm, rad).
// u_k = controlVector(d_l, d_r) (B.4, B.5): the motion of step k expressed in the frame of pose
// k-1 (mm, mm, rad). [-] subtracts componentwise and wraps the angle difference.
// S: upper square-root information of U_k = controlCovariance(d_l, d_r) (B.10, with the
// control variance floor), so |r|^2 is the Mahalanobis distance of the odometry error.
// At p_k = p_{k-1} (+) u_k the residual is zero and its Jacobians are -S J2^-1 J1 and S J2^-1
// (B.18, B.19), which is what makes the Schur complement of this factor the EKF prediction.
#include <ceres/cost_function.h>

#include <Eigen/Core>

#include "src/core/angles.h"
#include "src/core/gaussian.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"

namespace stereoloc {

struct OdometryFactor {
  OdometryFactor(const Eigen::Vector3d& u, const Eigen::Matrix3d& sqrt_information_upper)
      : u_(u), S_(sqrt_information_upper) {}

  template <typename T>
  bool operator()(const T* prev, const T* curr, T* residual) const {
    T rel[3];
    betweenT(prev, curr, rel);
    const T e[3] = {rel[0] - T(u_[0]), rel[1] - T(u_[1]), wrapAngle<T>(rel[2] - T(u_[2]))};
    for (int i = 0; i < 3; ++i) residual[i] = T(S_(i, 0)) * e[0] + T(S_(i, 1)) * e[1] + T(S_(i, 2)) * e[2];
    return true;
  }

  // From a relative pose measurement u (mm, mm, rad) and its covariance U.
  static ceres::CostFunction* Create(const Eigen::Vector3d& u, const Eigen::Matrix3d& covariance);
  // From the wheel increments of one step (mm), with the odometry model of src/core/odometry_model.h.
  static ceres::CostFunction* Create(double d_left, double d_right, const OdometryParams& params);

  const Eigen::Vector3d& u() const { return u_; }

 private:
  Eigen::Vector3d u_;
  Eigen::Matrix3d S_;
};

}  // namespace stereoloc
