#pragma once
// Helpers the sliding window's source files share (solvers/sliding_window_smoother.cpp and
// sliding_window_{marginalisation,late,recovery}.cpp); not part of the API.
#include <ceres/problem.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <array>
#include <memory>

#include "src/core/pose2.h"

namespace stereoloc {
namespace window_detail {

inline bool positiveDefinite(const Eigen::Matrix3d& C) {
  if (!C.allFinite()) return false;
  Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (C + C.transpose()));
  return llt.info() == Eigen::Success;
}

inline Pose2 poseOf(const std::array<double, 3>& x) { return Pose2(x[0], x[1], x[2]); }

// The window's factors own their costs, the smoother its manifold and loss.
inline std::unique_ptr<ceres::Problem> emptyProblem() {
  ceres::Problem::Options popts;
  popts.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  popts.enable_fast_removal = true;
  return std::make_unique<ceres::Problem>(popts);
}

}  // namespace window_detail
}  // namespace stereoloc
