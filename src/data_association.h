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

#include "src/field_map.h"
#include "src/pose2.h"
#include "src/types.h"

namespace stereoloc {

struct AssociationConfig {
  double gate_probability = 0.99;  // chi-square probability (2 dof) a candidate must fall inside
  bool exclusive = true;           // each landmark is associated with at most one observation per step
};

struct AssociationResult {
  int landmark_id = -1;  // -1: no candidate inside the gate
  double mahalanobis_squared = std::numeric_limits<double>::infinity();  // of the chosen candidate
  int candidates_in_gate = 0;  // > 1 means the choice was ambiguous (the nearest one won)
};

// The nearest landmark of obs.type inside the gate, skipping the ids in `excluded`.
// Landmarks that coincide with the robot position are skipped. `covariance` is the pose
// covariance (x, y, theta); obs.covariance is R.
AssociationResult associate(const Observation& obs, const Pose2& pose, const Eigen::Matrix3d& covariance,
                            const FieldMap& map, const AssociationConfig& config = AssociationConfig(),
                            const std::vector<int>& excluded = {});

// Associates every observation with landmark_id == -1 in one step. Observations that already
// carry an id keep it (and, with exclusive, reserve it). With exclusive, pairs are assigned
// greedily in order of increasing Mahalanobis distance. Unassociated observations keep -1.
std::vector<Observation> associateObservations(const std::vector<Observation>& observations, const Pose2& pose,
                                               const Eigen::Matrix3d& covariance, const FieldMap& map,
                                               const AssociationConfig& config = AssociationConfig());

}  // namespace stereoloc
