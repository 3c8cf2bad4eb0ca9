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

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
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
  BlockMarginalPriorFactor(std::vector<Block> blocks, const Eigen::MatrixXd& S, const Eigen::VectorXd& r0)
      : blocks_(std::move(blocks)), S_(S), r0_(r0) {
    int dim = 0;
    for (const Block& b : blocks_) {
      if (b.x0.size() < 1 || (b.pose && b.x0.size() != 3) || !b.x0.allFinite())
        throw Error("block marginal prior: a block is empty, a pose block not of size 3, or x0 not finite");
      offsets_.push_back(dim);
      dim += static_cast<int>(b.x0.size());
      mutable_parameter_block_sizes()->push_back(static_cast<int>(b.x0.size()));
    }
    if (blocks_.empty() || S_.rows() != dim || S_.cols() != dim || r0_.size() != dim)
      throw Error("block marginal prior: S must be D x D and r0 D for the D parameters of N >= 1 blocks");
    if (!S_.allFinite() || !r0_.allFinite()) throw Error("block marginal prior: S or r0 not finite");
    set_num_residuals(dim);
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const int dim = static_cast<int>(r0_.size());
    Eigen::VectorXd dx(dim);
    for (size_t i = 0; i < blocks_.size(); ++i) {
      const Block& b = blocks_[i];
      for (int j = 0; j < b.x0.size(); ++j) dx(offsets_[i] + j) = parameters[i][j] - b.x0(j);
      if (b.pose) dx(offsets_[i] + 2) = wrapAngle(dx(offsets_[i] + 2));
    }
    Eigen::Map<Eigen::VectorXd> r(residuals, dim);
    r = S_ * dx + r0_;
    if (jacobians) {
      for (size_t i = 0; i < blocks_.size(); ++i) {
        if (!jacobians[i]) continue;
        const int n = static_cast<int>(blocks_[i].x0.size());
        Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> J_r_b(jacobians[i], dim, n);
        J_r_b = S_.middleCols(offsets_[i], n);
      }
    }
    return true;
  }

  // From the marginal information H (symmetric positive semi-definite) and gradient g at the
  // linearisation point: S = upper Cholesky factor of H, r0 = S^-T g. A calibration block that
  // the marginalised factors hardly see (the tilt, from one pose's pixels) leaves H singular in
  // its direction; then S = Lambda^1/2 V^T from H = V Lambda V^T, with the eigenvalues below
  // 1e-12 of the largest set to zero (no information there; g lies in the range of H for a
  // Schur complement). Throws stereoloc::Error when H is not finite or has a negative
  // eigenvalue beyond rounding.
  static BlockMarginalPriorFactor* FromInformation(std::vector<Block> blocks, const Eigen::MatrixXd& H,
                                                   const Eigen::VectorXd& g) {
    const Eigen::MatrixXd Hs = 0.5 * (H + H.transpose());
    if (!Hs.allFinite() || !g.allFinite()) throw Error("block marginal prior: information or gradient not finite");
    Eigen::LLT<Eigen::MatrixXd> llt(Hs);
    if (llt.info() == Eigen::Success) {
      const Eigen::MatrixXd S = llt.matrixU();
      const Eigen::VectorXd r0 = S.transpose().triangularView<Eigen::Lower>().solve(g);
      return new BlockMarginalPriorFactor(std::move(blocks), S, r0);
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(Hs);
    const Eigen::VectorXd& l = eig.eigenvalues();  // ascending
    const double top = l(l.size() - 1);
    const double floor = 1e-12 * top;
    if (!(top > 0) || l(0) < -1e-9 * top)
      throw Error("block marginal prior: marginal information is not positive semi-definite");
    Eigen::VectorXd root = Eigen::VectorXd::Zero(l.size()), inv_root = Eigen::VectorXd::Zero(l.size());
    for (int i = 0; i < l.size(); ++i)
      if (l(i) > floor) {
        root(i) = std::sqrt(l(i));
        inv_root(i) = 1.0 / root(i);
      }
    const Eigen::MatrixXd S = root.asDiagonal() * eig.eigenvectors().transpose();
    const Eigen::VectorXd r0 = inv_root.asDiagonal() * (eig.eigenvectors().transpose() * g);
    return new BlockMarginalPriorFactor(std::move(blocks), S, r0);
  }

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
