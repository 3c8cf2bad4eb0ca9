// The sliding window's marginalisation, solve and covariances (solvers/sliding_window_smoother.h;
// derivations: docs/estimators.md, "Smoothers").
#include "solvers/sliding_window_smoother.h"

#include <ceres/solver.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <vector>

#include "factors/block_marginal_prior_factor.h"
#include "factors/marginal_prior_factor.h"
#include "solvers/sliding_window_detail.h"
#include "src/core/error.h"

namespace stereoloc {
namespace {

// accumulateNormalEquations (solvers/smoother_common.h) for blocks of any size: `pose` marks the
// (x, y, theta) blocks, whose angle difference is wrapped; the others are Euclidean.
bool accumulateBlocks(const ceres::CostFunction& cost, const std::vector<const double*>& current,
                      const std::vector<const double*>& linearisation, const std::vector<int>& offsets,
                      const std::vector<bool>& pose, Eigen::MatrixXd& H, Eigen::VectorXd& g) {
  using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const int m = cost.num_residuals();
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  const size_t nb = sizes.size();
  Eigen::VectorXd r(m);
  std::vector<RowMajor> J(nb);
  std::vector<double*> jp(nb);
  for (size_t i = 0; i < nb; ++i) {
    J[i].resize(m, sizes[i]);
    jp[i] = J[i].data();
  }
  if (!cost.Evaluate(linearisation.data(), r.data(), jp.data()) || !r.allFinite()) return false;
  for (size_t i = 0; i < nb; ++i) {
    if (!J[i].allFinite()) return false;
    if (current[i] == linearisation[i]) continue;
    Eigen::VectorXd d(sizes[i]);
    for (int j = 0; j < sizes[i]; ++j) d(j) = current[i][j] - linearisation[i][j];
    if (pose[i]) d(2) = wrapAngle(d(2));
    r += J[i] * d;
  }
  for (size_t i = 0; i < nb; ++i) {
    g.segment(offsets[i], sizes[i]) += J[i].transpose() * r;
    for (size_t j = 0; j < nb; ++j) H.block(offsets[i], offsets[j], sizes[i], sizes[j]) += J[i].transpose() * J[j];
  }
  return true;
}

}  // namespace

using window_detail::poseOf;

bool SlidingWindowSmoother::accumulate(const Factor& f, const std::vector<const double*>& cur,
                                       const std::vector<const double*>& lin, const std::vector<int>& off,
                                       Eigen::MatrixXd& H, Eigen::VectorXd& g) const {
  std::vector<bool> pose;
  if (!f.calib.empty()) {
    pose.assign(f.nodes.size(), true);
    pose.resize(f.nodes.size() + f.calib.size(), false);
  }
  auto normal = [&](Eigen::MatrixXd& Ht, Eigen::VectorXd& gt) {
    return f.calib.empty() ? accumulateNormalEquations(*f.cost, cur, lin, off, Ht, gt)
                           : accumulateBlocks(*f.cost, cur, lin, off, pose, Ht, gt);
  };
  if (!f.robust) return normal(H, g);
  // IRLS weight rho'(|r|^2) at the current estimate.
  Eigen::VectorXd r(f.cost->num_residuals());
  if (!f.cost->Evaluate(cur.data(), r.data(), nullptr) || !r.allFinite()) return false;
  double rho[3];
  loss_->Evaluate(r.squaredNorm(), rho);
  const double w = std::max(rho[1], 0.0);
  Eigen::MatrixXd Hf = Eigen::MatrixXd::Zero(H.rows(), H.cols());
  Eigen::VectorXd gf = Eigen::VectorXd::Zero(g.size());
  if (!normal(Hf, gf)) return false;
  H += w * Hf;
  g += w * gf;
  return true;
}

// The normal equations of the factors touching pose o, over o (first), the poses they link it
// to and the calibration blocks they see.
SlidingWindowSmoother::Neighbourhood SlidingWindowSmoother::neighbourhoodOf(Node* o) const {
  Neighbourhood nb;
  nb.vars = {o};
  // A drifting wheel calibration's own prior joins the first marginalisation, so that its
  // information ages with the rest (marginaliseOldest).
  const bool drift = wheels_block_ >= 0 && config_.observation_model.unmodelled.wheelsDrift();
  for (size_t i = 0; i < factors_.size(); ++i) {
    const Factor& f = *factors_[i];
    const bool wheel_prior =
        drift && f.nodes.empty() && std::find(f.calib.begin(), f.calib.end(), wheels_block_) != f.calib.end();
    if (!wheel_prior && std::find(f.nodes.begin(), f.nodes.end(), o) == f.nodes.end()) continue;
    nb.touching.push_back(i);
    for (Node* n : f.nodes)
      if (std::find(nb.vars.begin(), nb.vars.end(), n) == nb.vars.end()) nb.vars.push_back(n);
  }
  // The calibration blocks the marginalised factors see stay in the prior (wheels, then head).
  for (Calib c : calibBlocks())
    for (size_t i : nb.touching)
      if (std::find(factors_[i]->calib.begin(), factors_[i]->calib.end(), c) != factors_[i]->calib.end()) {
        nb.calib.push_back(c);
        break;
      }
  int dim = 3 * static_cast<int>(nb.vars.size());
  std::vector<int> calib_off;
  for (Calib c : nb.calib) {
    calib_off.push_back(dim);
    dim += calibSize(c);
  }
  nb.H = Eigen::MatrixXd::Zero(dim, dim);
  nb.g = Eigen::VectorXd::Zero(dim);
  for (size_t i : nb.touching) {
    const Factor& f = *factors_[i];
    std::vector<const double*> cur, lin;
    std::vector<int> off;
    for (size_t j = 0; j < f.nodes.size(); ++j) {
      cur.push_back(f.nodes[j]->x.data());
      lin.push_back(linearisationPoint(f, j));
      off.push_back(3 * static_cast<int>(std::find(nb.vars.begin(), nb.vars.end(), f.nodes[j]) - nb.vars.begin()));
    }
    for (size_t j = 0; j < f.calib.size(); ++j) {
      const double* c = calibData(f.calib[j]);
      cur.push_back(c);
      lin.push_back(c);
      off.push_back(calib_off[static_cast<size_t>(std::find(nb.calib.begin(), nb.calib.end(), f.calib[j]) - nb.calib.begin())]);
    }
    if (!accumulate(f, cur, lin, off, nb.H, nb.g))
      throw Error("sliding window: step " + std::to_string(o->step) + ": a factor cannot be linearised for marginalisation");
  }
  return nb;
}

void SlidingWindowSmoother::marginaliseOldest() {
  Node* o = nodes_.front().get();
  const Neighbourhood nb = neighbourhoodOf(o);
  // The Schur complement of o in nb's normal equations: a prior on the rest, linearised here.
  ceres::CostFunction* prior = nullptr;
  std::vector<Node*> kept(nb.vars.begin() + 1, nb.vars.end());
  if (!kept.empty() || !nb.calib.empty()) {
    Eigen::MatrixXd Hm;
    Eigen::VectorXd gm;
    schurComplement(nb.H, nb.g, 3, &Hm, &gm);
    ageWheelInformation(nb, *o, Hm, gm);
    if (nb.calib.empty()) {
      std::vector<Pose2> x0;
      for (Node* n : kept) x0.push_back(poseOf(n->x));
      prior = MarginalPriorFactor::FromInformation(x0, Hm, gm);
    } else {
      std::vector<BlockMarginalPriorFactor::Block> blocks;
      for (Node* n : kept) blocks.push_back({Eigen::Vector3d(n->x[0], n->x[1], n->x[2]), true});
      for (Calib c : nb.calib) blocks.push_back({Eigen::Map<const Eigen::VectorXd>(calibData(c), calibSize(c)), false});
      prior = BlockMarginalPriorFactor::FromInformation(blocks, Hm, gm);
    }
  }
  pushHistory(estimateOf(*o));
  pushIntermediates(*o, nodes_.size() > 1 ? nodes_[1].get() : nullptr);
  for (size_t k = nb.touching.size(); k-- > 0;) removeFactor(nb.touching[k]);
  problem_->RemoveParameterBlock(o->x.data());
  nodes_.pop_front();
  if (prior) {
    addFactor(prior, kept, false, nb.calib);  // linearisation point == the prior's x0
    // The prior fixed these poses' linearisation: their other factors must use the same point,
    // or the window would count information along directions the prior linearised differently.
    for (Node* n : kept)
      if (!n->prior_point) n->prior_point = n->x;
  }
  ++stats_.marginalisations;
}

void SlidingWindowSmoother::ageWheelInformation(const Neighbourhood& nb, const Node& o, Eigen::MatrixXd& Hm,
                                                Eigen::VectorXd& gm) const {
  const UnmodelledNoise& noise = config_.observation_model.unmodelled;
  const auto wheels = std::find(nb.calib.begin(), nb.calib.end(), wheels_block_);
  if (!noise.wheelsDrift() || wheels == nb.calib.end() || nodes_.size() < 2) return;
  // The prior speaks of the wheels at o; the window's factors of the wheels from the next pose
  // on (one block, constant over the window): the walk over the travel in between.
  double travel_left = std::fabs(nodes_[1]->d_left), travel_right = std::fabs(nodes_[1]->d_right);
  for (const Intermediate& m : o.after) {
    travel_left += std::fabs(m.d_left);
    travel_right += std::fabs(m.d_right);
  }
  int offset = 3 * (static_cast<int>(nb.vars.size()) - 1);
  for (auto c = nb.calib.begin(); c != wheels; ++c) offset += calibSize(*c);
  addRandomWalk(Hm, gm, offset, wheelDriftVariance(noise, travel_left, travel_right, odometry_.wheel_base_mm));
}

void SlidingWindowSmoother::solve(int max_iterations) {
  ceres::Solver::Options opts;
  if (config_.sparse_solver) {
    opts.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    opts.sparse_linear_algebra_library_type = ceres::SUITE_SPARSE;
  } else {
    opts.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  }
  opts.minimizer_type = ceres::TRUST_REGION;
  opts.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  opts.max_num_iterations = max_iterations;
  if (config_.max_solver_seconds > 0) opts.max_solver_time_in_seconds = config_.max_solver_seconds;
  opts.function_tolerance = config_.function_tolerance;
  opts.gradient_tolerance = config_.gradient_tolerance;
  opts.parameter_tolerance = config_.parameter_tolerance;
  opts.num_threads = 1;
  opts.logging_type = ceres::SILENT;
  opts.minimizer_progress_to_stdout = false;
  if (config_.gauss_newton) {
    // LM adds diag(J^T J) / radius: with radius 1e16 the step is the Gauss-Newton step to
    // machine precision.
    opts.initial_trust_region_radius = 1e16;
    opts.max_trust_region_radius = 1e16;
  }
  if (image_sigmas_) {
    if (image_free_)
      problem_->SetParameterBlockVariable(image_.data());
    else
      problem_->SetParameterBlockConstant(image_.data());
  }
  ceres::Solver::Summary summary;
  ceres::Solve(opts, problem_.get(), &summary);
  if (!summary.IsSolutionUsable()) throw Error("sliding window: Ceres failed: " + summary.message);
  stats_.solver_iterations += static_cast<long>(summary.iterations.size()) - 1;
}

Eigen::MatrixXd SlidingWindowSmoother::windowInformation() {
  const int n = static_cast<int>(nodes_.size());
  for (int i = 0; i < n; ++i) nodes_[static_cast<size_t>(i)]->slot = i;
  const int dim = 3 * n + calibDim();
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(dim, dim);
  Eigen::VectorXd g = Eigen::VectorXd::Zero(dim);
  std::vector<const double*> cur, lin;
  std::vector<int> off;
  for (const auto& fp : factors_) {
    const Factor& f = *fp;
    cur.clear();
    lin.clear();
    off.clear();
    for (size_t j = 0; j < f.nodes.size(); ++j) {
      cur.push_back(f.nodes[j]->x.data());
      lin.push_back(linearisationPoint(f, j));
      off.push_back(3 * f.nodes[j]->slot);
    }
    for (size_t j = 0; j < f.calib.size(); ++j) {
      const double* c = calibData(f.calib[j]);
      cur.push_back(c);
      lin.push_back(c);
      off.push_back(3 * n + calibOffset(f.calib[j]));
    }
    if (!accumulate(f, cur, lin, off, H, g))
      throw Error("sliding window: a factor cannot be linearised for the covariance");
  }
  return H;
}

void SlidingWindowSmoother::computeCovariances(bool all) {
  const int n = static_cast<int>(nodes_.size());
  if (n == 0) return;
  const Eigen::MatrixXd H = windowInformation();
  Eigen::LLT<Eigen::MatrixXd> llt(H);
  if (llt.info() != Eigen::Success)
    throw Error("sliding window: the information of the window is not positive definite (rank deficient)");
  auto setJoint = [&](int i, const Eigen::MatrixXd& C, int row, int col_i, int col_next) {
    Node& a = *nodes_[static_cast<size_t>(i)];
    Eigen::Matrix<double, 6, 6> J;
    J.topLeftCorner<3, 3>() = C.block<3, 3>(row, col_i);
    J.topRightCorner<3, 3>() = C.block<3, 3>(row, col_next);
    J.bottomLeftCorner<3, 3>() = J.topRightCorner<3, 3>().transpose();
    J.bottomRightCorner<3, 3>() = C.block<3, 3>(row + 3, col_next);
    a.joint_next = 0.5 * (J + J.transpose());
    a.have_joint_next = true;
  };
  const int cd = calibDim();
  if (all) {
    const Eigen::MatrixXd C = llt.solve(Eigen::MatrixXd::Identity(3 * n + cd, 3 * n + cd));
    if (cd > 0) calib_covariance_ = C.bottomRightCorner(cd, cd);
    for (int i = 0; i < n; ++i) {
      const Eigen::Matrix3d b = C.block<3, 3>(3 * i, 3 * i);
      nodes_[static_cast<size_t>(i)]->covariance = 0.5 * (b + b.transpose());
      if (config_.calibration.odometry)
        nodes_[static_cast<size_t>(i)]->wheels_cross = C.block<3, 3>(3 * i, 3 * n + calibOffset(wheels_block_));
      if (i + 1 < n) setJoint(i, C, 3 * i, 3 * i, 3 * i + 3);
    }
    return;
  }
  // The oldest pose with its successor (for the steps between them, see pushIntermediates)
  // and the newest pose.
  const bool pair = n > 1 && !nodes_.front()->after.empty();
  const int cols = pair ? 9 : 6;
  Eigen::MatrixXd E = Eigen::MatrixXd::Zero(3 * n + cd, cols + cd);
  E.block<3, 3>(0, 0).setIdentity();
  E.block<3, 3>(3 * (n - 1), 3).setIdentity();
  if (pair) E.block<3, 3>(3, 6).setIdentity();
  if (cd > 0) E.bottomRightCorner(cd, cd).setIdentity();
  const Eigen::MatrixXd X = llt.solve(E);
  if (cd > 0) {
    const Eigen::MatrixXd Cc = X.bottomRightCorner(cd, cd);
    calib_covariance_ = 0.5 * (Cc + Cc.transpose());
  }
  const Eigen::Matrix3d oldest = X.block<3, 3>(0, 0);
  const Eigen::Matrix3d newest = X.block<3, 3>(3 * (n - 1), 3);
  nodes_.front()->covariance = 0.5 * (oldest + oldest.transpose());
  nodes_.back()->covariance = 0.5 * (newest + newest.transpose());
  if (config_.calibration.odometry) {
    const int w = cols + calibOffset(wheels_block_);
    nodes_.front()->wheels_cross = X.block<3, 3>(0, w);
    nodes_.back()->wheels_cross = X.block<3, 3>(3 * (n - 1), w);
  }
  if (pair) {
    Eigen::MatrixXd C(6, 6);  // rows 0..5 of X's columns (oldest, successor)
    C.leftCols<3>() = X.block(0, 0, 6, 3);
    C.rightCols<3>() = X.block(0, 6, 6, 3);
    setJoint(0, C, 0, 0, 3);
  }
}

}  // namespace stereoloc
