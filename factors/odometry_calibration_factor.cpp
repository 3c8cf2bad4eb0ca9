#include "factors/odometry_calibration_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* OdometryCalibrationFactor::Create(double m_left, double m_right,
                                                       const WheelIncrements& noise_travel,
                                                       const OdometryParams& params) {
  params.validate();
  Eigen::Matrix2d S = wheelCovariance(noise_travel.d_left, noise_travel.d_right, params);
  const double fx = params.control_variance_floor.x();
  const double ft = params.control_variance_floor.z() * 0.25 * params.wheel_base_mm * params.wheel_base_mm;
  S += fx * Eigen::Matrix2d::Ones();
  S += ft * (Eigen::Matrix2d() << 1.0, -1.0, -1.0, 1.0).finished();
  const double lat = params.control_variance_floor.y();
  if (!(std::isfinite(m_left) && std::isfinite(m_right) && std::isfinite(noise_travel.d_left) &&
        std::isfinite(noise_travel.d_right) && S(0, 0) > 0 && S(1, 1) > 0 &&
        S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0) > 0 && lat > 0))
    throw Error(
        "odometry calibration factor: readings and noise travel must be finite, the wheel covariance positive "
        "definite and the lateral floor positive");
  return new ceres::AutoDiffCostFunction<OdometryCalibrationFactor, 3, 3, 3, 3>(new OdometryCalibrationFactor(
      m_left, m_right, sqrtInformationUpper<2>(S, "odometry calibration factor: wheel covariance"), std::sqrt(lat)));
}

}  // namespace stereoloc
