#pragma once
// The extended Kalman filter of thesis Algorithm 5 (section 5.1), with the validation gate and
// kidnap recovery of section 5.1.3.
//
//   Prediction (5.7), (5.9):  predictPose (src/core/odometry_model.h): p = p (+) u (B.16),
//                             P = J1 P J1^T + J2 U J2^T  with U from the wheel noise (B.10).
//   Update per observation (sequential, one landmark at a time, each linearised at the current
//   estimate), with h = predictRangeBearing (5.27) and H = dh/dp:
//       nu = z [-] h(p)            (bearing wrapped BEFORE gating and fusing)
//       S  = H P H^T + R           (5.14)
//       e2 = nu^T S^-1 nu          (5.20)
//       K  = P H^T S^-1            (5.19)
//       p  = p [+] K nu            (5.15)
//       P  = (I - K H) P (I - K H)^T + K R K^T   (Joseph form, 5.17)
//   Compass: a scalar update on theta (H = [0 0 1], wrapped innovation), applied before the
//   landmark observations of the same step.
//   Gate (5.20), per step: the sum of the fused observations' e2 (sequential innovations, so the
//   e2 of the stacked innovation at the prediction) against chi-square with their summed degrees
//   of freedom; while it fails, the observation with the largest e2 at the prediction is set
//   aside (not fused, a rejection) and the step fused again. One observation alone: (5.20).
//   Why jointly: docs/estimators.md, "Gate: joint compatibility of the step".
//   Lost (5.1.3): GateConfig::lost_after consecutive gated observations declare the robot lost;
//   from then on the filter predicts from odometry only and asks the global fix service every
//   step until a fix re-initialises it (Fig. 5.6).
//
// With a single observation per step, the update is exactly one Gauss-Newton step of the
// prior + range-bearing least-squares problem linearised at the prediction; the sliding-window
// smoother with W = 1 relies on that.
//
// Iterated update (EkfConfig::max_iterations > 1, the `iekf` method; not in the thesis): the
// same MAP problem solved by Gauss-Newton with step control instead of one step
// (solvers/iterated_update.h). Why: a stereo sighting constrains the pose to a thin curved set
// (range to ~1 %, bearing to ~0.02 deg), and one step from a prior 30 mm off puts the
// covariance's thin axis at the wrong angle. In the study's `line` scenario the first update
// then gave NEES 1250-6400 at one step, and the filter stayed over-confident for tens of steps.
//
// Self-calibration (EkfConfig::calibration, the `ekf:calib` method; not in the thesis): the
// wheel block c = (c_l, c_r, w), the stereo block q of solvers/self_calibration.h and, with a
// pixel model where the noise model states them, the smoothers' image block e, the row offset
// dv and each fused feature's offsets b become states beside the pose, x = (p, c, q, e, dv, b),
// with their priors' covariance and no process noise (constant for a run; a feature's b joins
// when it is first fused), but for the wheels when the noise model says they drift:
//   prediction  p' = p (+) u(c_l d_l, c_r d_r, w),  F = [J1 J_p'c 0; 0 I 0; 0 0 I],
//               P' = F P F^T + diag(J2 U J2^T, Q_c, 0)   (solvers/calibrated_models.h;
//               Q_c = wheelDriftVariance, 0 unless UnmodelledNoise::wheel_scale_drift or
//               wheel_base_drift)
//   update      a stereo sighting on its whitened pixel columns r(x) (the smoothers' pixel
//               factors, factors/stereo_pixel_*calibration_factor.h): nu = -r, H = dr/dx,
//               R = I, iterated to the MAP of prediction and sighting (the observation model
//               range_bearing: on calibratedSighting's range and bearing instead)
// with the same gate, Joseph form and joint gating as above; observations without pixels keep
// their own z and R, through the range block k = (c0, c1, c2, d_b) when it is estimated (a
// range-bearing sensor's range factor across its field of view and bearing offset,
// factors/range_bearing_calibration_factor.h; x = (p, c, q, k, e, dv, b)). With the field block
// (calibration.field, the `ekf:calib-field` method; a pixel model) the change f of the field's nine
// dimensions joins before the feature offsets, x = (p, c, q, [k], e, dv, f, b): every pixel
// sighting sees its landmark at l + J_l f (factors/field_shifted_factor.h), and a global fix,
// computed on the field's estimate, measures p + J (f_hat - f) with J = d fix / d f. The wheel base is
// considered, not estimated (its row of K is zero). Every global fix sees the sightings through
// the current calibration, and a lost filter re-anchors on a fix that agrees with its prediction
// (fused as a measurement of the pose) instead of restarting there. Why each:
// docs/estimators.md, "A self-calibrating EKF".
//
// Considered calibration (calibration.consider, the `ekf:consider` method): the same joint state
// with every calibration row of K zero, the Schmidt-Kalman filter. The calibration stays the
// given one; its uncertainty, the image errors, each feature's offsets and, with the field block,
// the field's dimensions still enter every covariance, so the pose's covariance is honest about
// them (docs/estimators.md, "A filter that considers its calibration").
#include <Eigen/Core>
#include <map>
#include <string>
#include <optional>
#include <unordered_map>
#include <vector>

#include "solvers/global_fix_hypotheses.h"
#include "solvers/self_calibration.h"
#include "solvers/smoother_common.h"
#include "solvers/data_association.h"
#include "solvers/initialisation.h"
#include "solvers/iterated_update.h"
#include "solvers/validation_gate.h"
#include "src/core/estimator.h"
#include "src/core/exposure_offset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"

namespace stereoloc {

struct EkfConfig {
  InitialBelief init;                // start belief; default: wait for a global fix
  GateConfig gate;                   // (5.20) probability (2 dof) and lost_after
  // false reproduces Figs. 5.3-5.5 (every observation fused). A random start (5.1.4) needs it
  // false: its first updates linearise far from the truth and would be gated, so lost at once.
  bool gate_enabled = true;
  AssociationConfig association;     // for observations with landmark_id == -1
  bool use_compass = true;           // fuse Step::compass when present
  // Chi-square probability (1 dof) of updateCompass's gate; process() tests the compass with the
  // step's sightings at GateConfig::probability.
  double compass_gate_probability = 0.99;
  bool reinitialise_when_lost = true;       // ask global_fix when lost; false: stay lost
  GlobalFixFunction global_fix;      // empty: defaultGlobalFix() (solvers/global_fix.h)
  // Hand-over to the global start: while the belief's larger position standard deviation
  // exceeds this (mm), every step first asks global_fix, and a fix whose own position spread is
  // smaller restarts the filter there. With the thesis's random start (section 5.1.4: a
  // covariance as large as the field) the gate of every sighting holds several landmarks of its
  // type, so association picks a wrong one and the filter settles on a wrong pose; a fix needs
  // no prior. Costs one fix attempt per step until then (a few microseconds). 0: off
  // (Algorithm 5 as printed).
  double handover_sigma_mm = 150.0;
  // While the belief is that wide and no global fix is possible (no identifiable landmark in
  // view), the filter follows a bank of hypotheses spawned from the one-landmark fixes of each
  // ambiguous sighting with the compass over every landmark of its type (solvers/
  // global_fix_hypotheses.h) and reports the mixture's mean and covariance; once the mixture's
  // position spread is below handover_sigma_mm, the filter goes on from it. Only until the belief
  // has been narrower than handover_sigma_mm once (a wide start). false: wait for a global fix.
  bool multi_hypothesis_start = true;
  HypothesisConfig hypotheses;
  // Gauss-Newton steps of each range-bearing update (solvers/iterated_update.h); 1 is
  // Algorithm 5 as printed.
  int max_iterations = 1;
  double iteration_tolerance = 1e-6;  // mm and rad: stop when no component of the step moves more
  // Self-calibration: the wheel, stereo and range blocks (odometry, stereo, range) with their
  // prior sigmas; SelfCalibrationConfig's other options are the smoothers'. Needs
  // max_iterations == 1.
  SelfCalibrationConfig calibration;
  // With calibration.stereo: the rig that took the pixels and their noise (pixelCovarianceFor,
  // the marking terms as white noise); with calibration.odometry: unmodelled.slip_rel_sigma is
  // added to the wheel noise. Unused without self-calibration.
  ObservationModelConfig observation_model;
  // false: finish() returns only the newest estimate, so memory stays constant on an unbounded
  // stream (the Localizer's); true: one Estimate per step.
  bool keep_history = true;
};

// What one update did: for the kidnap study's plots of the innovation and e^2 (Figs. 5.4, 5.5).
struct EkfUpdateRecord {
  long step = 0;
  int landmark_id = -1;            // -1 for the compass or an observation that could not be associated
  bool compass = false;
  bool associated = true;          // false: landmark_id was -1 and no landmark fell inside the gate
  // At the belief the step's earlier observations left (for the first one: the prediction).
  Eigen::Vector2d innovation = Eigen::Vector2d::Zero();       // (mm, rad); compass: (rad, 0)
  Eigen::Matrix2d innovation_covariance = Eigen::Matrix2d::Zero();  // S; compass: S(0,0)
  double mahalanobis_squared = 0.0;  // e^2 (5.20)
  bool accepted = false;             // passed the gate and was fused
  int observation_index = -1;        // in Step::observations; -1 for the compass
};

class Ekf : public Estimator {
 public:
  Ekf(const FieldMap& map, const OdometryParams& odometry, EkfConfig config = EkfConfig());

  std::string name() const override { return "ekf"; }
  // The first processed step defines the initial time: its odometry is not applied (the initial
  // belief is the pose at that step). Throws stereoloc::Error on non-increasing step numbers,
  // unknown landmark ids or invalid R / compass sigma.
  Estimate process(const Step& step) override;
  std::vector<Estimate> finish() override { return estimates_; }

  // Lower-level operations (benchmarks, tests, the smoother comparison). They act on the
  // current belief regardless of the lost state and do not touch the lost counter.
  void reset(const Pose2& pose, const Eigen::Matrix3d& covariance);
  void predict(double d_left, double d_right);
  // Gates (alone, at the current belief) and, if accepted (or the gate is disabled), fuses one
  // range-bearing observation of a landmark at `landmark` (mm, world). Skipped (not accepted)
  // when h is degenerate.
  EkfUpdateRecord updateRangeBearing(const Observation& obs, const Eigen::Vector2d& landmark);
  EkfUpdateRecord updateCompass(double heading, double sigma);

  bool initialised() const { return initialised_; }
  bool lost() const { return lost_; }
  const Pose2& pose() const { return pose_; }
  const Eigen::Matrix3d& covariance() const { return P_; }
  const ValidationGate& gate() const { return gate_; }
  // The updates of the last processed step, in order.
  const std::vector<EkfUpdateRecord>& lastUpdates() const { return updates_; }
  // With EkfConfig::calibration: the calibration states and their marginal covariance now
  // (considered, calibration.consider: the given calibration and its prior, never updated);
  // nullopt without.
  std::optional<CalibrationEstimate> calibration() const;

  // Everything a processed step changes, to go back to: restoreState() and then the same steps
  // again give the same estimates, bit for bit (the Localizer replays the steps since a late
  // observation's step this way). finish() then holds no estimate made after the save.
  class State;
  State saveState() const;
  void restoreState(const State& state);

 private:
  // One observation's innovation at the current belief; fused if `fuse` and (unless `gated` is
  // false) it passes the gate (5.20).
  EkfUpdateRecord fuseRangeBearing(const Observation& obs, const Eigen::Vector2d& landmark, bool gated, bool fuse);
  EkfUpdateRecord fuseCompass(double heading, double sigma, bool gated, bool fuse);
  // The step's compass and sightings (except the `excluded` ones; index size(): the compass)
  // fused ungated from the current belief, in order; sums the e^2 and degrees of freedom of the
  // fused ones. Unidentified sightings are associated at the belief the earlier ones left.
  std::vector<EkfUpdateRecord> fuseStep(const Step& step, bool wide, const std::vector<bool>& excluded,
                                        double* joint_e2, int* joint_dof);
  double jointThreshold(int dof);  // chi2Quantile(gate.probability, dof), computed once per dof
  void validateStep(const Step& step) const;  // throws stereoloc::Error naming the step
  // The step's status after prediction, fixes and updates (process() records the estimate).
  EstimateStatus advance(const Step& step, bool first);
  // While the belief is `wide` (spread over handover_sigma_mm): a global fix narrower than it,
  // or the hypothesis bank's mixture; nullopt when neither decides the step.
  std::optional<EstimateStatus> startFromWideBelief(const Step& step, bool first, bool wide);
  // fuseStep under the joint gate, setting aside the least compatible observation until the
  // fused ones pass; the belief is left at the accepted ones.
  std::vector<EkfUpdateRecord> fuseJointlyGated(const Step& step, bool wide);
  // Index (in step.observations; their count for the compass) of the accepted record with the
  // largest e^2 at the prediction.
  size_t leastCompatible(const Step& step, const std::vector<EkfUpdateRecord>& recs, const Pose2& predicted,
                         const Eigen::Matrix3d& predicted_covariance) const;
  // Records the step's updates and feeds the lost policy (5.1.3).
  EstimateStatus recordUpdates(const Step& step, const std::vector<EkfUpdateRecord>& recs);
  bool tryGlobalFix(const Step& step);
  // Self-calibrating: fuse a fix that agrees; false: restart. J_fix_field: with the field block,
  // d fix / d f (fixFieldJacobian).
  using FixFieldJacobian = Eigen::Matrix<double, 3, kFieldDimensionCount>;
  bool reanchor(const PoseFix& fix, const std::optional<FixFieldJacobian>& J_fix_field);
  // reset() on the fix, with the field block the pose's covariance and correlation through it.
  void restartOnFix(const PoseFix& fix, const std::optional<FixFieldJacobian>& J_fix_field);
  // The global fix of the sightings `seen` on the map as the filter sees the field: the given map,
  // or with the field block its dimensions changed by the block's estimate.
  std::optional<PoseFix> fixOnFieldEstimate(const Step& seen) const;
  // With the field block a fix (fixOnFieldEstimate) measures the pose through the field's
  // estimate: fix = p + J (f_hat - f) to first order, J = d fix / d f by central differences of
  // the fix over each dimension. nullopt when a changed field gives no fix.
  std::optional<FixFieldJacobian> fixFieldJacobian(const Step& seen) const;
  Estimate makeEstimate(const Step& step, EstimateStatus status) const;

  // Self-calibration (EkfConfig::calibration).
  bool calibrating() const { return joint_.rows() > 3; }
  // Sets the pose belief; the calibration keeps its covariance, uncorrelated with the new pose.
  void setPoseBelief(const Pose2& pose, const Eigen::Matrix3d& covariance);
  void predictCalibrated(double d_left, double d_right);
  // The innovation of `obs` against `landmark` on the joint state (pixelInnovation, or range and
  // bearing): nu, S, H and R; nullopt when the sighting cannot be predicted (the landmark at the
  // pose or behind the cameras, the calibrated disparity not positive).
  struct JointInnovation {
    Eigen::VectorXd nu;  // 2: range-bearing (mm, rad) or whitened pixel columns
    Eigen::MatrixXd S, R;
    Eigen::MatrixXd H;  // 2 x the joint state's dimension
    double e2 = 0.0;
  };
  std::optional<JointInnovation> jointInnovation(const Observation& obs, const Landmark& landmark) const;
  // The stereo block's update in pixel space (the pixel columns u_l, u_r of
  // factors/stereo_pixel_calibration_factor.h, whitened), where the noise is: no conversion bias
  // for the calibration to absorb.
  std::optional<JointInnovation> pixelInnovation(const Observation& obs, const Landmark& landmark) const;
  EkfUpdateRecord fuseCalibrated(const Observation& obs, const Landmark& landmark, bool gated, bool fuse);
  // Index of the landmark's feature offsets in the joint state; -1 when they are not states.
  Eigen::Index featureAt(int landmark_id) const;
  // Adds the landmark's offsets as states with their prior (uncorrelated with the rest) when the
  // noise model states them and they are not states yet; false when nothing was added.
  bool addFeatureOffsets(const Landmark& landmark);
  // The Schmidt gain: the wheel base's row of K zero, or with calibration.consider every
  // calibration state's.
  void considerStates(Eigen::MatrixXd& K) const;
  // x (+) K nu on the joint state with the Joseph form (5.17); H the measurement's, R its noise.
  void applyJointUpdate(const Eigen::MatrixXd& K, const Eigen::VectorXd& nu, const Eigen::MatrixXd& H,
                        const Eigen::MatrixXd& R);
  // The joint covariance after a gain K (any K: the Joseph form, 5.17), and P_ from it.
  void josephUpdate(const Eigen::MatrixXd& K, const Eigen::MatrixXd& H, const Eigen::MatrixXd& R);
  // The joint state's mean (the covariance is joint_): read, set, and moved by dx in the joint
  // state's coordinates (the pose by plus, the rest additively).
  struct JointState {
    Pose2 pose;
    Eigen::Vector3d wheels;
    CalibrationEstimate::StereoVector head;
    CalibrationEstimate::ImageVector image;
    double row = 0.0;
    Eigen::VectorXd offsets;
    std::vector<int> feature_ids;  // whose offsets they are (restoring a state drops later ones)
    Eigen::Vector4d range = Eigen::Vector4d::Zero();
    FieldDimensionVector field = FieldDimensionVector::Zero();
  };
  JointState jointState() const { return {pose_, wheels_, head_, image_, row_, offsets_, feature_ids_, range_, field_}; }
  void setJointState(const JointState& x);
  JointState jointPlus(const JointState& x, const Eigen::VectorXd& dx) const;
  // What association sees: with the stereo block, the observation through the current q with
  // q's uncertainty in R (calibratedObservation); the observation itself otherwise.
  Observation associationView(const Observation& obs) const;
  // The step with every sighting as associationView gives it: what a global fix sees (a fix on
  // the given calibration would restart the filter where its range bias puts the robot).
  Step seenThroughCalibration(const Step& step) const;
  // With the row block: the observation with its right column's slide s dv taken out.
  Observation slid(const Observation& obs) const;
  // The map's landmark of obs.landmark_id at `xy` (its kind sets the pixel noise); for a landmark
  // outside the map, one of the observation's kind.
  Landmark landmarkOf(const Observation& obs, const Eigen::Vector2d& xy) const;

  FieldMap map_;  // a copy: the filter does not depend on the caller's lifetime
  OdometryParams odometry_;
  EkfConfig config_;
  IteratedUpdateOptions iteration_;
  ValidationGate gate_;
  double compass_threshold_;
  std::vector<double> joint_thresholds_;  // chi-square quantile of the gate by degrees of freedom
  Pose2 pose_;
  Eigen::Matrix3d P_ = Eigen::Matrix3d::Zero();
  bool initialised_ = false;
  bool lost_ = false;
  bool have_step_ = false;
  long last_step_ = 0;
  // The steps' body rates (made at the first step; part of State) and the rate of the step
  // being processed.
  std::optional<BodyRateTracker> rate_tracker_;
  Eigen::Vector3d wheels_walked_ = Eigen::Vector3d::Zero();  // CalibrationEstimate::wheels_walk_variance
  BodyRate step_rate_;
  std::vector<EkfUpdateRecord> updates_;
  std::vector<Estimate> estimates_;
  HypothesisBank bank_;
  bool localised_ = false;  // the belief has been narrower than handover_sigma_mm once
  // Self-calibration: the wheel, stereo and row states (nominal where not estimated), their offsets
  // in the joint state (-1: not estimated) and the joint covariance of (pose, wheels, head, row); P_ is
  // its pose block. Empty (0 x 0) without self-calibration.
  Eigen::Vector3d wheels_ = Eigen::Vector3d(1, 1, 75);
  CalibrationEstimate::StereoVector head_ = CalibrationEstimate().head;
  // The image block e, whitened (its prior is I; image_sigmas_ scales it), with the stereo block
  // and a pixel model when the noise model states lens or relative-rotation errors.
  CalibrationEstimate::ImageVector image_ = CalibrationEstimate::ImageVector::Zero();
  std::optional<CalibrationEstimate::ImageVector> image_sigmas_;
  double row_ = 0.0;  // the row block dv (px), with the stereo block when the noise model states it
  // The range block (c0, c1, c2, d_b; factors/range_bearing_calibration_factor.h): a range-bearing
  // sensor's range factor and bearing offset, in the update of every sighting that is not seen
  // through the stereo block.
  Eigen::Vector4d range_ = Eigen::Vector4d::Zero();
  bool rangeCalibrated(const Observation& obs) const { return range_at_ >= 0 && !(head_at_ >= 0 && obs.pixels); }
  // The field block f (the change of the field's nine dimensions, mm; factors/field_shifted_factor.h)
  // with the stereo block: every pixel sighting sees its landmark at l + J_l f.
  FieldDimensionVector field_ = FieldDimensionVector::Zero();
  std::unordered_map<int, Eigen::Matrix<double, 2, kFieldDimensionCount>> field_jacobian_;  // landmark id -> J_l
  int wheels_at_ = -1, head_at_ = -1, image_at_ = -1, row_at_ = -1, range_at_ = -1, field_at_ = -1;
  // The feature offsets (b_c, b_d) of each landmark fused so far whose offsets the noise model
  // states (featureOffsetSigmas), two states each from features_at_ on, in the order first fused.
  std::map<int, FeatureOffsetSigma> feature_sigmas_;  // by landmark id: the ones that may be added
  std::vector<int> feature_ids_;
  Eigen::VectorXd offsets_;
  Eigen::Index features_at_ = -1;
  Eigen::MatrixXd joint_;

 public:
  class State {
   private:
    friend class Ekf;
    JointState x;
    Eigen::Matrix3d P;
    Eigen::MatrixXd joint;
    ValidationGate gate;
    std::vector<PoseHypothesis> hypotheses;
    bool initialised = false, lost = false, have_step = false, localised = false;
    long last_step = 0;
    std::optional<BodyRateTracker> rate_tracker;
    Eigen::Vector3d wheels_walked = Eigen::Vector3d::Zero();
    size_t estimates = 0;
  };
};

}  // namespace stereoloc
