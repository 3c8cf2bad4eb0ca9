#include "factors/calibration_prior_factor.h"

namespace stereoloc {

DiagonalPriorFactor::DiagonalPriorFactor(const Eigen::VectorXd& mean, const Eigen::VectorXd& sigma)
    : mean_(mean), inverse_sigma_(sigma.cwiseInverse()) {
  if (!(sigma.size() == mean_.size() && sigma.allFinite() && sigma.minCoeff() > 0))
    throw Error("calibration prior: one finite sigma > 0 per entry");
  set_num_residuals(static_cast<int>(mean_.size()));
  mutable_parameter_block_sizes()->push_back(static_cast<int32_t>(mean_.size()));
}

bool DiagonalPriorFactor::Evaluate(double const* const* p, double* r, double** J) const {
  const Eigen::Index n = mean_.size();
  Eigen::Map<Eigen::VectorXd>(r, n) = inverse_sigma_.cwiseProduct(Eigen::Map<const Eigen::VectorXd>(p[0], n) - mean_);
  if (J && J[0]) {
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> J_r_c(J[0], n, n);
    J_r_c = inverse_sigma_.asDiagonal();
  }
  return true;
}

DensePriorFactor::DensePriorFactor(const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance) : mean_(mean) {
  if (covariance.rows() != mean_.size() || covariance.cols() != mean_.size())
    throw Error("calibration prior: covariance of the mean's size needed");
  S_ = sqrtInformationUpper<Eigen::Dynamic>(covariance, "calibration prior covariance");
  set_num_residuals(static_cast<int>(mean_.size()));
  mutable_parameter_block_sizes()->push_back(static_cast<int32_t>(mean_.size()));
}

bool DensePriorFactor::Evaluate(double const* const* p, double* r, double** J) const {
  const Eigen::Index n = mean_.size();
  Eigen::Map<Eigen::VectorXd>(r, n) = S_ * (Eigen::Map<const Eigen::VectorXd>(p[0], n) - mean_);
  if (J && J[0]) Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(J[0], n, n) = S_;
  return true;
}

}  // namespace stereoloc
