#include "factors/range_bearing_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* RangeBearingFactor::Create(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                                const Eigen::Matrix2d& covariance) {
  return new ceres::AutoDiffCostFunction<RangeBearingFactor, 2, 3>(
      new RangeBearingFactor(landmark, z, sqrtInformationUpper<2>(covariance, "range-bearing covariance R")));
}

}  // namespace stereoloc
