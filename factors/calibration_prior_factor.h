#pragma once
// Gaussian prior on a calibration parameter block (self-calibration): what the user's
// calibration says, with its stated uncertainty.
//
//   r = S (c - c0)                                                         N residuals
//
// c: the block (units of its owner: odometry_calibration_factor.h, stereo_pixel_calibration_factor.h);
// c0: the prior mean; S: upper square-root information of the N x N prior covariance. No angle
// wraps: calibration angles are small corrections.
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

#include "src/core/gaussian.h"

namespace stereoloc {

template <int N>
class CalibrationPriorFactor final : public ceres::SizedCostFunction<N, N> {
 public:
  using VectorN = Eigen::Matrix<double, N, 1>;
  using MatrixN = Eigen::Matrix<double, N, N>;

  CalibrationPriorFactor(const VectorN& mean, const MatrixN& sqrt_information_upper)
      : mean_(mean), S_(sqrt_information_upper) {}

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const Eigen::Map<const VectorN> c(parameters[0]);
    Eigen::Map<VectorN> r(residuals);
    r = S_ * (c - mean_);
    if (jacobians && jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, N, N, Eigen::RowMajor>> J_r_c(jacobians[0]);
      J_r_c = S_;
    }
    return true;
  }

  static ceres::CostFunction* Create(const VectorN& mean, const MatrixN& covariance) {
    return new CalibrationPriorFactor(mean, sqrtInformationUpper<N>(covariance, "calibration prior covariance"));
  }

 private:
  VectorN mean_;
  MatrixN S_;
};

}  // namespace stereoloc
