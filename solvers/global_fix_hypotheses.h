#pragma once
// Multi-hypothesis global start from ambiguous sightings: how a tracker with a belief as wide as
// the field (the thesis's random start, 5.1.4) localises before it sees an identifiable landmark.
//
//   HypothesisBank bank(map, odometry);
//   bank.process(step, first);             // every step while the tracker's belief is wide
//   if (!bank.empty()) PoseFix m = bank.mixture();   // the MMSE estimate and its covariance
//
// A marking corner or junction has no identity, but with the compass its one-landmark fix (4.10)
// puts the robot at one pose per landmark of its type. When the bank is empty, every sighting of a
// step with a compass spawns one Gaussian hypothesis per candidate landmark (fix1 of
// solvers/global_fix.h, its sigma-point covariance); hypotheses outside the field are impossible
// (4.2.1). Each hypothesis is then an EKF of its own: odometry prediction (5.7, 5.9), compass, and
// the step's other sightings associated jointly at its own, narrow belief (data_association.h) and
// fused by iterated updates. Its log-likelihood adds, per sighting and compass reading,
//   -e2 / 2                  for an innovation inside the gate (e2 of (5.20)),
//   -chi2_gate / 2           for one outside it or with no landmark of its type in the gate,
// so a hypothesis pays for every sighting it cannot explain. Hypotheses whose log-likelihood falls
// more than prune_log_ratio below the best are dropped, duplicates (poses within the 3-dof gate
// of each other) merged, and the mixture with weights exp(log-likelihood) is the belief: its mean
// and its covariance about the mean (the same moments the particle filter reports, 5.37). The
// tracker takes over from the mixture's moments once their position spread is narrow (a single
// mode). Multiple-hypothesis localisation after Jensfelt and Kristensen, "Active global
// localisation for a mobile robot using multiple hypothesis tracking" (IEEE T-RA 17(5), 2001).
// Cost and measurements: docs/estimators.md, "Random start".
#include <Eigen/Core>
#include <utility>
#include <vector>

#include "solvers/data_association.h"
#include "solvers/global_fix.h"
#include "solvers/initialisation.h"
#include "solvers/iterated_update.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

struct HypothesisConfig {
  double gate_probability = 0.9999;          // chi-square probability (2 dof) of a sighting's gate
  double compass_gate_probability = 0.9999;  // chi-square probability (1 dof) of the compass gate
  // A hypothesis whose log-likelihood is this much below the best one's is dropped. ln(1e6): one
  // sighting more than the best left unexplained is not enough (a spurious detection), two are.
  double prune_log_ratio = 13.8;
  double merge_probability = 0.99;  // two hypotheses within this 3-dof gate of each other are one
  int max_hypotheses = 64;          // the most likely are kept
  int max_iterations = 5;           // Gauss-Newton steps of each sighting's update (solvers/iterated_update.h)
  // A hypothesis that explains none of the sightings of this many observed steps in a row is
  // dropped even when it is the best (all of them wrong: the bank empties and spawns again).
  int max_misses = 3;
  double bounds_margin_mm = 100.0;  // a hypothesis this far outside the map bounds is impossible
  AssociationConfig association;    // of a hypothesis's sightings at its own belief
  GlobalFixOptions fix_options = trackerFixOptions();  // the one-landmark fixes that spawn hypotheses
};

struct PoseHypothesis {
  Pose2 pose;                                            // mm, rad
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (x, y, theta)
  double log_likelihood = 0.0;                           // of the sightings since it was spawned
  int misses = 0;  // observed steps in a row whose sightings it explained none of
};

class HypothesisBank {
 public:
  HypothesisBank(const FieldMap& map, const OdometryParams& odometry, HypothesisConfig config = HypothesisConfig());

  // One step: predicts (unless `first`: no odometry before the initial step), updates, prunes and
  // merges the hypotheses; spawns new ones from the step's sightings when none is left. Expects
  // observations validated by the caller; an unknown landmark id throws stereoloc::Error.
  void process(const Step& step, bool first);
  void clear() { hypotheses_.clear(); }
  bool empty() const { return hypotheses_.empty(); }
  const std::vector<PoseHypothesis>& hypotheses() const { return hypotheses_; }  // most likely first
  // The bank's whole state is its hypotheses: set them back to what hypotheses() returned.
  void restore(std::vector<PoseHypothesis> hypotheses) { hypotheses_ = std::move(hypotheses); }
  std::vector<double> weights() const;  // normalised exp(log_likelihood), same order
  // Mean (circular in theta) and covariance about it of the weighted mixture. Requires !empty().
  PoseFix mixture() const;

 private:
  // Fuses the sightings (index `skip` excluded; identified ones keep their landmark) into h and
  // adds their log-likelihood terms. Returns false when the hypothesis became impossible.
  bool update(PoseHypothesis& h, const std::vector<Observation>& observations, int skip) const;
  void spawn(const Step& step);
  void pruneAndMerge();

  FieldMap map_;  // a copy: the bank does not depend on the caller's lifetime
  OdometryParams odometry_;
  HypothesisConfig config_;
  double gate_threshold_, compass_threshold_, merge_threshold_;
  IteratedUpdateOptions iteration_;
  std::vector<PoseHypothesis> hypotheses_;
};

}  // namespace stereoloc
