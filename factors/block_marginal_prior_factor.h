#pragma once
// Linear marginalisation prior on poses and Euclidean blocks: the sliding window's marginal
// prior when it also spans the self-calibration blocks (solvers/self_calibration.h), which are
// never marginalised, so the calibration's information from the marginalised poses is carried.
//
//   r = S (x [-] x0) + r0                                      sum of the block sizes residuals
//
// x = (b_1, ..., b_N) stacked; a pose block is (x, y, theta) in the world frame (mm, mm, rad) and
// [-] wraps its angle difference; any other block (the calibration: wheel scales and wheel base,
// tilt correction and baseline scale, in the units of factors/odometry_calibration_factor.h and
// factors/stereo_pixel_calibration_factor.h) is a plain difference. x0: the linearisation point
// stored when the prior was made (first-estimate Jacobians: the Jacobian is S wherever it is
// evaluated). S (upper triangular, or the eigen square root of a singular H: FromInformation) and r0 come from the marginal information H = S^T S and
// gradient g = S^T r0, as in factors/marginal_prior_factor.h, which is this factor on poses only.
#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <vector>

#include "src/core/angles.h"
#include "src/core/error.h"

namespace stereoloc {

class BlockMarginalPriorFactor final : public ceres::CostFunction {
 public:
  struct Block {
    Eigen::VectorXd x0;  // the linearisation point of this block
    bool pose = false;   // true: (x, y, theta), the angle difference is wrapped
  };

  // S: square root of the information (upper triangular), r0: the residual at x0; both sized by
  // the sum of the block sizes. Throws stereoloc::Error on mismatched sizes or non-finite input.
  BlockMarginalPriorFactor(std::vector<Block> blocks, const Eigen::MatrixXd& S, const Eigen::VectorXd& r0);

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // From the marginal information H (symmetric positive semi-definite) and gradient g at the
  // linearisation point: S = upper Cholesky factor of H, r0 = S^-T g. A calibration block that
  // the marginalised factors hardly see (the tilt, from one pose's pixels) leaves H singular in
  // its direction; then S = Lambda^1/2 V^T from H = V Lambda V^T, with the eigenvalues below
  // 1e-12 of the largest set to zero (no information there; g lies in the range of H for a
  // Schur complement). Throws stereoloc::Error when H is not finite or has a negative
  // eigenvalue beyond rounding.
  static BlockMarginalPriorFactor* FromInformation(std::vector<Block> blocks, const Eigen::MatrixXd& H,
                                                   const Eigen::VectorXd& g);

  const std::vector<Block>& blocks() const { return blocks_; }
  const Eigen::MatrixXd& sqrtInformation() const { return S_; }
  const Eigen::VectorXd& r0() const { return r0_; }

 private:
  std::vector<Block> blocks_;
  std::vector<int> offsets_;
  Eigen::MatrixXd S_;
  Eigen::VectorXd r0_;
};

}  // namespace stereoloc
