#include "factors/block_marginal_prior_factor.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <cmath>
#include <utility>

namespace stereoloc {

BlockMarginalPriorFactor::BlockMarginalPriorFactor(std::vector<Block> blocks, const Eigen::MatrixXd& S,
                                                   const Eigen::VectorXd& r0)
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

bool BlockMarginalPriorFactor::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
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

BlockMarginalPriorFactor* BlockMarginalPriorFactor::FromInformation(std::vector<Block> blocks, const Eigen::MatrixXd& H,
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

}  // namespace stereoloc
