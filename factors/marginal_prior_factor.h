#pragma once
// Linear marginalisation prior on N >= 1 poses, the result of a Schur complement.
//
//   r = S (x [-] x0) + r0                                                     3N residuals
//
// x = (p_1, ..., p_N) stacked, each (x, y, theta) in the world frame (mm, mm, rad); x0 the
// linearisation point stored when the prior was made (first-estimate Jacobians: the Jacobian
// is S wherever it is evaluated); [-] subtracts per pose and wraps each angle difference.
// S (3N x 3N, upper triangular) and r0 come from the marginal information H = S^T S and
// gradient g = S^T r0 of the linearised system, so 1/2 |r|^2 = 1/2 |r0|^2 + g^T dx +
// 1/2 dx^T H dx is exactly the quadratic model that the Schur complement left behind.
#include <ceres/cost_function.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <string>
#include <vector>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/pose2.h"

namespace stereoloc {

class MarginalPriorFactor final : public ceres::CostFunction {
 public:
  // S: 3N x 3N square root of the information (upper triangular), r0: 3N residual at x0.
  MarginalPriorFactor(std::vector<Pose2> linearisation_point, const Eigen::MatrixXd& S, const Eigen::VectorXd& r0)
      : x0_(std::move(linearisation_point)), S_(S), r0_(r0) {
    const int n = static_cast<int>(x0_.size());
    if (n < 1 || S_.rows() != 3 * n || S_.cols() != 3 * n || r0_.size() != 3 * n)
      throw Error("marginal prior: S must be 3N x 3N and r0 3N for N >= 1 poses");
    if (!S_.allFinite() || !r0_.allFinite()) throw Error("marginal prior: S or r0 not finite");
    for (int i = 0; i < n; ++i) mutable_parameter_block_sizes()->push_back(3);
    set_num_residuals(3 * n);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
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

  // From the marginal information H (3N x 3N, symmetric positive definite) and gradient g at
  // the linearisation point: S = upper Cholesky factor of H, r0 = S^-T g.
  // Throws stereoloc::Error when H is not positive definite (the marginal is rank deficient).
  static MarginalPriorFactor* FromInformation(std::vector<Pose2> linearisation_point, const Eigen::MatrixXd& H,
                                              const Eigen::VectorXd& g) {
    const Eigen::MatrixXd Hs = 0.5 * (H + H.transpose());
    Eigen::LLT<Eigen::MatrixXd> llt(Hs);
    if (llt.info() != Eigen::Success || !Hs.allFinite())
      throw Error("marginal prior: marginal information is not positive definite (rank deficient)");
    const Eigen::MatrixXd S = llt.matrixU();
    const Eigen::VectorXd r0 = S.transpose().triangularView<Eigen::Lower>().solve(g);
    return new MarginalPriorFactor(std::move(linearisation_point), S, r0);
  }

  const std::vector<Pose2>& linearisationPoint() const { return x0_; }
  const Eigen::MatrixXd& sqrtInformation() const { return S_; }
  const Eigen::VectorXd& r0() const { return r0_; }

 private:
  std::vector<Pose2> x0_;
  Eigen::MatrixXd S_;
  Eigen::VectorXd r0_;
};

}  // namespace stereoloc
