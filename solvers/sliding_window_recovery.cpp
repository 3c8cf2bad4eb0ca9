// The sliding window lost or failed: global fixes, re-anchoring, restarts, and giving the window
// up after a step that fails halfway (solvers/sliding_window_smoother.h).
#include "solvers/sliding_window_smoother.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <vector>

#include "solvers/sliding_window_detail.h"
#include "src/core/error.h"

namespace stereoloc {

using window_detail::emptyProblem;
using window_detail::poseOf;
using window_detail::positiveDefinite;

void SlidingWindowSmoother::takeCheckpoint() {
  Checkpoint& c = checkpoint_;
  c.poses.resize(nodes_.size());
  for (size_t i = 0; i < nodes_.size(); ++i) c.poses[i] = {nodes_[i]->step, nodes_[i]->x, nodes_[i]->covariance};
  c.calibration.clear();
  for (const CalibBlock& b : calib_) c.calibration.insert(c.calibration.end(), b.data, b.data + b.size);
  c.calib_blocks = calib_.size();
  c.calib_dim = calib_dim_;
  c.features = features_.size();
  c.calib_covariance = calib_covariance_;
}

void SlidingWindowSmoother::abandonWindow(std::optional<long> failed) {
  const Checkpoint& c = checkpoint_;
  if (failed && !nodes_.empty() && nodes_.back()->step >= *failed) dropNewest();
  for (const auto& n : nodes_) {
    const auto kept = std::find_if(c.poses.begin(), c.poses.end(),
                                   [&n](const Checkpoint::PoseState& p) { return p.step == n->step; });
    if (kept == c.poses.end()) continue;
    n->x = kept->x;
    n->covariance = kept->covariance;
  }
  try {
    computeCovariances(true);
  } catch (const Error&) {
    // The window's information is what failed: each pose keeps the marginal it last had, and a
    // pose that never had one (made by the failed step) the previous pose's composed with the
    // odometry between them.
    for (size_t i = 1; i < nodes_.size(); ++i) {
      Node& n = *nodes_[i];
      if (positiveDefinite(n.covariance)) continue;
      const Node& k = *nodes_[i - 1];
      Matrix3d A1, A2;
      compose(poseOf(k.x), k.rel_to_next, &A1, &A2);
      n.covariance = composedCovariance(k, A1, A2, k.rel_to_next_covariance, Matrix3d::Zero());
    }
  }
  for (size_t i = 0; i < nodes_.size(); ++i) {
    pushHistory(estimateOf(*nodes_[i]));
    pushIntermediates(*nodes_[i], i + 1 < nodes_.size() ? nodes_[i + 1].get() : nullptr);
  }
  // A problem built anew: the failure may have come between a change of it and of ours.
  problem_ = emptyProblem();
  factors_.clear();
  nodes_.clear();
  while (features_.size() > c.features) {
    feature_index_.erase(features_.back().landmark_id);
    features_.pop_back();
  }
  calib_.resize(c.calib_blocks);
  calib_dim_ = c.calib_dim;
  size_t k = 0;
  for (const CalibBlock& b : calib_) {
    std::copy(c.calibration.begin() + static_cast<long>(k), c.calibration.begin() + static_cast<long>(k) + b.size,
              b.data);
    k += static_cast<size_t>(b.size);
    problem_->AddParameterBlock(b.data, b.size);
  }
  calib_covariance_ = c.calib_covariance;
  addCalibrationPrior();
  lost_ = false;
  rel_ = Pose2();
  rel_covariance_.setZero();
  rel_wheels_.setZero();
  steps_since_keyframe_ = 0;
}

std::optional<PoseFix> SlidingWindowSmoother::globalFix(const Step& step) const {
  if (!config_.global_fix) return std::nullopt;
  if (!config_.calibration.stereo) return config_.global_fix(step, map_);
  // The fix from the observations as the current calibration sees them (see fuseObservation):
  // with the given calibration's range bias it can lie hundreds of millimetres off, and then
  // disagrees with the window's prediction, which restarts the window instead of re-anchoring it.
  Step calibrated = step;
  calibrated.observations.clear();
  for (const Observation& o : step.observations) {
    if (!o.pixels) {
      calibrated.observations.push_back(o);
      continue;
    }
    Landmark kind;
    kind.type = o.type;
    try {
      calibrated.observations.push_back(calibratedObservation(
          o, config_.observation_model.rig, head_, headCovariance(), pixelCovarianceFor(o, kind, config_.observation_model)));
    } catch (const GeometryError&) {
    }
  }
  return config_.global_fix(calibrated, map_);
}

bool SlidingWindowSmoother::tryGlobalFix(const Step& step, Estimate* out) {
  if (!config_.global_fix) return false;
  const std::optional<PoseFix> fix = globalFix(step);
  if (!fix || !fix->pose.isFinite() || !positiveDefinite(fix->covariance)) return false;
  finaliseWindow();
  startWindow(step, fix->pose, fix->covariance, EstimateStatus::Reinitialised);
  ++stats_.reinitialisations;
  *out = estimateOf(*nodes_.back());
  return true;
}

bool SlidingWindowSmoother::reanchor(const PoseFix& fix, const Pose2& pred, const Eigen::Matrix3d& P_pred) {
  if (!(config_.reanchor_probability > 0)) return false;
  const Eigen::Vector3d v(fix.pose.x - pred.x, fix.pose.y - pred.y, angleDiff(fix.pose.theta, pred.theta));
  const Eigen::Matrix3d S = P_pred + fix.covariance;
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(0.5 * (S + S.transpose()));
  const double d2 = v.dot(ldlt.solve(v));
  if (!std::isfinite(d2) || d2 > std::max(chi2Quantile(config_.reanchor_probability, 3), config_.restart_min_evidence))
    return false;
  // The rigid motion that takes the newest pose onto the fix, applied to the whole window: the
  // initial guess, since the odometry between the poses is what the window trusts.
  Node* newest = nodes_.back().get();
  const Pose2 anchor = poseOf(newest->x);
  std::vector<std::array<double, 3>> before;
  for (const auto& n : nodes_) {
    before.push_back(n->x);
    const Pose2 q = compose(fix.pose, between(anchor, poseOf(n->x)));
    n->x = {q.x, q.y, q.theta};
  }
  // A sighting that cannot be evaluated there (with the stereo head calibrated: its landmark
  // behind the cameras) contradicts the moved window outright: a real loss after all.
  double cost = 0.0;
  if (!problem_->Evaluate(ceres::Problem::EvaluateOptions(), &cost, nullptr, nullptr, nullptr)) {
    for (size_t i = 0; i < nodes_.size(); ++i) nodes_[i]->x = before[i];
    return false;
  }
  // The first-estimate Jacobians move with the poses (the old ones belong to the wrong place).
  relinearise();
  gate_.reset();
  lost_ = false;
  ++stats_.reanchorings;
  // The newest pose's gated observations against the fix, the others against the marginals of
  // the window solved with them.
  std::vector<int> used;
  for (const Observation& o : newest->gated)
    if (o.landmark_id >= 0) used.push_back(o.landmark_id);
  auto refuse = [&](Node* n, Pose2 pose, Eigen::Matrix3d P) {
    std::vector<Observation> gated;
    gated.swap(n->gated);
    for (const Observation& obs : gated) {
      const bool accepted = fuseObservation(obs, n, pose, P, used);
      ++(accepted ? stats_.accepted_observations : stats_.rejected_observations);
      --stats_.rejected_observations;  // counted once, when it was gated
      if (!accepted) n->gated.push_back(obs);
    }
  };
  refuse(newest, fix.pose, fix.covariance);
  newest->status = EstimateStatus::Reinitialised;
  solve(config_.max_iterations);
  computeCovariances(true);
  for (const auto& n : nodes_) {
    if (n.get() == newest || n->gated.empty()) continue;
    used.clear();
    refuse(n.get(), poseOf(n->x), n->covariance);
    if (n->status == EstimateStatus::Predicted && n->gated.empty()) n->status = EstimateStatus::Tracking;
  }
  relinearise();
  while (static_cast<int>(nodes_.size()) > config_.window) marginaliseOldest();
  solve(config_.max_iterations);
  computeCovariances(false);
  return true;
}

Estimate SlidingWindowSmoother::startFromGlobalFix(const Step& step) {
  Estimate out;
  if (tryGlobalFix(step, &out)) return out;
  out.step = step.step;
  out.t = step.t;
  out.status = EstimateStatus::Uninitialised;
  pushHistory(out);
  return out;
}

Estimate SlidingWindowSmoother::recoverFromLoss(const Step& step, const PoseFix& fix, const Pose2& pred_pose,
                                                const Eigen::Matrix3d& pred_P) {
  if (reanchor(fix, pred_pose, pred_P)) return estimateOf(*nodes_.back());
  // Re-initialise from this step's fix: the predicted pose of this step is replaced.
  dropNewest();
  finaliseWindow();
  startWindow(step, fix.pose, fix.covariance, EstimateStatus::Reinitialised);
  ++stats_.reinitialisations;
  return estimateOf(*nodes_.back());
}

}  // namespace stereoloc
