#pragma once
// Nearest-neighbour data association of unidentified observations (landmark_id == -1) with map
// landmarks of the same type, given a Gaussian pose prior. Used by the frontend and by every
// tracker. The distance is the squared Mahalanobis distance of the innovation (5.20),
//   nu = z [-] h(pose, l),   S = H P H^T + R,   d^2 = nu^T S^-1 nu,
// with h = predictRangeBearing (5.27) and H its Jacobian, so a candidate is only accepted
// inside the same chi-square gate the trackers use for validation.
#include <Eigen/Core>
#include <limits>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

struct AssociationConfig {
  double gate_probability = 0.99;  // chi-square probability (2 dof) a candidate must fall inside
  bool exclusive = true;           // each landmark is associated with at most one observation per step
  // An observation with more than one landmark of its type inside the gate stays unassociated:
  // with a loose prior (a start, a re-localisation) the nearest of two gated marking corners is
  // often the wrong one, and one wrong update corrupts a filter far more than a skipped one
  // costs (the image-frontend EKF once jumped 130 mm on its first step that way).
  bool reject_ambiguous = true;
  // associateObservations tests the observations of a step jointly (JCBB, Neira & Tardos 2001):
  // the pose error is common to all of them, so a prior that is 3 sigma off can put every true
  // landmark just outside its individual gate and a wrong one inside, while the true set is
  // jointly compatible. Candidates need individual_gate_probability (looser) on their own and
  // the hypothesis gate_probability with 2k dof jointly; the hypothesis with the most pairings
  // wins (then the smallest joint distance). false: greedy nearest-neighbour pairs.
  bool joint = true;
  double individual_gate_probability = 0.9999;
};

struct AssociationResult {
  int landmark_id = -1;  // -1: no candidate inside the gate
  double mahalanobis_squared = std::numeric_limits<double>::infinity();  // of the chosen candidate
  int candidates_in_gate = 0;  // > 1: ambiguous (no association with reject_ambiguous, else the nearest)
};

// The nearest landmark of obs.type inside the gate, skipping the ids in `excluded` (none when
// the gate holds several and config.reject_ambiguous).
// Landmarks that coincide with the robot position are skipped. `covariance` is the pose
// covariance (x, y, theta); obs.covariance is R.
AssociationResult associate(const Observation& obs, const Pose2& pose, const Eigen::Matrix3d& covariance,
                            const FieldMap& map, const AssociationConfig& config = AssociationConfig(),
                            const std::vector<int>& excluded = {});

// Associates every observation with landmark_id == -1 in one step. Observations that already
// carry an id keep it (and, with exclusive, reserve it). With exclusive and joint, by joint
// compatibility branch and bound (see AssociationConfig::joint); with reject_ambiguous only the
// pairings shared by every best hypothesis are kept. With exclusive and not joint, pairs are
// assigned greedily in order of increasing Mahalanobis distance, and observations with several
// landmarks in the gate stay unassociated with reject_ambiguous. Unassociated observations keep -1.
std::vector<Observation> associateObservations(const std::vector<Observation>& observations, const Pose2& pose,
                                               const Eigen::Matrix3d& covariance, const FieldMap& map,
                                               const AssociationConfig& config = AssociationConfig());

}  // namespace stereoloc
