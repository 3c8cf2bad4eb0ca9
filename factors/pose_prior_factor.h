#pragma once
// Gaussian prior on one pose.
//
//   r = S (p [-] mean)                                                        3 residuals
//
// p, mean: poses (x, y, theta), world frame (mm, mm, rad); [-] wraps the angle difference.
// S: upper square-root information of the 3x3 covariance in (x, y, theta).
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

#include "src/core/angles.h"
#include "src/core/gaussian.h"
#include "src/core/pose2.h"

namespace stereoloc {

class PosePriorFactor final : public ceres::SizedCostFunction<3, 3> {
 public:
  PosePriorFactor(const Pose2& mean, const Eigen::Matrix3d& sqrt_information_upper)
      : mean_(mean), S_(sqrt_information_upper) {}

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const double* p = parameters[0];
    const Eigen::Vector3d e(p[0] - mean_.x, p[1] - mean_.y, wrapAngle(p[2] - mean_.theta));
    Eigen::Map<Eigen::Vector3d> r(residuals);
    r = S_ * e;
    if (jacobians && jacobians[0]) {
      // d(p [-] mean)/dp is the identity (src/core/pose2.h convention), so the Jacobian is S.
      Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> J(jacobians[0]);
      J = S_;
    }
    return true;
  }

  static ceres::CostFunction* Create(const Pose2& mean, const Eigen::Matrix3d& covariance);

 private:
  Pose2 mean_;
  Eigen::Matrix3d S_;
};

}  // namespace stereoloc
