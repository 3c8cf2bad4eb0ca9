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
  MarginalPriorFactor(std::vector<Pose2> linearisation_point, const Eigen::MatrixXd& S, const Eigen::VectorXd& r0);

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // From the marginal information H (3N x 3N, symmetric positive definite) and gradient g at
  // the linearisation point: S = upper Cholesky factor of H, r0 = S^-T g.
  // Throws stereoloc::Error when H is not positive definite (the marginal is rank deficient).
  static MarginalPriorFactor* FromInformation(std::vector<Pose2> linearisation_point, const Eigen::MatrixXd& H,
                                              const Eigen::VectorXd& g);

  const std::vector<Pose2>& linearisationPoint() const { return x0_; }
  const Eigen::MatrixXd& sqrtInformation() const { return S_; }
  const Eigen::VectorXd& r0() const { return r0_; }

 private:
  std::vector<Pose2> x0_;
  Eigen::MatrixXd S_;
  Eigen::VectorXd r0_;
};

}  // namespace stereoloc
