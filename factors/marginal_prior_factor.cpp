#include "factors/marginal_prior_factor.h"

#include <Eigen/Cholesky>
#include <utility>

namespace stereoloc {

MarginalPriorFactor::MarginalPriorFactor(std::vector<Pose2> linearisation_point, const Eigen::MatrixXd& S,
                                         const Eigen::VectorXd& r0)
    : x0_(std::move(linearisation_point)), S_(S), r0_(r0) {
  const int n = static_cast<int>(x0_.size());
  if (n < 1 || S_.rows() != 3 * n || S_.cols() != 3 * n || r0_.size() != 3 * n)
    throw Error("marginal prior: S must be 3N x 3N and r0 3N for N >= 1 poses");
  if (!S_.allFinite() || !r0_.allFinite()) throw Error("marginal prior: S or r0 not finite");
  for (int i = 0; i < n; ++i) mutable_parameter_block_sizes()->push_back(3);
  set_num_residuals(3 * n);
}

bool MarginalPriorFactor::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int n = static_cast<int>(x0_.size());
  Eigen::VectorXd dx(3 * n);
  for (int i = 0; i < n; ++i) {
    const double* p = parameters[i];
    dx.segment<3>(3 * i) << p[0] - x0_[i].x, p[1] - x0_[i].y, wrapAngle(p[2] - x0_[i].theta);
  }
  Eigen::Map<Eigen::VectorXd> r(residuals, 3 * n);
  r = S_ * dx + r0_;
  if (jacobians) {
    for (int i = 0; i < n; ++i) {
      if (!jacobians[i]) continue;
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>> J(jacobians[i], 3 * n, 3);
      J = S_.middleCols<3>(3 * i);
    }
  }
  return true;
}

MarginalPriorFactor* MarginalPriorFactor::FromInformation(std::vector<Pose2> linearisation_point,
                                                          const Eigen::MatrixXd& H, const Eigen::VectorXd& g) {
  const Eigen::MatrixXd Hs = 0.5 * (H + H.transpose());
  Eigen::LLT<Eigen::MatrixXd> llt(Hs);
  if (llt.info() != Eigen::Success || !Hs.allFinite())
    throw Error("marginal prior: marginal information is not positive definite (rank deficient)");
  const Eigen::MatrixXd S = llt.matrixU();
  const Eigen::VectorXd r0 = S.transpose().triangularView<Eigen::Lower>().solve(g);
  return new MarginalPriorFactor(std::move(linearisation_point), S, r0);
}

}  // namespace stereoloc
