#pragma once
// Test helpers for the check that a sliding window as long as the data solves the batch
// smoother's problem: the window's configuration for it, and how far apart the two solutions are.
#include <Eigen/Core>
#include <algorithm>
#include <vector>

#include "solvers/batch_smoother.h"
#include "solvers/sliding_window_smoother.h"
#include "src/core/estimator.h"
#include "src/core/pose2.h"

namespace stereoloc::test {

// The batch it is compared with: no kidnap cuts, solved to the limit of double precision, so that
// only the formulation could differ.
inline void solveToTheLimit(BatchSmootherConfig& c) {
  c.cut_at_reinitialisation = false;
  c.function_tolerance = c.parameter_tolerance = c.gradient_tolerance = 1e-16;
}

// A window over all `steps` that solves the batch's problem: no gate, linearised at the current
// estimate (covariances at the optimum, as the batch's), solved to the limit of double precision.
inline void solveAsTheBatch(SlidingWindowConfig& c, size_t steps) {
  c.window = static_cast<int>(steps);
  c.gate_enabled = false;
  c.linearisation = WindowLinearisation::Current;
  c.final_iterations = 100;
  c.function_tolerance = c.parameter_tolerance = c.gradient_tolerance = 1e-16;
}

// max |a - b| / max |b| over the entries (b's largest entry at least 1e-300).
inline double relativeDifference(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1e-300, b.cwiseAbs().maxCoeff());
}

// The largest pose difference (mm or rad, per entry) and relative covariance difference between
// two trajectories of the same steps; infinite when their lengths or steps differ.
struct SolutionGap {
  double pose = 0.0, covariance = 0.0;
};
inline SolutionGap solutionGap(const std::vector<Estimate>& a, const std::vector<Estimate>& b) {
  SolutionGap g;
  if (a.size() != b.size()) return {1e300, 1e300};
  for (size_t i = 0; i < a.size(); ++i) {
    if (a[i].step != b[i].step) return {1e300, 1e300};
    g.pose = std::max(g.pose, minus(a[i].pose, b[i].pose).cwiseAbs().maxCoeff());
    g.covariance = std::max(g.covariance, relativeDifference(a[i].covariance, b[i].covariance));
  }
  return g;
}

}  // namespace stereoloc::test
