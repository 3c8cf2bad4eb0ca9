#pragma once
// Gaussian prior on a calibration parameter block (self-calibration): what the user's
// calibration says, with its stated uncertainty.
//
//   r = S (c - c0)                                                         N residuals
//
// c: the block (units of its owner: odometry_calibration_factor.h, stereo_pixel_calibration_factor.h);
// c0: the prior mean; S: upper square-root information of the N x N prior covariance. No angle
// wraps: calibration angles are small corrections.
#include <ceres/cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <utility>

#include "src/core/error.h"
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

// The same with independent entries, of any size: r_i = (c_i - mean_i) / sigma_i (the batch's
// joined stereo block, whose size depends on the map's features).
class DiagonalPriorFactor final : public ceres::CostFunction {
 public:
  // Throws Error unless there is one finite sigma > 0 per entry.
  DiagonalPriorFactor(const Eigen::VectorXd& mean, const Eigen::VectorXd& sigma);
  bool Evaluate(double const* const* p, double* r, double** J) const override;

 private:
  Eigen::VectorXd mean_, inverse_sigma_;
};

// The same with a full covariance, of any size: r = S (c - mean), S the upper square-root
// information (the batch's joined stereo block when the field block's prior is a measured
// field's covariance, whose dimensions are correlated).
class DensePriorFactor final : public ceres::CostFunction {
 public:
  // Throws Error unless `covariance` is finite, symmetric and positive definite and of mean's size.
  DensePriorFactor(const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance);
  bool Evaluate(double const* const* p, double* r, double** J) const override;

 private:
  Eigen::VectorXd mean_;
  Eigen::MatrixXd S_;
};

}  // namespace stereoloc
