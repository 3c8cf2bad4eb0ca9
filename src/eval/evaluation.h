#pragma once
// Evaluation: pure functions from (estimates, ground truth) to the metrics the thesis reports
// (mean/std/min/max distance error, Tables 6.4-6.16) and the consistency metrics it does not
// (RMSE, NEES with its chi-square band). Used by the study, the benchmarks and the tests.
#include <Eigen/Core>
#include <map>
#include <optional>
#include <vector>

#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

// Mean, population standard deviation, min and max: the thesis's table format.
struct ErrorStats {
  size_t count = 0;
  double mean = 0, std = 0, min = 0, max = 0;
};
ErrorStats errorStats(const std::vector<double>& values);

// Ground truth keyed by step number.
using TruthByStep = std::map<long, Pose2>;
TruthByStep truthByStep(const std::vector<Step>& steps, const std::vector<std::optional<Pose2>>& groundtruth);

struct PoseError {
  long step = 0;
  double dx = 0, dy = 0, dtheta = 0;  // estimate [-] truth: mm, mm, rad (wrapped)
  double distance = 0;                // hypot(dx, dy), mm
  std::optional<double> nees;         // e^T P^-1 e, when the covariance is positive definite
  // Its parts, with nees: the position's (2 dof, the 2x2 block of P: its mean is 2 when
  // consistent) and the heading's (1 dof, dtheta^2 / P_theta_theta), which say which part of a
  // covariance is too narrow or too wide (they need not add up to nees).
  std::optional<double> position_nees, heading_nees;
  EstimateStatus status = EstimateStatus::Tracking;
};

// e^T P^-1 e for e = estimate [-] truth; nullopt when P is not positive definite or not finite.
std::optional<double> nees(const Pose2& estimate, const Eigen::Matrix3d& covariance, const Pose2& truth);

// One PoseError per estimate that has ground truth at its step and is initialised.
std::vector<PoseError> poseErrors(const std::vector<Estimate>& estimates, const TruthByStep& truth);

struct TrajectoryMetrics {
  size_t count = 0;
  double position_rmse = 0;  // mm
  double theta_rmse = 0;     // rad
  ErrorStats distance;       // mm (the thesis's "distance to the truth")
  ErrorStats abs_dx, abs_dy, abs_dtheta;  // mm, mm, rad (Tables 6.4-6.13)
  double mean_nees = 0;      // over estimates with a covariance
  double mean_position_nees = 0, mean_heading_nees = 0;  // the same estimates (2 and 1 consistent)
  size_t nees_count = 0;
  double nees_in_band = 0;   // fraction of per-estimate NEES inside the 95 % chi-square(3) band
};
TrajectoryMetrics trajectoryMetrics(const std::vector<PoseError>& errors);

// The two-sided band [lo, hi] that the AVERAGE of `runs` independent NEES values with `dof`
// degrees of freedom falls in with the given probability: chi2(N dof)/N quantiles.
struct NeesBand {
  double lo = 0, hi = 0;
};
NeesBand neesBand(int dof, int runs, double probability = 0.95);

}  // namespace stereoloc
