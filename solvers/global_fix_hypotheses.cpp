#include "solvers/global_fix_hypotheses.h"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <utility>

#include "solvers/iterated_update.h"
#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

HypothesisBank::HypothesisBank(const FieldMap& map, const OdometryParams& odometry, HypothesisConfig config)
    : map_(map),
      odometry_(odometry),
      config_(std::move(config)),
      gate_threshold_(chi2Quantile(config_.gate_probability, 2)),
      compass_threshold_(chi2Quantile(config_.compass_gate_probability, 1)),
      merge_threshold_(chi2Quantile(config_.merge_probability, 3)) {
  odometry_.validate();
  if (!(config_.prune_log_ratio > 0) || config_.max_hypotheses < 1 || config_.max_iterations < 1 ||
      config_.max_misses < 1)
    throw Error("hypotheses: prune_log_ratio must be positive, max_hypotheses, max_iterations and max_misses >= 1");
  iteration_.max_iterations = config_.max_iterations;
}

bool HypothesisBank::update(PoseHypothesis& h, const std::vector<Observation>& observations, int skip) const {
  const std::vector<Observation> assoc =
      associateObservations(observations, h.pose, h.covariance, map_, config_.association);
  bool explained_any = false, unexplained_any = false;
  for (size_t k = 0; k < assoc.size(); ++k) {
    if (static_cast<int>(k) == skip) continue;
    const Observation& o = assoc[k];
    const Landmark* lm = o.landmark_id >= 0 ? map_.find(o.landmark_id) : nullptr;
    if (o.landmark_id >= 0 && !lm) throw Error("hypotheses: unknown landmark id " + std::to_string(o.landmark_id));
    // Gated at the hypothesis's belief after the step's earlier sightings: these sequential
    // innovations are independent, so their e2 add up to the log-likelihood of the step.
    std::optional<RangeBearingInnovation> g;
    if (lm) g = rangeBearingInnovationAt(h.pose, h.covariance, o.z(), o.covariance, lm->xy());  // (5.20)
    const double e2 = g ? g->mahalanobis_squared : gate_threshold_ + 1.0;
    if (std::isfinite(e2) && e2 <= gate_threshold_) {
      const std::optional<RangeBearingPosterior> post =
          updateRangeBearingBelief(h.pose, h.covariance, o.z(), o.covariance, lm->xy(), iteration_);
      if (!post) return false;  // unreachable: h was defined at this belief for the gate
      h.pose = post->pose;
      h.covariance = post->covariance;
      h.log_likelihood -= 0.5 * e2;
      explained_any = true;
    } else {
      h.log_likelihood -= 0.5 * gate_threshold_;  // a sighting this hypothesis cannot explain
      unexplained_any = true;
    }
  }
  h.misses = unexplained_any && !explained_any ? h.misses + 1 : (explained_any ? 0 : h.misses);
  return h.pose.isFinite() && h.covariance.allFinite() &&
         map_.bounds().contains(h.pose.translation(), config_.bounds_margin_mm) && h.misses < config_.max_misses;
}

void HypothesisBank::spawn(const Step& step) {
  if (!step.compass || step.observations.empty()) return;
  const double sigma = step.compass_sigma > 0 ? step.compass_sigma : config_.fix_options.compass_sigma_default;
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const Observation& o = step.observations[i];
    std::vector<const Landmark*> candidates;
    if (o.landmark_id >= 0) {
      const Landmark* lm = map_.find(o.landmark_id);
      if (!lm) throw Error("hypotheses: unknown landmark id " + std::to_string(o.landmark_id));
      candidates.push_back(lm);
    } else {
      candidates = map_.ofType(o.type);
    }
    for (const Landmark* lm : candidates) {
      const GlobalFix fix = fixFromOneLandmark(o, lm->xy(), *step.compass, sigma, config_.fix_options);  // (4.10)
      if (fix.status != FixStatus::Ok || !fix.pose.isFinite() || !fix.covariance.allFinite()) continue;
      if (!map_.bounds().contains(fix.pose.translation(), config_.bounds_margin_mm)) continue;  // 4.2.1
      PoseHypothesis h;
      h.pose = fix.pose;
      h.covariance = fix.covariance;
      std::vector<Observation> rest = step.observations;
      rest[i].landmark_id = lm->id;  // reserved for this sighting; it is inside the fix already
      if (update(h, rest, static_cast<int>(i))) hypotheses_.push_back(h);
    }
  }
}

void HypothesisBank::pruneAndMerge() {
  std::stable_sort(hypotheses_.begin(), hypotheses_.end(),
                   [](const PoseHypothesis& a, const PoseHypothesis& b) { return a.log_likelihood > b.log_likelihood; });
  if (hypotheses_.empty()) return;
  const double best = hypotheses_.front().log_likelihood;
  std::vector<PoseHypothesis> kept;
  for (PoseHypothesis& h : hypotheses_) {
    if (h.log_likelihood < best - config_.prune_log_ratio) break;
    bool duplicate = false;
    for (const PoseHypothesis& k : kept) {
      const Eigen::Vector3d d = minus(h.pose, k.pose);
      const Eigen::Matrix3d S = h.covariance + k.covariance;
      duplicate = mahalanobisSquared<3>(d, S) < merge_threshold_;
      if (duplicate) break;
    }
    if (duplicate) continue;
    h.log_likelihood -= best;  // relative: only the differences matter, and they stay bounded
    kept.push_back(h);
    if (static_cast<int>(kept.size()) >= config_.max_hypotheses) break;
  }
  hypotheses_ = std::move(kept);
}

void HypothesisBank::process(const Step& step, bool first) {
  if (hypotheses_.empty()) {
    spawn(step);
    pruneAndMerge();
    return;
  }
  const bool compass = step.compass.has_value();
  const double sigma = step.compass_sigma > 0 ? step.compass_sigma : config_.fix_options.compass_sigma_default;
  std::vector<PoseHypothesis> alive;
  for (PoseHypothesis h : hypotheses_) {
    if (!first) {
      const PosePrediction p = predictPose(h.pose, h.covariance, step.d_left, step.d_right, odometry_);  // (5.7), (5.9)
      h.pose = p.pose;
      h.covariance = p.covariance;
    }
    if (compass) {
      const double nu = angleDiff(*step.compass, h.pose.theta);
      const double S = h.covariance(2, 2) + sigma * sigma;
      const double e2 = nu * nu / S;
      if (e2 <= compass_threshold_) {
        const Eigen::Vector3d K = h.covariance.col(2) / S;
        h.pose = plus(h.pose, K * nu);
        Eigen::Matrix3d IKH = Eigen::Matrix3d::Identity();
        IKH.col(2) -= K;
        const Eigen::Matrix3d P = IKH * h.covariance * IKH.transpose() + (sigma * sigma) * K * K.transpose();
        h.covariance = 0.5 * (P + P.transpose());
        h.log_likelihood -= 0.5 * e2;
      } else {
        h.log_likelihood -= 0.5 * compass_threshold_;
      }
    }
    if (update(h, step.observations, -1)) alive.push_back(h);
  }
  hypotheses_ = std::move(alive);
  if (hypotheses_.empty()) spawn(step);
  pruneAndMerge();
}

std::vector<double> HypothesisBank::weights() const {
  std::vector<double> w;
  double sum = 0.0;
  for (const PoseHypothesis& h : hypotheses_) {
    w.push_back(std::exp(h.log_likelihood));  // <= 1: the best is at 0 after pruneAndMerge
    sum += w.back();
  }
  for (double& v : w) v /= sum;
  return w;
}

PoseFix HypothesisBank::mixture() const {
  if (hypotheses_.empty()) throw Error("hypotheses: the mixture of an empty bank");
  const std::vector<double> w = weights();
  double x = 0, y = 0, s = 0, c = 0;
  for (size_t i = 0; i < w.size(); ++i) {
    x += w[i] * hypotheses_[i].pose.x;
    y += w[i] * hypotheses_[i].pose.y;
    s += w[i] * std::sin(hypotheses_[i].pose.theta);
    c += w[i] * std::cos(hypotheses_[i].pose.theta);
  }
  PoseFix m;
  m.pose = Pose2(x, y, wrapAngle(std::atan2(s, c)));
  m.covariance.setZero();
  for (size_t i = 0; i < w.size(); ++i) {
    const Pose2& p = hypotheses_[i].pose;
    const Eigen::Vector3d d(p.x - x, p.y - y, angleDiff(p.theta, m.pose.theta));
    m.covariance += w[i] * (hypotheses_[i].covariance + d * d.transpose());
  }
  m.covariance = 0.5 * (m.covariance + m.covariance.transpose());
  return m;
}

}  // namespace stereoloc
