#include "factors/pose_prior_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* PosePriorFactor::Create(const Pose2& mean, const Eigen::Matrix3d& covariance) {
  return new PosePriorFactor(mean, sqrtInformationUpper<3>(covariance, "pose prior covariance"));
}

}  // namespace stereoloc
