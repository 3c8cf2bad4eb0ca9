#include "src/data_association.h"

#include <algorithm>
#include <Eigen/LU>
#include <cmath>
#include <tuple>

#include "src/error.h"
#include "src/gaussian.h"
#include "src/measurement_model.h"

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
  for (const auto& [d2, i, id] : pairs) {
    if (assigned[i] || std::find(used.begin(), used.end(), id) != used.end()) continue;
    out[i].landmark_id = id;
    assigned[i] = true;
    used.push_back(id);
  }
  return out;
}

}  // namespace stereoloc
