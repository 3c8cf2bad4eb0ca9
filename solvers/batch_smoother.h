#pragma once
// Batch smoother: the whole trajectory as one nonlinear least-squares problem on Ceres
// (offline refinement; `stereoloc refine`, `localize --method batch`).
//
//   minimise  |prior(p_0)|^2 + sum_k |odometry(p_{k-1}, p_k)|^2 + sum |compass(p_k)|^2
//             + sum rho(|range_bearing(p_k, l_j)|^2)
//
// with the factors of factors/ (whitened by the upper square-root information), poses on the
// R^2 x SO(2) manifold (factors/pose_manifold.h), an optional robust loss rho on the
// observations, and per-pose marginal covariances (O(N) chain recursion, or ceres::Covariance).
// The graph of a known-landmark problem is a chain: every factor links one pose or two
// consecutive ones.
//
// The least-squares problem is solved by Levenberg-Marquardt on its block tridiagonal normal
// equations (solvers/chain_solver.h): time and memory linear in the number of steps (a few
// hundred bytes per pose), about 2 s for 100,000 steps. BatchSolver::Ceres solves the same
// problem with Ceres's sparse Cholesky instead (same optimum; for cross-checks).
//
// Use: feed the steps with process() (it returns the initial guess, cheap), then finish()
// solves and returns one Estimate per processed step. The first processed step is the initial
// time (its odometry is not applied), as for the EKF. Initial guess: a forward EKF pass (default),
// odometry chained from the initial belief (or the first global fix), or given estimates. An
// observation whose factor cannot be evaluated at the guess (a pixel factor's landmark behind
// the cameras) waits outside the solve until a solution brings it into view (docs/estimators.md).
// Kidnap (5.1.3): the filter pass's gate detects it; each re-initialisation after "lost" cuts the
// odometry chain and anchors the new segment on the global fix (cut_at_reinitialisation). The
// solve places each cut where the sightings of the unconfirmed stretch before the fix put it,
// keeps a cut only on the data's evidence, may move it back to an earlier fix, and with
// self-calibration undoes the cuts when they leave the calibration implausible (docs/estimators.md,
// "Where a cut goes").
// Self-calibration (BatchSmootherConfig::calibration, solvers/self_calibration.h): the odometry
// and stereo calibration as global parameter blocks of the same problem; the chain solver then
// solves the bordered system (a few dense columns beside the tridiagonal poses) in O(N), and
// calibration() returns the estimate with its marginal covariance.
#include <ceres/problem.h>

#include <Eigen/Core>
#include <algorithm>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "solvers/ekf.h"
#include "solvers/initialisation.h"
#include "solvers/self_calibration.h"
#include "solvers/smoother_common.h"
#include "solvers/data_association.h"
#include "src/core/estimator.h"
#include "src/core/exposure_offset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"

namespace stereoloc {

// Where the initial guess of the poses comes from.
enum class InitialGuess {
  Odometry,  // odometry chained from the initial belief / first global fix
  Filter,    // a forward EKF pass (solvers/ekf.h) with the same belief, gate and fixes: a guess
             // whose error does not grow with the trajectory, so the iterations do not either
};
std::string toString(InitialGuess guess);                    // "odometry", "filter"
InitialGuess initialGuessFromString(const std::string& name);  // throws stereoloc::Error

// How the per-pose marginal covariances are computed.
enum class CovarianceMethod {
  Chain,  // O(N): the information of a known-landmark graph is block tridiagonal (poses are
          // linked only by odometry), so its diagonal inverse blocks follow from one forward and
          // one backward (RTS) pass (chainMarginalCovariances, solvers/smoother_common.h)
  Ceres,  // ceres::Covariance with SPARSE_QR (SuiteSparse): general but O(N^2) here
};
std::string toString(CovarianceMethod method);                    // "chain", "ceres"
CovarianceMethod covarianceMethodFromString(const std::string& name);  // throws stereoloc::Error

// How the least-squares problem is minimised.
enum class BatchSolver {
  Chain,  // Levenberg-Marquardt on the block tridiagonal normal equations (solvers/chain_solver.h): O(N)
  Ceres,  // ceres::Solver, SPARSE_NORMAL_CHOLESKY with SuiteSparse: general, several times slower and larger
};
std::string toString(BatchSolver solver);                    // "chain", "ceres"
BatchSolver batchSolverFromString(const std::string& name);  // throws stereoloc::Error

// Where a long solve is, for a progress display (BatchSmootherConfig::progress).
struct BatchProgress {
  std::string phase;   // "solve" (iteration of a full-chain solve), "cut test", "covariance"
  long done = 0;       // solve: iterations so far; cut test: candidate cuts tested
  long total = 0;      // solve: the iteration limit; cut test: candidate cuts
  int iteration = 0;
  double cost = 0.0;   // current 1/2 sum |r|^2
};

struct BatchSmootherConfig {
  InitialBelief init;               // prior on the first pose; Global: the first global fix's
  GlobalFixFunction global_fix;     // empty: defaultGlobalFix() (solvers/initialisation.h)
  AssociationConfig association;    // for observations with landmark_id == -1 (at the initial guess)
  bool use_compass = true;          // add a compass factor when Step::compass is set
  RobustLossConfig loss;            // on the observation factors; scale in whitened units
  // Range-bearing (the thesis's form) or stereo pixel factors for observations with pixels
  // (solvers/smoother_common.h); the rig must be the dataset's for the pixel models.
  ObservationModelConfig observation_model;
  // Wheel slip the odometry's k |d| does not state (UnmodelledNoise::slip_rel_sigma,
  // solvers/smoother_common.h): fraction of each increment, added to the odometry factors.
  double slip_rel_sigma = 0.0;
  int max_iterations = 100;         // Levenberg-Marquardt iterations
  double function_tolerance = 1e-10;   // relative cost decrease that stops the solver
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  int num_threads = 1;              // BatchSolver::Ceres; results do not depend on it (tested)
  BatchSolver solver = BatchSolver::Chain;
  // Called during finish() (solve iterations, cut tests, covariance); may be empty.
  std::function<void(const BatchProgress&)> progress;
  InitialGuess initial_guess = InitialGuess::Filter;
  GateConfig gate;                  // of the filter pass (InitialGuess::Filter)
  bool compute_covariance = true;   // per-pose marginal covariances
  CovarianceMethod covariance_method = CovarianceMethod::Chain;
  // Kidnap (5.1.3): when the filter pass (InitialGuess::Filter) declares itself lost and a global
  // fix re-initialises it, the fix is tested (gate probability, 3 dof) against the odometry
  // chained from the last pose confirmed by an accepted observation. If it is inconsistent, the
  // odometry factor after the last confirmed pose becomes a candidate cut, and the poses from
  // there to the fix are re-guessed by chaining the odometry backwards from the fix. After the
  // solve with the cuts, each cut is verified by model selection: the problem is solved again
  // with that odometry factor restored, and the cut is kept only if it lowers 2 x cost by more
  // than the Bayesian information criterion's 3 ln(m) (m residuals; at least the gate's
  // chi-square(3) quantile), so outliers or a poor linearisation that misled the filter do not
  // cut the chain. A segment the data do not determine (singular information) is never cut
  // off. false: one unbroken chain.
  bool cut_at_reinitialisation = true;
  // Least rise of 2 x cost (whitened, after the residual variance factor) that restoring a cut's
  // odometry factor must cause for the cut to be kept. A kidnap is a gross event: on the
  // simulated kidnap the rise is ~1e5, while on real data (MR.CLAM) re-initialisations that are
  // not kidnaps rise by 50-180 and 10 % outliers without a robust loss by up to ~400; the BIC
  // alone (3 ln m, ~30) would keep those cuts and lose the odometry between them.
  double cut_min_evidence = 1000.0;
  // When the filter pass re-initialised (there are candidate cuts), `loss` is None and the first
  // solve fits badly (residual variance factor over 10): the batch begins again from the filter
  // pass's guess, and the solves up to the placing of the cuts and the re-pairing use a Cauchy
  // loss (scale 2.3849); least squares goes on from their solution. A lost filter's guess holds
  // gross errors that least squares does not leave: sightings from before a kidnap on poses the
  // guess put after it, pairings made at a wrong pose. With self-calibration they drag the
  // calibration into a wrong basin (docs/estimators.md, "Where a cut goes"). false: least
  // squares throughout.
  bool robust_start = true;
  // Self-calibration: the odometry block replaces every odometry factor by its calibrated form,
  // the stereo block every pixel factor (needs a pixel observation model). Only the part's
  // switches and prior sigmas are used here. The filter pass runs with the nominal calibration.
  SelfCalibrationConfig calibration;
  // With the exposure offset estimated (the image block and observation_model.unmodelled.
  // exposure_offset_sigma_s > 0): where its factors take each image's body rate from. The
  // wheels' rate keeps part of their noise and lags the turns, and the offset fitted against it
  // as if exact comes out shrunk and over-confident (docs/realistic_world.md).
  BodyRateSource exposure_rate = BodyRateSource::SmoothedPoses;
  // With the stereo calibration: the observations the filter pass paired (landmark_id -1 in the
  // input) are left out of a first solve on the identified landmarks, then paired again at each
  // solution with its calibration until no pairing changes (at most 3 passes); one the solution
  // cannot pair (outside every gate, or ambiguous) keeps the filter pass's pairing if the filter
  // pass fused that step's sightings (status tracking or reinitialised), and stays unpaired if it
  // only predicted there. false: the filter pass's pairings, made with the nominal calibration,
  // are final.
  bool reassociate_with_calibration = true;

  void validate() const;            // throws stereoloc::Error naming the field
};

enum class CovarianceStatus {
  NotComputed,    // compute_covariance was false, or the solve failed
  Ok,
  RankDeficient,  // the problem does not determine every pose (information singular)
};
std::string toString(CovarianceStatus status);  // "not_computed", "ok", "rank_deficient"

struct BatchSummary {
  bool solved = false;            // Ceres returned a usable solution
  bool converged = false;         // ... and reached a tolerance (not the iteration limit)
  int iterations = 0;             // of the full-chain solves (the first, and the last after cut tests)
  int cut_test_iterations = 0;    // of the windowed solves that test the candidate cuts
  double initial_cost = 0.0;      // 1/2 sum |r|^2 (with the robust loss applied)
  double final_cost = 0.0;
  double filter_seconds = 0.0;    // in process(): the initial guess (the EKF pass), buffering
  double solve_seconds = 0.0;     // in finish(): the solves, including the cut tests
  double cut_test_seconds = 0.0;  // part of solve_seconds
  double covariance_seconds = 0.0;
  int poses = 0;
  int odometry_factors = 0;
  int observation_factors = 0;
  int compass_factors = 0;
  int unassociated_observations = 0;  // landmark_id == -1 with no landmark inside the gate
  // Identified observations whose factor could not be evaluated at the initial guess (a pixel
  // factor's landmark behind the cameras): left out of the first solve, readmitted when a
  // solution brings the landmark into view.
  int observations_left_out_at_guess = 0;
  int observations_left_out = 0;      // ... of them, still not evaluable at the solution: not used
  int uninitialised_steps = 0;        // before the first global fix: no pose, not estimated
  CovarianceStatus covariance_status = CovarianceStatus::NotComputed;
  int segments = 0;               // pieces of the odometry chain (1 + cut_steps.size())
  std::vector<long> cut_steps;    // steps whose odometry factor was cut (kidnap), in order
  std::vector<long> reinit_steps; // the filter's re-initialisation step of each kept cut
  int withdrawn_cuts = 0;         // candidate cuts rejected by the likelihood-ratio test
  int cut_outliers = 0;           // ... of them, for a single sighting left out (an outlier) instead
  std::string message;            // the solver's termination message / covariance failure reason
};

class BatchSmoother : public Estimator {
 public:
  // map and odometry: those of the Dataset (Dataset::map, Dataset::odometry).
  BatchSmoother(const FieldMap& map, const OdometryParams& odometry, BatchSmootherConfig config = BatchSmootherConfig());

  std::string name() const override { return "batch"; }
  // Buffers the step and returns the initial guess for it (status Predicted, or Uninitialised
  // / Reinitialised before and at the first global fix). Throws stereoloc::Error on
  // non-increasing step numbers, unknown landmark ids and invalid values.
  Estimate process(const Step& step) override;
  // Solves and returns the smoothed trajectory, one Estimate per processed step (status
  // Tracking for estimated poses; covariance zero when it could not be computed, see summary()).
  // Calling it again returns the same result.
  std::vector<Estimate> finish() override;

  // Initial guess from other estimates (e.g. the EKF's finish()), matched by step number;
  // steps without an initialised estimate are chained from the previous pose by odometry.
  // Call before the first process().
  void setInitialEstimates(const std::vector<Estimate>& estimates);

  const BatchSummary& summary() const { return summary_; }
  // The calibration estimate of finish() (config.calibration); its covariance is zero when the
  // marginal covariances could not be computed.
  const CalibrationEstimate& calibration() const { return calibration_; }

 private:
  void solve();
  Estimate processStep(const Step& step);
  // The estimate setInitialEstimates gave for step, when it is usable.
  const Estimate* givenEstimate(long step) const;
  // The chain's first step (from the filter pass's first estimate, else the configured start or a
  // global fix): the prior, the guess and the step's status; Uninitialised while there is none.
  // A start from a fix clears the step's observations and compass (the fix used them).
  EstimateStatus startChain(Step& step, const Estimate* filtered, Pose2& guess);
  // A later step: the guess from the filter pass (and its candidate cut), else dead reckoning.
  EstimateStatus continueChain(Step& step, const Estimate* filtered, Pose2& guess);
  void smoothGuess(size_t first, std::vector<double>* x) const;
  void trackRejections(size_t index);
  bool cutAtReinitialisation(size_t index, const Estimate& fix, const Step& step);  // true: a candidate cut
  std::unique_ptr<Ekf> filter_;   // InitialGuess::Filter

  FieldMap map_;
  OdometryParams odometry_;
  BatchSmootherConfig config_;
  std::vector<Estimate> given_;   // setInitialEstimates, sorted by step
  // The processed steps, compact (about 50 bytes a step plus its observations): a long log is
  // held once here, without a vector per step.
  struct BufferedStep {
    long step = 0;
    double t = 0;                                   // s
    double d_left = 0, d_right = 0;                 // mm
    WheelIncrements noise;                          // mm, the travel of (B.6) (NoiseTravel)
    double compass = 0, compass_sigma = 0;          // rad; compass_sigma 0: no reading
    size_t observations_end = 0;                    // observations_[end of the previous step, this)
    BodyRate rate;  // at the step's images: the odometry's (bodyRate), then the smoothed poses'
  };
  class StepFactorSource;
  class Solve;  // one solve of the buffered steps (solvers/batch_solve.cpp)
  void buffer(const Step& step);
  size_t observationsBegin(size_t index) const { return index == 0 ? 0 : steps_[index - 1].observations_end; }
  // The buffered step observation o (index into observations_) belongs to.
  const BufferedStep& stepOf(size_t o) const {
    return *std::upper_bound(steps_.begin(), steps_.end(), o,
                             [](size_t i, const BufferedStep& b) { return i < b.observations_end; });
  }
  std::optional<BodyRateTracker> rate_tracker_;  // the steps' body rates (made at the first step)
  std::vector<BufferedStep> steps_;
  NoiseTravel noise_travel_{odometry_.readings};  // of every buffered step in order
  std::vector<Observation> observations_;  // of all buffered steps in order, identified
  std::vector<Estimate> guess_;   // initial guess per step
  long first_index_ = -1;         // index into steps_ of the first initialised step
  Pose2 prior_pose_;
  Eigen::Matrix3d prior_covariance_ = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d guess_covariance_ = Eigen::Matrix3d::Zero();  // dead-reckoned, for association
  // Kidnap handling (cut_at_reinitialisation).
  struct Cut {
    size_t index;                 // into steps_: the odometry factor into this pose is cut
    size_t reinit;                // into steps_: the filter's re-initialisation (global fix)
  };
  std::vector<Cut> cuts_;         // candidate (then verified) cuts, in step order
  long last_accepted_ = -1;       // index of the last step with an observation accepted by the filter's gate
  // (step index, observations before association) of the steps that needed association, in
  // step order: re-associated if a kidnap cut moves the pose.
  std::vector<std::pair<size_t, std::vector<Observation>>> raw_observations_;
  bool solved_ = false;
  std::vector<Estimate> result_;
  BatchSummary summary_;
  CalibrationEstimate calibration_;
};

}  // namespace stereoloc
