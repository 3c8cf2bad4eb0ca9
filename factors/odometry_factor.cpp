#include "factors/odometry_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* OdometryFactor::Create(const Eigen::Vector3d& u, const Eigen::Matrix3d& covariance) {
  return new ceres::AutoDiffCostFunction<OdometryFactor, 3, 3, 3>(
      new OdometryFactor(u, sqrtInformationUpper<3>(covariance, "odometry covariance U")));
}

ceres::CostFunction* OdometryFactor::Create(double d_left, double d_right, const OdometryParams& params) {
  return Create(controlVector(d_left, d_right, params.wheel_base_mm), controlCovariance(d_left, d_right, params));
}

}  // namespace stereoloc
