#include "factors/range_bearing_calibration_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* RangeBearingCalibrationFactor::Create(const Eigen::Vector2d& landmark, const Eigen::Vector2d& z,
                                                           const Eigen::Matrix2d& covariance) {
  return new ceres::AutoDiffCostFunction<RangeBearingCalibrationFactor, 2, 3, kCalibrationSize>(
      new RangeBearingCalibrationFactor(landmark, z,
                                        sqrtInformationUpper<2>(covariance, "range-bearing covariance R")));
}

}  // namespace stereoloc
