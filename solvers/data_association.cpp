#include "solvers/data_association.h"

#include <algorithm>
#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <tuple>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// Squared Mahalanobis distance of obs against landmark l from the pose prior; nullopt-like
// infinity when the geometry is degenerate or S is not positive definite.
double candidateDistance(const Observation& obs, const Pose2& pose, const Eigen::Matrix3d& P,
                         const Eigen::Vector2d& landmark) {
  Matrix23d H;
  Eigen::Vector2d zhat;
  try {
    zhat = predictRangeBearing(pose, landmark, &H);
  } catch (const GeometryError&) {
    return std::numeric_limits<double>::infinity();
  }
  const Eigen::Vector2d nu = rangeBearingInnovation(obs.z(), zhat);  // wrapped before gating
  const Eigen::Matrix2d S = H * P * H.transpose() + obs.covariance;     // (5.14)
  const double det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
  if (!(det > 0) || !(S(0, 0) > 0)) return std::numeric_limits<double>::infinity();
  const double d2 = nu.dot(S.inverse() * nu);  // (5.20)
  return std::isfinite(d2) ? d2 : std::numeric_limits<double>::infinity();
}

void checkInputs(const Observation& obs, const Pose2& pose, const Eigen::Matrix3d& P) {
  if (!pose.isFinite() || !P.allFinite()) throw Error("data association: pose prior is not finite");
  if (!obs.covariance.allFinite() || !std::isfinite(obs.range) || !std::isfinite(obs.bearing))
    throw Error("data association: observation is not finite");
}

// Joint compatibility branch and bound over the unidentified observations of one step.
class JointSearch {
 public:
  JointSearch(const std::vector<Observation>& obs, const Pose2& pose, const Eigen::Matrix3d& P, const FieldMap& map,
              const AssociationConfig& config, const std::vector<int>& reserved)
      : obs_(obs), pose_(pose), P_(P), map_(map), config_(config), reserved_(reserved) {
    const double individual = chi2Quantile(config.individual_gate_probability, 2);
    for (size_t i = 0; i < obs.size(); ++i) {
      if (obs[i].landmark_id >= 0) continue;
      Item item;
      item.obs = i;
      for (const Landmark& l : map.landmarks()) {
        if (l.type != obs[i].type || contains(reserved_, l.id)) continue;
        const double d2 = mapCost({{&obs[i], l.xy()}});
        if (d2 <= individual) item.candidates.emplace_back(d2, l.id);
      }
      std::sort(item.candidates.begin(), item.candidates.end());
      items_.push_back(item);
    }
  }

  // The pairing (observation index -> landmark id, -1 none) of the best hypothesis.
  std::vector<int> solve() {
    std::vector<int> h(items_.size(), -1);
    search(0, h, 0, 0.0);
    std::vector<int> out(obs_.size(), -1);
    if (best_.empty()) return out;
    for (size_t k = 0; k < items_.size(); ++k) {
      int id = best_.front()[k];
      if (config_.reject_ambiguous)
        for (const std::vector<int>& other : best_)
          if (other[k] != id) id = -1;  // the best hypotheses disagree on this observation
      out[items_[k].obs] = id;
    }
    return out;
  }

 private:
  struct Item {
    size_t obs = 0;
    std::vector<std::pair<double, int>> candidates;  // (individual d^2, landmark id), nearest first
  };

  static bool contains(const std::vector<int>& v, int id) { return std::find(v.begin(), v.end(), id) != v.end(); }

  // Joint compatibility of the pairings in h: the minimum over the pose of the MAP cost
  //   (x - x0)^T P^-1 (x - x0) + sum_j nu_j(x)^T R_j^-1 nu_j(x),   nu_j = z_j [-] h(x, l_j),
  // by Gauss-Newton from the prior x0 (an iterated update). It is chi-square with 2k dof for a
  // right hypothesis and, for one pairing of a linear model, the innovation distance (5.20).
  // Relinearising matters: stereo bearings are so precise that the prior's linearisation error
  // over a 3-sigma pose offset is many bearing sigmas. Infinity when not jointly compatible.
  double jointDistance(const std::vector<int>& h) const {
    std::vector<std::pair<const Observation*, Eigen::Vector2d>> pairs;
    for (size_t k = 0; k < h.size(); ++k)
      if (h[k] >= 0) pairs.emplace_back(&obs_[items_[k].obs], map_.at(h[k]).xy());
    const double d2 = mapCost(pairs);
    return d2 <= chi2Quantile(config_.gate_probability, 2 * static_cast<int>(pairs.size()))
               ? d2
               : std::numeric_limits<double>::infinity();
  }

  double mapCost(const std::vector<std::pair<const Observation*, Eigen::Vector2d>>& pairs) const {
    const Eigen::LLT<Eigen::Matrix3d> prior(P_);
    if (prior.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
    const Eigen::Matrix3d P_inv = prior.solve(Eigen::Matrix3d::Identity());
    std::vector<Eigen::Matrix2d> R_inv;
    for (const auto& pr : pairs) {
      const Eigen::LLT<Eigen::Matrix2d> llt(pr.first->covariance);
      if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
      R_inv.push_back(llt.solve(Eigen::Matrix2d::Identity()));
    }
    Pose2 x = pose_;
    double cost = std::numeric_limits<double>::infinity();
    for (int it = 0; it < kIterations; ++it) {
      const Eigen::Vector3d dx(x.x - pose_.x, x.y - pose_.y, wrapAngle(x.theta - pose_.theta));
      Eigen::Matrix3d A = P_inv;
      Eigen::Vector3d g = -P_inv * dx;
      cost = dx.dot(P_inv * dx);
      for (size_t j = 0; j < pairs.size(); ++j) {
        Matrix23d H;
        Eigen::Vector2d zhat;
        try {
          zhat = predictRangeBearing(x, pairs[j].second, &H);
        } catch (const GeometryError&) {
          return std::numeric_limits<double>::infinity();
        }
        const Eigen::Vector2d nu = rangeBearingInnovation(pairs[j].first->z(), zhat);
        cost += nu.dot(R_inv[j] * nu);
        A += H.transpose() * R_inv[j] * H;
        g += H.transpose() * R_inv[j] * nu;
      }
      if (it + 1 == kIterations) break;
      const Eigen::Vector3d step = A.ldlt().solve(g);
      if (!step.allFinite()) return std::numeric_limits<double>::infinity();
      x = Pose2(x.x + step.x(), x.y + step.y(), wrapAngle(x.theta + step.z()));
    }
    return std::isfinite(cost) ? cost : std::numeric_limits<double>::infinity();
  }

  static constexpr int kIterations = 6;  // the last one only evaluates the cost

  // h holds the pairings of observations < k; d2 is their joint distance.
  void search(size_t k, std::vector<int>& h, int pairings, double d2) {
    if (k == items_.size()) {
      if (pairings == 0) return;
      if (pairings > best_pairings_ || (pairings == best_pairings_ && d2 < best_d2_)) {
        if (pairings > best_pairings_) best_.clear();
        best_pairings_ = pairings;
        best_d2_ = d2;
        best_.insert(best_.begin(), h);
      } else if (pairings == best_pairings_) {
        best_.push_back(h);
      }
      return;
    }
    for (const auto& candidate : items_[k].candidates) {
      const int id = candidate.second;
      if (contains(h, id)) continue;
      h[k] = id;
      const double joint = jointDistance(h);
      if (std::isfinite(joint)) search(k + 1, h, pairings + 1, joint);
      h[k] = -1;
    }
    // Leaving observation k out can only help if the rest can still reach the best count.
    if (pairings + static_cast<int>(items_.size() - k - 1) >= best_pairings_) search(k + 1, h, pairings, d2);
  }

  const std::vector<Observation>& obs_;
  const Pose2& pose_;
  const Eigen::Matrix3d& P_;
  const FieldMap& map_;
  const AssociationConfig& config_;
  const std::vector<int>& reserved_;
  std::vector<Item> items_;
  int best_pairings_ = 0;
  double best_d2_ = std::numeric_limits<double>::infinity();
  std::vector<std::vector<int>> best_;  // every hypothesis with best_pairings_, the smallest d^2 first
};

}  // namespace

AssociationResult associate(const Observation& obs, const Pose2& pose, const Eigen::Matrix3d& covariance,
                            const FieldMap& map, const AssociationConfig& config, const std::vector<int>& excluded) {
  checkInputs(obs, pose, covariance);
  const double threshold = chi2Quantile(config.gate_probability, 2);
  AssociationResult best;
  for (const Landmark& l : map.landmarks()) {
    if (l.type != obs.type) continue;
    if (std::find(excluded.begin(), excluded.end(), l.id) != excluded.end()) continue;
    const double d2 = candidateDistance(obs, pose, covariance, l.xy());
    if (!(d2 <= threshold)) continue;
    ++best.candidates_in_gate;
    if (d2 < best.mahalanobis_squared) {
      best.mahalanobis_squared = d2;
      best.landmark_id = l.id;
    }
  }
  if (config.reject_ambiguous && best.candidates_in_gate > 1) best.landmark_id = -1;
  return best;
}

std::vector<Observation> associateObservations(const std::vector<Observation>& observations, const Pose2& pose,
                                               const Eigen::Matrix3d& covariance, const FieldMap& map,
                                               const AssociationConfig& config) {
  std::vector<Observation> out = observations;
  if (!config.exclusive) {
    for (Observation& o : out)
      if (o.landmark_id < 0) o.landmark_id = associate(o, pose, covariance, map, config).landmark_id;
    return out;
  }
  const double threshold = chi2Quantile(config.gate_probability, 2);
  std::vector<int> used;
  for (const Observation& o : out)
    if (o.landmark_id >= 0) used.push_back(o.landmark_id);
  if (config.joint) {
    for (const Observation& o : out)
      if (o.landmark_id < 0) checkInputs(o, pose, covariance);
    const std::vector<int> ids = JointSearch(out, pose, covariance, map, config, used).solve();
    for (size_t i = 0; i < out.size(); ++i)
      if (out[i].landmark_id < 0) out[i].landmark_id = ids[i];
    return out;
  }
  // All gated (distance, observation, landmark) pairs, assigned greedily nearest first; ties
  // are broken by observation then landmark index so the result does not depend on sort order.
  std::vector<std::tuple<double, size_t, int>> pairs;
  for (size_t i = 0; i < out.size(); ++i) {
    if (out[i].landmark_id >= 0) continue;
    checkInputs(out[i], pose, covariance);
    for (const Landmark& l : map.landmarks()) {
      if (l.type != out[i].type) continue;
      if (std::find(used.begin(), used.end(), l.id) != used.end()) continue;
      const double d2 = candidateDistance(out[i], pose, covariance, l.xy());
      if (d2 <= threshold) pairs.emplace_back(d2, i, l.id);
    }
  }
  std::sort(pairs.begin(), pairs.end());
  std::vector<bool> assigned(out.size(), false);
  if (config.reject_ambiguous) {
    std::vector<int> in_gate(out.size(), 0);
    for (const auto& pair : pairs) ++in_gate[std::get<1>(pair)];
    for (size_t i = 0; i < out.size(); ++i) assigned[i] = in_gate[i] > 1;  // never assigned below
  }
  for (const auto& [d2, i, id] : pairs) {
    if (assigned[i] || std::find(used.begin(), used.end(), id) != used.end()) continue;
    out[i].landmark_id = id;
    assigned[i] = true;
    used.push_back(id);
  }
  return out;
}

}  // namespace stereoloc
