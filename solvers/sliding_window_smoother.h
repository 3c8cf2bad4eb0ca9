#pragma once
// Sliding-window (fixed-lag) smoother: the real-time form of the factor graph (`localize
// --method window`, `stream`, `Localizer`).
//
// The window holds the last W keyframe poses with their odometry, compass and observation
// factors; each step marginalises the oldest pose(s) into a MarginalPriorFactor (Schur
// complement) and solves the window from the previous solution. A pose's factors are linearised
// at its current estimate until it enters a marginal prior, then at that prior's point
// (WindowLinearisation); with first estimates instead, W = 1 and one Gauss-Newton iteration it is
// the EKF (5.7)-(5.19) step for step (tested). Gate and lost policy as in the EKF (5.20, 5.1.3);
// an observation the gate rejected against the one-step prediction is tested again against its
// pose's marginal in each later window and fused when it passes, so a prediction that was off
// does not cost the observations that correct it. A global fix which does not contradict the
// window's own prediction as a kidnap would (the gate was fooled by a start belief far in its
// tail, or by an over-confident prediction) re-anchors the window instead of restarting it: the
// poses, the odometry and the gated observations stay, so no step keeps its unsmoothed prior
// and the calibration keeps its evidence (docs/estimators.md, "Re-anchoring"). Steps without observations are composed into one
// odometry factor between keyframes (5.9); finish() smooths them given both keyframes.
// insertLate() adds an observation that arrives after later odometry at its own pose while that
// pose is in the window (exactly the in-order graph until a pose leaves the window), and reports
// older ones too late. Self-calibration (`calibration`, solvers/self_calibration.h): the wheel
// scales and wheel base, and the head tilt and baseline scale, are global parameter blocks with
// the factors of the self-calibrating batch; they are never marginalised, the marginal prior spans
// (oldest kept pose, calibration) so the information of marginalised poses on them is carried,
// and the odometry between keyframes is the calibrated factor of their steps composed
// (factors/composed_odometry_calibration_factor.h), so W keyframes span as many steps as without
// calibration. Wheels that drift (UnmodelledNoise::wheel_scale_drift, wheel_base_drift) are one
// block, constant over the window, whose marginal prior takes the random walk over each
// marginalised pose's travel (ageWheelInformation), the wheels' own prior with it. With the
// stereo block, gate, association and global fixes see each pixel observation
// through the current calibration estimate and its covariance, and a sighting that gates out
// through the prior calibration (calibratedObservation), so the given calibration's range bias
// does not reject the sightings that calibrate it. When the noise model states the lens estimate's
// or the cameras' relative rotation errors, they are the image block (imageErrorSigmas) of the
// pixel factors as in the batch, estimated after the window's first steps
// (image_errors_after_steps); the gate keeps them as pixel noise. With the cameras' exposure
// offset estimated, each pose's pixel factors are made again before each solve at the central
// difference of its neighbours' estimates, the body rate the offset acts through
// (exposure_rate). When the noise model states
// the rectified rows' misalignment, it is a further global block, the row offset dv (rowOffsetSigma), in the pixel
// factors of the features the frontend matched along their row (s dv on u_r). With it, a landmark
// whose constant pixel offsets the noise model states (featureOffsetSigmas, feature_offsets) gets
// its own global block (b_c, b_d) when it is first fused, with their zero-mean prior, and its
// sightings' factors carry it instead of its constant as white noise, which a short window would
// average over the sightings as if it did not repeat; the gate ignores these offsets (a fraction
// of a pixel). Memory is bounded by W, restart_buffer_steps and the landmarks seen (plus one
// Estimate per step for finish() unless keep_history is off). Derivations: docs/estimators.md,
// "Smoothers". Sources: sliding_window_smoother.cpp (a step: prediction, keyframes, gate and
// factors), sliding_window_marginalisation.cpp (marginal priors, solve, covariances),
// sliding_window_late.cpp (insertLate), sliding_window_recovery.cpp (lost, fixes, failures).
#include <ceres/problem.h>

#include <Eigen/Core>
#include <array>
#include <deque>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "factors/pose_manifold.h"
#include "solvers/calibrated_models.h"
#include "solvers/initialisation.h"
#include "solvers/self_calibration.h"
#include "solvers/smoother_common.h"
#include "solvers/validation_gate.h"
#include "solvers/data_association.h"
#include "src/core/estimator.h"
#include "src/core/exposure_offset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"

namespace stereoloc {

// The linearisation point of a window pose's factors in the marginalisation and the covariances.
enum class WindowLinearisation {
  // The current estimate until the pose is in a marginal prior, then the prior's linearisation
  // point, in every factor on it: one point per pose, the prior's own (default).
  PriorPoint,
  // Each factor where it was created (an observation at the predicted pose): with W = 1 and one
  // Gauss-Newton iteration the EKF step for step.
  FirstEstimates,
  // The current estimate in every factor, also on a pose a marginal prior linearised elsewhere.
  Current,
};
std::string toString(WindowLinearisation l);                       // "prior_point", "first_estimates", "current"
WindowLinearisation windowLinearisationFromString(const std::string& name);  // throws stereoloc::Error

struct SlidingWindowConfig {
  int window = 20;                   // W: poses kept in the window (>= 1)
  InitialBelief init;                // start belief; default: wait for a global fix
  GlobalFixFunction global_fix;      // empty: defaultGlobalFix() (solvers/initialisation.h)
  GateConfig gate;                   // (5.20) probability (2 dof) and lost_after
  bool gate_enabled = true;          // false: every observation is fused
  AssociationConfig association;     // for observations with landmark_id == -1
  bool use_compass = true;           // add a compass factor when Step::compass is set
  double compass_gate_probability = 0.99;  // chi-square probability (1 dof) of the compass gate
  bool reinitialise_when_lost = true;      // ask the global fix when lost; false: stay lost
  // When lost, a global fix re-anchors the window (see the header) unless its distance to the
  // prediction, d^2 with the sum of both covariances (3 dof), exceeds both this probability's
  // chi-square quantile and restart_min_evidence; otherwise the window restarts at the fix. 0: a
  // loss always restarts the window, as the EKF does.
  double reanchor_probability = 0.999;
  // A restart cuts the odometry between the window and the fix, as the batch's cut does
  // (BatchSmootherConfig::cut_min_evidence, the same 1000): d^2 is the rise of 2 x cost that
  // keeping that odometry costs, and only a gross one is a kidnap. On real data the prediction is
  // over-confident (MR.CLAM: NEES 30-80), and a loss that is no kidnap has a d^2 of tens, up to
  // about 180 (docs/estimators.md, "Re-anchoring"); 0: the chi-square test alone.
  double restart_min_evidence = 1000.0;
  int max_iterations = 5;            // per step, Levenberg-Marquardt from the previous solution
  double max_solver_seconds = 0.0;   // per-step wall-clock bound on the solve; 0 = none (a time
                                     // bound makes the result depend on the machine)
  bool gauss_newton = false;         // true: an (almost) infinite trust region, i.e. pure
                                     // Gauss-Newton steps (the EKF comparison)
  // Where the factors are linearised for the marginal priors and the covariances (the solve
  // itself always uses the current estimate); see WindowLinearisation. Self-calibration always
  // linearises at the current estimate (see the .cpp).
  WindowLinearisation linearisation = WindowLinearisation::PriorPoint;
  // Observations the gate rejected against the one-step prediction are tested again after each
  // solve against their pose's marginal in the window, and fused when they pass (see the header).
  bool retest_gated = true;
  // Chi-square probability of that test (2 dof; 1 dof for the compass). Far wider than the gate:
  // against the window's marginal it only has to catch outliers (docs/estimators.md, "Gate").
  double retest_probability = 0.9999;
  bool sparse_solver = true;         // SPARSE_NORMAL_CHOLESKY (SuiteSparse); false: DENSE_NORMAL_CHOLESKY
  int final_iterations = 50;         // finish(): iterations of the last solve of the window
  // Per-step stopping rules: the warm start is already close, so a relative cost decrease of
  // 1e-6 (far below the noise) ends the step; tighten them for exact comparisons.
  double function_tolerance = 1e-6;
  double gradient_tolerance = 1e-10;
  double parameter_tolerance = 1e-8;
  bool keep_history = true;          // false: finish() returns only the final window
  // A step becomes a keyframe (a window pose) when it has observations or a compass reading,
  // or after this many steps since the last keyframe (>= 1; 1: every step is a keyframe).
  int keyframe_max_steps = 50;
  RobustLossConfig robust_loss;      // on the range-bearing factors (whitened units); none by default
  // Range-bearing (the thesis's form) or stereo pixel factors for observations with pixels
  // (solvers/smoother_common.h). The gate and the belief update always use range-bearing.
  ObservationModelConfig observation_model;
  // With a robust loss, the chi-square gate (and with it the lost policy) is off unless this is
  // set: the loss then plays the gate's role (see the header comment).
  bool gate_with_robust_loss = false;
  // The odometry (and compass) of the last this-many steps is kept so that late observations
  // of one of them can start the window, or restart it when lost, from a global fix at their
  // step (insertLate); 0: late observations cannot.
  int restart_buffer_steps = 100;
  // Self-calibration: odometry and/or stereo blocks with the priors of SelfCalibrationConfig (its
  // sigmas; `residuals`, `use_compass` and `max_iterations` are taken from this config:
  // pixel columns unless observation_model is Pixels). Stereo needs observation_model.rig.
  SelfCalibrationConfig calibration;
  // With the image block (calibration.image_errors and a noise model that states its errors):
  // the steps after which the window estimates it. Before, the block stays at its prior mean and
  // the sightings keep its errors as pixel noise: fitted to a window's first few sightings its
  // twelve parameters, weakly determined, can with the stereo block settle the first poses
  // tens of mm off, which the marginal prior then keeps (docs/realistic_world.md). 0: from the
  // first step (then a window as long as the data is the batch).
  int image_errors_after_steps = 20;
  // With the exposure offset estimated (the image block and observation_model.unmodelled.
  // exposure_offset_sigma_s > 0): where its factors take each image's body rate from. The
  // wheels' rate lags the turns and keeps part of their noise, and an offset fitted against it as
  // if exact comes out shrunk and over-confident; SmoothedPoses re-makes, before each solve, the
  // factors of every window pose between two others no more than BodyRateTracker's 0.5 s apart
  // at the central difference of their estimates (the newest pose keeps the wheels' rate until
  // the next step). Odometry: the wheels' rate throughout (a window as long as the data is then
  // the batch with the same source).
  BodyRateSource exposure_rate = BodyRateSource::SmoothedPoses;

  void validate() const;             // throws stereoloc::Error naming the field
};

// What insertLate did with the observations of an earlier step.
enum class LateObservationStatus {
  Inserted,     // the step is in the window: its observations went through gate and association
                // (none given: nothing changes)
  TooLate,      // the step's pose has left the window (marginalised or before a re-start)
  NotTracking,  // uninitialised or lost: observations are not fused (as in process())
};
std::string toString(LateObservationStatus status);

struct LateObservationResult {
  LateObservationStatus status = LateObservationStatus::TooLate;
  int accepted = 0;   // observations fused (Inserted only)
  int rejected = 0;   // gated or not associable (Inserted only)
  Estimate estimate;  // the real-time estimate of the newest step afterwards (current())
};

// Counters for tests and benchmarks.
struct SlidingWindowStats {
  long steps = 0;
  long marginalisations = 0;
  long reinitialisations = 0;
  long accepted_observations = 0;
  long rejected_observations = 0;   // gated or not associable
  long solver_iterations = 0;       // summed over steps
  long keyframes = 0;               // window poses created (including re-initialisations)
  long late_inserted = 0;           // insertLate calls whose step was in the window
  long late_too_late = 0;           // insertLate calls whose step had left the window
  long reanchorings = 0;            // losses resolved by a global fix that agreed with the window
  long readmitted_observations = 0;  // gated at first, fused when tested against a later window
};

class SlidingWindowSmoother : public Estimator {
 public:
  // map and odometry: those of the Dataset (Dataset::map, Dataset::odometry).
  SlidingWindowSmoother(const FieldMap& map, const OdometryParams& odometry,
                        SlidingWindowConfig config = SlidingWindowConfig());
  ~SlidingWindowSmoother() override;
  SlidingWindowSmoother(const SlidingWindowSmoother&) = delete;
  SlidingWindowSmoother& operator=(const SlidingWindowSmoother&) = delete;

  std::string name() const override { return "window"; }
  // The real-time estimate: the newest pose and its marginal covariance after this step.
  // The first processed step is the initial time (its odometry is not applied). Throws
  // stereoloc::Error on non-increasing step numbers, unknown landmark ids, invalid values, and
  // when the step fails halfway (Ceres fails, the window's information is rank deficient, the
  // global fix throws): the window is then given up as a loss would restart it. Its poses go to
  // the history as the step found them, the failed step has none, the calibration keeps its
  // estimate from before the step as the prior of the next window, and processing goes on from
  // the next global fix.
  Estimate process(const Step& step) override;
  // Solves the final window (final_iterations) and returns one Estimate per processed step:
  // poses that left the window keep their estimate and covariance from the time they were
  // marginalised; the final window is smoothed. Processing may not continue afterwards.
  std::vector<Estimate> finish() override;
  // Observations of the already processed step `step` (see the header comment): fused at its
  // own pose when it is in the window, then the window is solved again. Throws stereoloc::Error
  // for a step that was not processed (later than the newest or skipped) or invalid observations,
  // and when the insertion fails halfway, which gives the window up as process() does (the
  // processed steps keep their estimates).
  LateObservationResult insertLate(long step, const std::vector<Observation>& observations);
  // The real-time estimate of the newest processed step (the newest keyframe composed with the
  // odometry since it, for a non-keyframe step). Uninitialised before the first pose.
  Estimate current() const;

  int windowSize() const { return static_cast<int>(nodes_.size()); }
  bool initialised() const { return !nodes_.empty(); }
  // The calibration estimate with its marginal covariance after the last step (after finish():
  // the final window's); nullopt without self-calibration.
  std::optional<CalibrationEstimate> calibration() const;
  bool lost() const { return lost_; }
  const SlidingWindowStats& stats() const { return stats_; }

 private:
  // A step that is not a keyframe: its odometry relative to the keyframe before it.
  struct Intermediate {
    long step = 0;
    double t = 0.0;
    Pose2 rel;                             // relative to the keyframe (mm, mm, rad)
    Eigen::Matrix3d rel_covariance = Eigen::Matrix3d::Zero();
    EstimateStatus status = EstimateStatus::Predicted;
    double d_left = 0.0, d_right = 0.0;    // this step's wheel increments (mm), for insertLate
    WheelIncrements noise;                 // mm, their travel of (B.6) (NoiseTravel)
    Eigen::Matrix3d rel_wheels = Eigen::Matrix3d::Zero();  // d rel / d wheel calibration
    BodyRate rate;                         // at the step's images (bodyRate)
  };
  struct Node {
    long step = 0;
    double t = 0.0;
    std::array<double, 3> x{};           // current estimate (x, y, theta)
    EstimateStatus status = EstimateStatus::Tracking;
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // last marginal computed
    // Its cross-covariance with the wheel calibration (rows: pose, columns: c_l, c_r, w), computed
    // with `covariance` (odometry self-calibration only).
    Eigen::Matrix3d wheels_cross = Eigen::Matrix3d::Zero();
    int slot = 0;                        // position in nodes_, refreshed before linearising
    // Joint marginal covariance with the next window pose (6x6: this, next), when computed.
    Eigen::Matrix<double, 6, 6> joint_next = Eigen::Matrix<double, 6, 6>::Zero();
    bool have_joint_next = false;
    std::vector<Intermediate> after;     // the non-keyframe steps that follow this keyframe
    Pose2 rel_to_next;                   // the composed odometry to the next keyframe and its covariance
    Eigen::Matrix3d rel_to_next_covariance = Eigen::Matrix3d::Zero();
    double d_left = 0.0, d_right = 0.0;  // this step's wheel increments (mm), for insertLate
    WheelIncrements noise;               // mm, their travel of (B.6) (NoiseTravel)
    BodyRate rate;                       // at the step's images (bodyRate)
    std::vector<Observation> gated;      // observations the gate rejected here (reanchor, retestGated)
    std::vector<int> landmarks;          // the landmarks of the observations fused here
    std::optional<std::pair<double, double>> gated_compass;  // a gated reading and its sigma (rad)
    // Set when the pose enters a marginal prior: that prior's linearisation point of it
    // (WindowLinearisation::PriorPoint).
    std::optional<std::array<double, 3>> prior_point;
  };
  // Self-calibration blocks. A factor names its blocks (after its poses, in its block order) by
  // their index in calib_, which is also their order in the window's variables: the wheels, the
  // head and the row offset when enabled, then one feature-offset block per landmark in the order
  // the landmarks were first fused.
  using Calib = int;
  struct CalibBlock {
    double* data = nullptr;
    int size = 0;
    int offset = 0;  // within the calibration variables (calib_covariance_)
  };
  // A landmark's feature offsets: the entries of (b_c, b_d) the noise model states, in that
  // order, in the first calibSize(block) entries of `value`; an entry it does not state is no
  // parameter (held at zero).
  struct FeatureBlock {
    int landmark_id = -1;
    FeatureOffsetSigma sigma;
    std::array<double, 2> value{};
    Calib block = -1;
  };
  struct Factor {
    std::unique_ptr<ceres::CostFunction> cost;
    std::vector<Node*> nodes;
    std::vector<Calib> calib;                           // calibration blocks after the nodes
    std::vector<std::array<double, 3>> linearisation;  // first estimates of the nodes
    ceres::ResidualBlockId id = nullptr;
    bool robust = false;                                // carries robust_loss
    bool odometry = false;                              // the odometry between consecutive poses
    // A sighting whose factor depends on its pose's body rate (the exposure offset estimated):
    // what refreshExposureRates re-makes it from.
    std::optional<Observation> rate_sighting;
    const Landmark* rate_landmark = nullptr;
    bool rate_image_free = false;  // made with the image block free (its errors not in the pixel noise)
  };

  void startWindow(const Step& step, const Pose2& pose, const Eigen::Matrix3d& covariance, EstimateStatus status);
  void addFactor(ceres::CostFunction* cost, std::vector<Node*> nodes, bool robust = false,
                 std::vector<Calib> calib = {});
  using StereoBlock = CalibrationEstimate::StereoVector;
  Calib addCalibBlock(double* data, int size);  // registers it after the others
  double* calibData(Calib c) const { return calib_[static_cast<size_t>(c)].data; }
  int calibSize(Calib c) const { return calib_[static_cast<size_t>(c)].size; }
  int calibOffset(Calib c) const { return calib_[static_cast<size_t>(c)].offset; }
  bool rowBlock() const { return row_sigma_.has_value(); }
  std::vector<Calib> calibBlocks() const;  // all of them, in variable order
  CalibrationEstimate::StereoMatrix headCovariance() const;  // the stereo block's part of calib_covariance_
  int calibDim() const { return calib_dim_; }
  // The feature-offset block of landmark `lm`, created with its prior at the first call; null
  // when its offsets are not estimated (no row block, feature_offsets off, none stated for its kind).
  const FeatureBlock* featureBlock(const Landmark& lm);
  void relinearise();                      // every factor's linearisation point := current values
  // The odometry prediction of one step with the current wheel calibration (the nominal one
  // without odometry calibration); J_c as in predictCalibratedStep (left alone without it).
  PosePrediction predictStep(const Pose2& rel, const Eigen::Matrix3d& C, double d_left, double d_right,
                             Eigen::Matrix3d* J_c = nullptr) const;
  // The covariance of keyframe k composed with odometry r (rel_covariance, d r / d wheels
  // rel_wheels; A1, A2 the composition's Jacobians (B.18), (B.19)): (5.9), and with odometry
  // self-calibration the wheel calibration's uncertainty and its correlation with k's pose.
  Eigen::Matrix3d composedCovariance(const Node& k, const Eigen::Matrix3d& A1, const Eigen::Matrix3d& A2,
                                     const Eigen::Matrix3d& rel_covariance, const Eigen::Matrix3d& rel_wheels) const;
  // The factor's contribution to the normal equations (accumulateNormalEquations), weighted by
  // the robust loss when it carries one. Returns false when it cannot be evaluated.
  bool accumulate(const Factor& f, const std::vector<const double*>& cur, const std::vector<const double*>& lin,
                  const std::vector<int>& off, Eigen::MatrixXd& H, Eigen::VectorXd& g) const;
  // Where factor f's j-th pose is linearised for marginalisation and covariances (config linearisation).
  const double* linearisationPoint(const Factor& f, size_t j) const;
  // Estimates of the non-keyframe steps after node `k` (the next window pose `next`, or none).
  void pushIntermediates(const Node& k, const Node* next);
  void removeFactor(size_t index);
  // The factors touching one pose and their normal equations (marginaliseOldest).
  struct Neighbourhood {
    std::vector<size_t> touching;  // indices into factors_
    std::vector<Node*> vars;       // the pose first, then the poses the factors link it to
    std::vector<Calib> calib;      // the calibration blocks the factors see, after the poses
    Eigen::MatrixXd H;
    Eigen::VectorXd g;
  };
  Neighbourhood neighbourhoodOf(Node* o) const;
  // The marginal prior (Hm, gm) of o's neighbourhood `nb` after o's Schur complement, its wheel
  // block walked over the travel from o to the next window pose when the wheels drift
  // (UnmodelledNoise::wheel_scale_drift; addRandomWalk).
  void ageWheelInformation(const Neighbourhood& nb, const Node& o, Eigen::MatrixXd& Hm, Eigen::VectorXd& gm) const;
  void marginaliseOldest();
  void finaliseWindow();                // moves every window pose into the history, clears the problem
  void addCalibrationPrior();           // the calibration's marginal as one prior factor (none without)
  void dropNewest();                    // removes the newest pose and its factors
  void solve(int max_iterations);
  void computeCovariances(bool all);    // newest and oldest (or all) marginal covariances
  // The Gauss-Newton information of the window (3n x 3n, poses in nodes_ order; refreshes the
  // slots), factors linearised as for the covariances.
  Eigen::MatrixXd windowInformation();
  // The observation as the gate and the belief update see it: as measured, or with the stereo
  // head self-calibrated through the current estimate, then through the prior (see
  // fuseObservation); empty when no calibration gives it a range.
  std::vector<Observation> gateViews(const Observation& measured) const;
  // Which test fuseObservation applies: the gate (5.20), the wider test of retestGated
  // (retest_probability), or none (the step's joint test, fuseStep, decides).
  enum class ObservationTest { Gate, Retest, None };
  // Test, associate and add one observation at `node` with the belief (pose, P), which is
  // updated as by the EKF's sequential update; `used`: the landmarks already taken this step.
  // When fused, *e2 (if given) is its e^2 at the belief it was fused at.
  bool fuseObservation(const Observation& obs, Node* node, Pose2& pose, Eigen::Matrix3d& P, std::vector<int>& used,
                       ObservationTest test = ObservationTest::Gate, double* e2 = nullptr);
  // The landmark of an identified sighting, or the one `view` associates with at the belief
  // (pose, P) (appended to `used`); null for none.
  const Landmark* landmarkOf(const Observation& measured, const Observation& view, const Pose2& pose,
                             const Eigen::Matrix3d& P, std::vector<int>& used);
  // The factor of a fused sighting of `lm` at `node`: through the stereo calibration's blocks
  // (head, image, row, the feature's offsets) or the range calibration's when estimated, else
  // the plain observation factor.
  void addObservationFactor(const Observation& measured, const Landmark& lm, Node* node);
  // The stereo self-calibration's pixel factor of a sighting of `lm` taken at body rate `rate`,
  // and its calibration blocks; `image_free`: the image block is estimated (else its errors are
  // pixel noise).
  struct CalibratedCost {
    ceres::CostFunction* cost = nullptr;
    std::vector<Calib> blocks;
  };
  CalibratedCost stereoCalibrationCost(const Observation& measured, const Landmark& lm, const BodyRate& rate,
                                       bool image_free);
  // Whether the pixel factors read their pose's body rate (the exposure offset estimated) and
  // take it from the smoothed poses (SlidingWindowConfig::exposure_rate).
  bool exposureRatesFromPoses() const;
  // SmoothedPoses: each window pose between two others gets their central difference as its body
  // rate, and its rate-dependent factors are re-made with it (see SlidingWindowConfig).
  void refreshExposureRates();
  // The newest pose's compass and observations of `step`, tested jointly as the EKF does (Ekf::
  // process): fused in order from the prediction (pred, P_pred), each at the belief the earlier
  // ones left, while the sum of their e^2 fails the chi-square gate of the summed degrees of
  // freedom the one least compatible with the prediction is set aside and the step fused again.
  // Returns, per observation, whether it was fused (the compass in *compass_fused); (pose, P)
  // end at the belief after the fused ones. Adds the factors; gated ones are not recorded here.
  std::vector<bool> fuseStep(const Step& step, Node* node, const Pose2& pred, const Eigen::Matrix3d& P_pred,
                             Pose2& pose, Eigen::Matrix3d& P, bool* compass_fused);
  double jointThreshold(int dof);  // chi2Quantile(gate.probability, dof), computed once per dof
  // process() after its checks, with the step's travel of (B.6) (NoiseTravel; restartLate replays
  // the steps it keeps with theirs).
  Estimate track(const Step& step, const WheelIncrements& noise);
  // The newest pose's belief as the EKF would have it (gating and association) and its
  // prediction before the step's measurements.
  struct StepBelief {
    Pose2 pose;
    Eigen::Matrix3d P = Eigen::Matrix3d::Zero();
    Pose2 pred_pose;
    Eigen::Matrix3d pred_P = Eigen::Matrix3d::Zero();
  };
  void keepForRestart(const Step& step, const WheelIncrements& noise);  // recent_ (restartLate)
  Estimate startFromGlobalFix(const Step& step);  // no window yet: a fix starts it, or Uninitialised
  // The odometry since the newest keyframe composed with this step's, and the prediction.
  StepBelief predictFromNewestKeyframe(const Step& step);
  // A step that is no window pose: kept after the newest keyframe (Intermediate), predicted.
  Estimate recordIntermediate(const Step& step, const WheelIncrements& noise, const StepBelief& b);
  // A new window pose at `pose`, tied to the previous one by the odometry since it.
  void appendKeyframe(const Step& step, const WheelIncrements& noise, const Pose2& pose);
  // fuseStep, the gated observations recorded and the lost policy (5.1.3); the step's estimate
  // when the loss is recovered at once by a global fix (recoverFromLoss).
  std::optional<Estimate> fuseUnderGate(const Step& step, Node* node, StepBelief& b, bool* fused);
  // Makes the non-keyframe step k->after[j] a window pose (see insertLate).
  Node* promote(size_t k_index, size_t j);
  // The odometry factor between consecutive keyframes a and b: `between` are the steps after a
  // and before b, then b's own wheel increments; (rel, C) their composition and its covariance.
  // With odometry self-calibration the calibrated factor (per step for one step, composed for
  // more), otherwise the composed OdometryFactor.
  void addOdometry(Node* a, Node* b, const std::vector<Intermediate>& between, const Pose2& rel,
                   const Eigen::Matrix3d& C);
  // Uninitialised or lost: a global fix from late observations of a recent step restarts the
  // window there (see insertLate). False when there is no fix.
  bool restartLate(long step, const std::vector<Observation>& observations);
  LateObservationResult insertChecked(long step, const std::vector<Observation>& observations);  // insertLate's work
  bool tryGlobalFix(const Step& step, Estimate* out);
  // config_.global_fix on the step; with stereo self-calibration on its observations as the
  // current calibration sees them (calibratedObservation).
  std::optional<PoseFix> globalFix(const Step& step) const;
  // The gate declared the robot lost at the newest pose, whose prediction was (pred, P_pred), and
  // the global fix agrees with that prediction (chi-square test): the belief, not the window, was
  // wrong. Moves the window rigidly onto the fix, re-tests the gated observations of the window
  // against the re-solved marginals and keeps every pose. False (nothing changed) when the fix
  // disagrees: a real loss, which restarts the window.
  bool reanchor(const PoseFix& fix, const Pose2& pred, const Eigen::Matrix3d& P_pred);
  // Lost, and `step` (the newest pose, its observations set aside) has a global fix: reanchor,
  // or else restart the window at the fix. Returns the step's estimate.
  Estimate recoverFromLoss(const Step& step, const PoseFix& fix, const Pose2& pred_pose, const Eigen::Matrix3d& pred_P);
  // After a solve: each window pose's gated observations against its marginal in the window;
  // those that pass are fused and the window is solved again. Returns how many were fused.
  int retestGated();
  int retestObservations(Node& node);  // its gated observations (retestGated); returns how many were fused
  Estimate estimateOf(const Node& n) const;
  void pushHistory(const Estimate& e);
  // What a step or an insertion that fails halfway falls back to (abandonWindow): the window
  // poses' estimates and the calibration as it found them. Member buffers, so that taking it
  // each step allocates nothing once the window is full.
  struct Checkpoint {
    struct PoseState {
      long step = 0;
      std::array<double, 3> x{};
      Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
    };
    std::vector<PoseState> poses;
    std::vector<double> calibration;  // calib_'s blocks' values, in order
    size_t calib_blocks = 0;
    int calib_dim = 0;
    size_t features = 0;
    Eigen::MatrixXd calib_covariance;
  };
  void takeCheckpoint();
  // Gives the window up after a failure halfway through a step (no-throw but for allocation):
  // the pose of step `failed` is dropped (none: every pose stays), the others go back to the
  // checkpoint's estimates and move into the history with their marginals in the window (when
  // its information allows; else as last computed), the calibration is set back to the
  // checkpoint and becomes the prior of the next window, and the problem is built anew from it,
  // so that the next step waits for a global fix as after a restart.
  void abandonWindow(std::optional<long> failed);

  FieldMap map_;
  OdometryParams odometry_;
  SlidingWindowConfig config_;
  ValidationGate gate_;
  bool gate_enabled_;  // gate_enabled, and no robust loss unless gate_with_robust_loss
  double compass_threshold_;
  std::vector<double> joint_thresholds_;  // by degrees of freedom
  double retest_threshold_;
  double retest_threshold_compass_;
  PoseManifold manifold_;
  std::unique_ptr<ceres::Problem> problem_;
  std::deque<std::unique_ptr<Node>> nodes_;
  std::vector<std::unique_ptr<Factor>> factors_;
  bool lost_ = false;
  bool have_step_ = false;
  bool finished_ = false;
  long last_step_ = 0;
  // The steps' body rates (made at the first step) and the rate of the step being tracked.
  std::optional<BodyRateTracker> rate_tracker_;
  BodyRate step_rate_;
  std::vector<Estimate> history_;
  SlidingWindowStats stats_;
  std::unique_ptr<ceres::LossFunction> loss_;  // nullptr: no robust loss
  // Odometry composed since the newest keyframe (identity and zero after a keyframe).
  Pose2 rel_;
  Eigen::Matrix3d rel_covariance_ = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d rel_wheels_ = Eigen::Matrix3d::Zero();  // d rel_ / d wheel calibration
  int steps_since_keyframe_ = 0;
  struct RecentStep {
    Step step;              // without observations
    WheelIncrements noise;  // its travel of (B.6), kept for a replay (restartLate)
  };
  std::deque<RecentStep> recent_;  // the last restart_buffer_steps steps
  NoiseTravel noise_travel_{odometry_.readings};  // of every step in order (a replay reuses the kept travel)
  // Self-calibration blocks (factors/odometry_calibration_factor.h: c_l, c_r, w (mm);
  // factors/stereo_pixel_calibration_factor.h; the row offset; the feature offsets) and their
  // joint marginal covariance (calib_'s order) from the last covariance computation.
  Eigen::Vector3d wheels_ = Eigen::Vector3d(1.0, 1.0, 0.0);
  StereoBlock head_ = CalibrationEstimate().head;
  // The image block (imageErrorSigmas): the lens estimate's errors and the right camera's
  // rotation, whitened (parameter i is e_i / sigma_i, prior the identity), with their sigmas.
  CalibrationEstimate::ImageVector image_ = CalibrationEstimate::ImageVector::Zero();
  std::optional<CalibrationEstimate::ImageVector> image_sigmas_;
  bool image_free_ = false;  // the image block is estimated (image_errors_after_steps)
  Eigen::Vector4d range_ = Eigen::Vector4d::Zero();  // the range block (c0, c1, c2, d_b)
  double row_ = 0.0;                   // the row offset dv (px), with row_sigma_
  std::optional<double> row_sigma_;    // its prior sigma, when estimated
  // The stated feature-offset sigmas by landmark (featureOffsetSigmas; empty when not estimated),
  // and the blocks of the landmarks fused so far (a deque: the solver holds their addresses).
  std::unordered_map<int, FeatureOffsetSigma> feature_sigmas_;
  std::deque<FeatureBlock> features_;
  std::unordered_map<int, size_t> feature_index_;  // landmark id -> features_ index
  std::vector<CalibBlock> calib_;
  int calib_dim_ = 0;
  Eigen::Vector3d wheels_walked_ = Eigen::Vector3d::Zero();  // CalibrationEstimate::wheels_walk_variance
  Calib wheels_block_ = -1, head_block_ = -1, image_block_ = -1, row_block_ = -1, range_block_ = -1,
        field_block_ = -1;  // -1: not estimated
  // The field block (SelfCalibrationConfig::field): the change of the field's dimensions (mm),
  // and each landmark's d(x, y)/d(dimensions).
  Eigen::Matrix<double, kFieldDimensionCount, 1> field_ = Eigen::Matrix<double, kFieldDimensionCount, 1>::Zero();
  std::unordered_map<int, Eigen::Matrix<double, 2, kFieldDimensionCount>> field_jacobian_;
  Eigen::MatrixXd calib_covariance_;
  Checkpoint checkpoint_;
  WindowLinearisation linearisation_ = WindowLinearisation::PriorPoint;  // in effect
};

}  // namespace stereoloc
