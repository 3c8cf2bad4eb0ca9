#include "src/eval/evaluation.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "src/core/gaussian.h"

namespace stereoloc {

ErrorStats errorStats(const std::vector<double>& values) {
  ErrorStats s;
  s.count = values.size();
  if (values.empty()) return s;
  double sum = 0;
  s.min = values.front();
  s.max = values.front();
  for (double v : values) {
    sum += v;
    s.min = std::min(s.min, v);
    s.max = std::max(s.max, v);
  }
  s.mean = sum / values.size();
  double ss = 0;
  for (double v : values) ss += (v - s.mean) * (v - s.mean);
  s.std = std::sqrt(ss / values.size());
  return s;
}

TruthByStep truthByStep(const std::vector<Step>& steps, const std::vector<std::optional<Pose2>>& groundtruth) {
  TruthByStep out;
  const size_t n = std::min(steps.size(), groundtruth.size());
  for (size_t i = 0; i < n; ++i)
    if (groundtruth[i]) out.emplace(steps[i].step, *groundtruth[i]);
  return out;
}

std::optional<double> nees(const Pose2& estimate, const Eigen::Matrix3d& covariance, const Pose2& truth) {
  if (!covariance.allFinite()) return std::nullopt;
  Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (covariance + covariance.transpose()));
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::Vector3d e = minus(estimate, truth);
  return e.dot(llt.solve(e));
}

std::vector<PoseError> poseErrors(const std::vector<Estimate>& estimates, const TruthByStep& truth) {
  std::vector<PoseError> out;
  out.reserve(estimates.size());
  for (const Estimate& est : estimates) {
    if (est.status == EstimateStatus::Uninitialised) continue;
    const auto it = truth.find(est.step);
    if (it == truth.end()) continue;
    const Eigen::Vector3d e = minus(est.pose, it->second);
    PoseError pe;
    pe.step = est.step;
    pe.dx = e.x();
    pe.dy = e.y();
    pe.dtheta = e.z();
    pe.distance = std::hypot(e.x(), e.y());
    pe.nees = nees(est.pose, est.covariance, it->second);
    if (pe.nees) {  // P positive definite, so are its blocks
      const Eigen::Matrix3d P = 0.5 * (est.covariance + est.covariance.transpose());
      const Eigen::Vector2d exy = e.head<2>();
      pe.position_nees = exy.dot(P.topLeftCorner<2, 2>().llt().solve(exy));
      pe.heading_nees = e.z() * e.z() / P(2, 2);
    }
    pe.status = est.status;
    out.push_back(pe);
  }
  return out;
}

TrajectoryMetrics trajectoryMetrics(const std::vector<PoseError>& errors) {
  TrajectoryMetrics m;
  m.count = errors.size();
  if (errors.empty()) return m;
  std::vector<double> dist, adx, ady, adt;
  double se_pos = 0, se_theta = 0, nees_sum = 0, position_nees_sum = 0, heading_nees_sum = 0;
  size_t in_band = 0;
  const double lo = chi2Quantile(0.025, 3), hi = chi2Quantile(0.975, 3);
  for (const PoseError& e : errors) {
    dist.push_back(e.distance);
    adx.push_back(std::fabs(e.dx));
    ady.push_back(std::fabs(e.dy));
    adt.push_back(std::fabs(e.dtheta));
    se_pos += e.distance * e.distance;
    se_theta += e.dtheta * e.dtheta;
    if (e.nees) {
      nees_sum += *e.nees;
      position_nees_sum += e.position_nees.value_or(0.0);
      heading_nees_sum += e.heading_nees.value_or(0.0);
      ++m.nees_count;
      in_band += (*e.nees >= lo && *e.nees <= hi) ? 1 : 0;
    }
  }
  m.position_rmse = std::sqrt(se_pos / errors.size());
  m.theta_rmse = std::sqrt(se_theta / errors.size());
  m.distance = errorStats(dist);
  m.abs_dx = errorStats(adx);
  m.abs_dy = errorStats(ady);
  m.abs_dtheta = errorStats(adt);
  if (m.nees_count > 0) {
    m.mean_nees = nees_sum / m.nees_count;
    m.mean_position_nees = position_nees_sum / m.nees_count;
    m.mean_heading_nees = heading_nees_sum / m.nees_count;
    m.nees_in_band = static_cast<double>(in_band) / m.nees_count;
  }
  return m;
}

NeesBand neesBand(int dof, int runs, double probability) {
  if (runs < 1) throw Error("neesBand: runs must be >= 1");
  const double a = 0.5 * (1.0 - probability);
  const int k = dof * runs;
  return NeesBand{chi2Quantile(a, k) / runs, chi2Quantile(1.0 - a, k) / runs};
}

}  // namespace stereoloc
