// The sliding window's late observations: insertLate at a pose in the window, the promotion of a
// non-keyframe step to a window pose, the restart from a recent step (solvers/sliding_window_smoother.h).
#include "solvers/sliding_window_smoother.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <vector>

#include "solvers/sliding_window_detail.h"
#include "src/core/error.h"

namespace stereoloc {

using window_detail::poseOf;
using window_detail::positiveDefinite;

SlidingWindowSmoother::Node* SlidingWindowSmoother::promote(size_t k_index, size_t j) {
  Node* k = nodes_[k_index].get();
  Node* next = k_index + 1 < nodes_.size() ? nodes_[k_index + 1].get() : nullptr;
  const Intermediate m = k->after[j];
  auto node = std::make_unique<Node>();
  node->step = m.step;
  node->t = m.t;
  node->status = m.status;
  node->d_left = m.d_left;
  node->d_right = m.d_right;
  node->noise = m.noise;
  node->rate = m.rate;
  const Pose2 p = compose(poseOf(k->x), m.rel);
  node->x = {p.x, p.y, p.theta};
  // The steps after it, composed from it as process() does after a keyframe.
  Pose2 rel;
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d rel_wheels = Eigen::Matrix3d::Zero();
  for (size_t i = j + 1; i < k->after.size(); ++i) {
    Intermediate q = k->after[i];
    const PosePrediction r = predictStep(rel, C, q.d_left, q.d_right, &rel_wheels);
    rel = r.pose;
    C = r.covariance;
    q.rel = rel;
    q.rel_covariance = C;
    q.rel_wheels = rel_wheels;
    node->after.push_back(q);
  }
  k->after.resize(j);
  Node* n = node.get();
  nodes_.insert(nodes_.begin() + static_cast<long>(k_index) + 1, std::move(node));
  problem_->AddParameterBlock(n->x.data(), 3, &manifold_);
  if (next) {
    for (size_t i = 0; i < factors_.size(); ++i)
      if (factors_[i]->odometry && factors_[i]->nodes[0] == k && factors_[i]->nodes[1] == next) {
        removeFactor(i);
        break;
      }
    const PosePrediction r = predictStep(rel, C, next->d_left, next->d_right);
    n->rel_to_next = r.pose;
    n->rel_to_next_covariance = r.covariance;
    addOdometry(n, next, n->after, r.pose, r.covariance);
  } else {
    rel_ = rel;  // the odometry since the newest keyframe, which is now this step
    rel_covariance_ = C;
    rel_wheels_ = rel_wheels;
    steps_since_keyframe_ = static_cast<int>(n->after.size());
  }
  k->rel_to_next = m.rel;
  k->rel_to_next_covariance = m.rel_covariance;
  k->have_joint_next = false;
  addOdometry(k, n, k->after, m.rel, m.rel_covariance);
  ++stats_.keyframes;
  return n;
}

LateObservationResult SlidingWindowSmoother::insertLate(long step, const std::vector<Observation>& observations) {
  if (finished_) throw Error("sliding window: insertLate() after finish()");
  if (!have_step_ || step > last_step_)
    throw Error("sliding window: observations of step " + std::to_string(step) + ", which was not processed yet");
  Step check;
  check.step = step;
  check.observations = observations;
  validateStep(check, "sliding window");
  for (size_t i = 0; i < observations.size(); ++i) {
    const int id = observations[i].landmark_id;
    if (id >= 0 && !map_.find(id))
      throw Error("sliding window: step " + std::to_string(step) + ": observation " + std::to_string(i) +
                  ": unknown landmark id " + std::to_string(id));
  }
  takeCheckpoint();
  try {
    return insertChecked(step, observations);
  } catch (...) {
    abandonWindow(std::nullopt);
    throw;
  }
}

LateObservationResult SlidingWindowSmoother::insertChecked(long step, const std::vector<Observation>& observations) {
  Step check;
  check.step = step;
  check.observations = observations;
  LateObservationResult result;
  if ((nodes_.empty() || (lost_ && config_.reinitialise_when_lost)) && restartLate(step, observations)) {
    result.status = LateObservationStatus::Inserted;
    for (const Observation& o : observations) result.accepted += o.landmark_id >= 0;  // the fix's
    result.estimate = current();
    return result;
  }
  if (nodes_.empty() || lost_) {
    result.status = LateObservationStatus::NotTracking;
    result.estimate = current();
    return result;
  }
  if (step < nodes_.front()->step) {
    ++stats_.late_too_late;
    result.status = LateObservationStatus::TooLate;
    result.estimate = current();
    return result;
  }
  result.status = LateObservationStatus::Inserted;
  result.estimate = current();
  if (observations.empty()) return result;  // nothing to add: the window stays as it is
  // The window pose of that step, or the keyframe it follows.
  size_t k = nodes_.size() - 1;
  while (nodes_[k]->step > step) --k;
  Node* node = nodes_[k].get();
  if (node->step != step) {
    size_t j = 0;
    while (j < node->after.size() && node->after[j].step != step) ++j;
    if (j == node->after.size())
      throw Error("sliding window: observations of step " + std::to_string(step) + ", which was not processed");
    node = promote(k, j);
    ++k;
  }
  ++stats_.late_inserted;
  // The step's belief in the current window: its marginal.
  const Eigen::MatrixXd H = windowInformation();
  const Eigen::LLT<Eigen::MatrixXd> llt(H);
  if (llt.info() != Eigen::Success)
    throw Error("sliding window: the information of the window is not positive definite (rank deficient)");
  Eigen::MatrixXd E = Eigen::MatrixXd::Zero(H.rows(), 3);
  E.block<3, 3>(3 * static_cast<long>(k), 0).setIdentity();
  Eigen::Matrix3d P = llt.solve(E).block<3, 3>(3 * static_cast<long>(k), 0);
  P = 0.5 * (P + P.transpose());
  const Pose2 marginal = poseOf(node->x);
  const Eigen::Matrix3d P_marginal = P;
  Pose2 pose = marginal;
  bool compass_fused = false;
  const std::vector<bool> accepted = fuseStep(check, node, marginal, P_marginal, pose, P, &compass_fused);
  for (size_t i = 0; i < observations.size(); ++i) {
    ++(accepted[i] ? result.accepted : result.rejected);
    if (!accepted[i]) node->gated.push_back(observations[i]);
    ++(accepted[i] ? stats_.accepted_observations : stats_.rejected_observations);
    if (accepted[i] && node->status != EstimateStatus::Reinitialised) node->status = EstimateStatus::Tracking;
    if (gate_enabled_ && !lost_ && gate_.record(accepted[i])) lost_ = true;  // (5.1.3): process() asks the global fix next
  }
  while (static_cast<int>(nodes_.size()) > config_.window) marginaliseOldest();
  solve(config_.max_iterations);
  computeCovariances(false);
  result.estimate = current();
  return result;
}

bool SlidingWindowSmoother::restartLate(long step, const std::vector<Observation>& observations) {
  auto it = std::find_if(recent_.begin(), recent_.end(), [step](const RecentStep& s) { return s.step.step == step; });
  if (it == recent_.end() || observations.empty() || !config_.global_fix) return false;
  if (!nodes_.empty() && step < nodes_.front()->step) return false;  // before the window: too late
  Step at = it->step;
  at.observations = observations;
  const std::optional<PoseFix> fix = globalFix(at);
  if (!fix || !fix->pose.isFinite() || !positiveDefinite(fix->covariance)) return false;
  const std::vector<RecentStep> after(it + 1, recent_.end());
  // The body rates again from the kept steps up to `at`; track() adds the later ones.
  rate_tracker_.reset();
  for (auto s = recent_.begin(); image_sigmas_ && s != it + 1; ++s)
    step_rate_ = stepBodyRate(rate_tracker_, s->step, odometry_, config_.observation_model.unmodelled.slip_rel_sigma);
  recent_.erase(it + 1, recent_.end());  // track() takes them again
  finaliseWindow();
  while (!history_.empty() && history_.back().step >= step) history_.pop_back();  // replaced below
  startWindow(at, fix->pose, fix->covariance, EstimateStatus::Reinitialised);
  ++stats_.reinitialisations;
  // The odometry since then, as process() would have taken it after this start.
  const long newest = last_step_;
  size_t tracked = 0;
  try {
    for (; tracked < after.size(); ++tracked) track(after[tracked].step, after[tracked].noise);
  } catch (...) {
    // track() kept the failed step for a later restart and took its body rate; the ones after
    // it are kept here, their rates taken.
    for (size_t i = tracked + 1; i < after.size(); ++i) {
      recent_.push_back(after[i]);
      if (image_sigmas_)
        step_rate_ =
            stepBodyRate(rate_tracker_, after[i].step, odometry_, config_.observation_model.unmodelled.slip_rel_sigma);
    }
    while (static_cast<int>(recent_.size()) > config_.restart_buffer_steps) recent_.pop_front();
    stats_.steps -= static_cast<long>(tracked) + 1;
    last_step_ = newest;
    throw;
  }
  stats_.steps -= static_cast<long>(after.size());
  last_step_ = newest;
  return true;
}

}  // namespace stereoloc
