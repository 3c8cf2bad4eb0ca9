#pragma once
// Monte Carlo localisation: the particle filter of thesis Algorithm 6 (section 5.3).
//
//   Prediction: each particle draws its own wheel increments from the odometry noise model,
//     d ~ N(d_measured, Sigma_v)  (B.6),  u = controlVector(d)  (B.4, B.5),
//     plus N(0, diag(control_variance_floor)) on u, and is compounded: p = p (+) u  (B.16).
//   Weights (5.34): the Gaussian range-bearing likelihood of each observation, with the bearing
//     innovation wrapped, floored for robustness to outliers and wrong associations:
//       log w += max(-e2 / 2, log(likelihood_floor)),   e2 = nu^T R^-1 nu,  nu = z [-] h(p) (5.27)
//     (the compass contributes the same way on theta). Normalised in the log domain (5.35, 5.36).
//   Estimate (5.37): the weighted mean, with a circular mean for theta, and the weighted
//     covariance (theta deviations wrapped about the mean).
//   Resampling (5.38): systematic / low-variance by default; the thesis's sorted roulette
//     (multinomial draws on the weights sorted in decreasing order) as an option.
//   Re-injection: T particles replaced by uniform ones over the map bounds after resampling.
//     We re-inject only on steps that carried an observation: without one there is no evidence
//     to remove wrong particles, so re-injection would only dilute the belief.
// Speed (3000 particles, target 0.5 ms per step): structure-of-arrays particles with the cached
//   cos/sin of each heading; the bearing innovation is evaluated in the frame of the measured
//   bearing (an atan2 of cross and dot products, no wrap; see weight()), and the per-particle
//   sin/cos and atan2 are the inline polynomials of solvers/fast_trig.h instead of libm calls.
// Self-calibration (ParticleFilterConfig::calibration; `pf:calib`): each particle carries its own
//   wheel calibration (c_l, c_r, w) and stereo calibration q (CalibrationEstimate::head), drawn
//   from the priors; it predicts with its wheels and predicts each sighting's pixel columns
//   through its q, so the weights select the calibrations the data agree with and the set's
//   spread holds their uncertainty. After each resampling every (pose, calibration) is moved by
//   Liu and West's kernel (shrunk towards the weighted mean, so the set keeps its mean and
//   covariance), which keeps the calibrations diverse where copies alone would collapse onto a
//   few values. On the realistic world's images it tracks but is over-confident
//   (docs/estimators.md, the particle filter's "Self-calibration").
// One std::mt19937_64 owned by the filter, seeded by the constructor: deterministic for a seed.
// Sources: particle_filter.cpp (the filter), particle_filter_calibration.cpp (self-calibration).
#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "solvers/fast_trig.h"
#include "solvers/global_fix_hypotheses.h"
#include "solvers/initialisation.h"
#include "solvers/self_calibration.h"
#include "solvers/validation_gate.h"
#include "solvers/data_association.h"
#include "src/core/estimator.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"

namespace stereoloc {

enum class ResamplingScheme {
  Systematic,      // low-variance: one uniform offset, N equally spaced pointers
  SortedRoulette,  // the thesis's: sort by decreasing weight, N independent roulette draws
};
std::string toString(ResamplingScheme scheme);  // "systematic", "sorted_roulette"
ResamplingScheme resamplingSchemeFromString(const std::string& name);

// How each particle's new pose is drawn on a step with observations.
//   Prior: Algorithm 6 as printed, the bootstrap filter: from the odometry model, then weighted
//     by the likelihood (5.34). Stereo bearings (~0.02-0.1 deg) are far sharper than one step's
//     odometry spread, so few particles carry the weight and the set starves.
//   LinearisedOptimal: the optimal importance density p(x_k | x_k-1, z_k) of Doucet, Godsill and
//     Andrieu ("On sequential Monte Carlo sampling methods for Bayesian filtering", 2000, sec.
//     II.D), linearised per particle: each particle's one-step Gaussian prediction
//     N(x_k-1 (+) u, G U G^T) is corrected by its own Kalman update with the observations (H
//     evaluated at that particle's prediction), the new pose is drawn from the result, and the
//     weight is the predictive likelihood N(z; h(x_pred), H G U G^T + R). The weights then vary
//     only with the particles' spread relative to (one step's odometry noise + R), not relative to
//     R alone, so they stay flat in the steady state whether the odometry or the stereo is the
//     sharper (docs/estimators.md). Chosen over progressive correction (several tempered
//     resample-and-jitter rounds per step, each a full likelihood pass) because it needs one pass
//     and no tuning of tempering stages, and over Rao-Blackwellising the heading because the
//     bearing couples heading and position, so the heading's conditional is not Gaussian in
//     closed form either.
enum class ParticleProposal { Prior, LinearisedOptimal };
std::string toString(ParticleProposal proposal);  // "prior", "linearised_optimal"
ParticleProposal particleProposalFromString(const std::string& name);

// KLD-sampling (Fox, "Adapting the sample size in particle filters through KLD-sampling", IJRR
// 2003; as in ROS AMCL): at each resampling, particles are drawn until their number reaches
//   n(k) = (k - 1) / (2 epsilon) * (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1))) z_(1-delta))^3,
// k the number of histogram bins (bin_xy_mm x bin_xy_mm x bin_theta_rad) holding at least one,
// so that with probability 1 - delta the Kullback-Leibler divergence between the sample-based
// and the true posterior stays below epsilon. Clamped to [min_particles, ParticleFilterConfig::particles].
struct KldSamplingConfig {
  bool enabled = false;
  double epsilon = 0.02;         // bound on the KL divergence (AMCL's kld_err is 0.01)
  double quantile = 0.99;        // 1 - delta, upper standard normal quantile z_(1-delta) (AMCL's kld_z)
  double bin_xy_mm = 20.0;       // mm, histogram bin edge in x and y
  double bin_theta_rad = 0.0873; // rad (5 deg), histogram bin in heading
  int min_particles = 300;       // lower clamp; the set never shrinks below it
};

struct ParticleFilterConfig {
  // Known: particles drawn from N(pose, covariance); Random: uniform over the map bounds and
  // heading (the pose and covariance are ignored); Global: no particles until the first fix,
  // then drawn from N(fix pose, fix covariance).
  InitialBelief init;
  int particles = 3000;         // N; the thesis saw no gain above 3000 [BDN07]
  // T uniform particles per observed step, T << N (0 disables). With observation noise like the
  // thesis's, T = 100 (3 % of 3000) recovers from a 430 mm kidnap within ~30 steps; T = 30
  // needs up to ~60 (tests/solvers/test_particle_filter.cpp).
  int reinjected = 100;
  ResamplingScheme resampling = ResamplingScheme::Systematic;
  // Resample when the effective sample size 1 / sum w^2 falls below this fraction of N;
  // 1.0 resamples on every observed step, as Algorithm 6 does.
  double resample_ess_fraction = 1.0;
  // Regularisation after resampling (the post-regularised PF of Musso, Oudjane and Le Gland,
  // "Improving regularised particle filters", 2001, with the kernel shrinkage of Liu and West,
  // 2001): each resampled particle p moves to m + a (p - m) + N(0, h^2 P), a = sqrt(1 - h^2),
  // m and P the weighted posterior mean and covariance (5.37) computed before resampling, so the
  // set keeps its mean and covariance. Resampling
  // only copies particles, and with stereo bearings (~0.1 deg) far sharper than the prior, a few
  // particles take all the weight; the copies then differ only by the small odometry noise and
  // the cloud collapses to a point (NEES in the hundreds). < 0: the Gaussian kernel's optimal
  // bandwidth h = (4 / (N (d + 2)))^(1 / (d + 4)), d = 3 (0.31 for N = 3000); 0: off (Algorithm 6
  // as printed).
  double regularisation_bandwidth = -1.0;
  // Regularise only resamplings whose effective sample size before resampling was below this
  // fraction of N (severe degeneracy: the likelihood much sharper than the prediction). There the
  // posterior is set by the observations, so the kernel cannot feed on itself; with flatter
  // weights the kernel would add to the prediction's spread at every step (1.0: always).
  // Measured: simulated stereo (3000 particles) mean NEES 464 -> 13.6 and RMSE 1.60x -> 1.14x
  // the EKF's; MR.CLAM robot 1 (3000) 1267 -> 438 mm. At 0.1 a 300-particle filter on a 30 s
  // MR.CLAM slice lost the robot (1.8 m), at 0.03 it does not.
  double regularisation_ess_fraction = 0.03;
  // true: shrink towards the mean (Liu and West) so the set keeps its covariance; false: the
  // plain kernel of Musso et al., which keeps separate modes apart but inflates the covariance
  // by (1 + h^2).
  bool regularisation_shrinkage = true;
  double likelihood_floor = 1e-3;  // per-observation likelihood floor, relative to the Gaussian's peak (0 < f <= 1)
  bool use_compass = true;         // weight with Step::compass when present
  // Odometry sampling (Algorithm 6, line 3). false: u ~ N(u(d), U) with U from (B.18), three
  // deviates and one Cholesky factor per step, no per-particle controlVector; the wheel noise
  // (sigma ~ 1 mm per 10 mm step) is far inside the region where (B.18) is linear. true: the
  // wheel increments are sampled and pushed through (B.4)/(B.5) per particle (exact, ~30 %
  // slower).
  bool sample_wheel_increments = false;
  ParticleProposal proposal = ParticleProposal::LinearisedOptimal;
  // With the optimal proposal: each particle's prediction is widened by a Gaussian kernel of
  // covariance h^2 C and pulled towards the set's mean by a = sqrt(1 - h^2) (the kernel shrinkage
  // of Liu and West, 2001: the mixture keeps the set's mean and covariance C), so that a set far
  // wider than the observations (the start, or a landmark seen again after a stretch of
  // odometry) still has components that reach the likelihood's peak; the Kalman update then
  // moves each component there. < 0: the Gaussian kernel's optimal bandwidth
  // h = (4 / (N (d + 2)))^(1 / (d + 4)), d = 3; 0: no kernel.
  double proposal_kernel_bandwidth = -1.0;
  // The kernel is used only while the set is one cluster: its position standard deviation below
  // this (mm) and its heading's below proposal_kernel_max_sigma_theta (rad). A uniform or
  // multi-modal set would be smeared across modes and linearised over metres.
  double proposal_kernel_max_sigma_mm = 150.0;
  double proposal_kernel_max_sigma_theta = 0.35;
  KldSamplingConfig kld;
  AssociationConfig association;   // for observations with landmark_id == -1 (uses the current estimate)
  // Lost status (5.1.3): gate each observation against the current estimate (2 dof). When
  // lost, a global fix (if any) re-draws all particles around it; otherwise re-injection
  // is what recovers.
  GateConfig gate;
  GlobalFixFunction global_fix;    // empty: defaultGlobalFix() (solvers/global_fix.h)
  // Hand-over to the global start, as EkfConfig::handover_sigma_mm: while the set's larger
  // position standard deviation exceeds this (mm), a global fix with a smaller spread re-draws
  // the particles around it. A uniform set (the random start) otherwise needs tens of steps of
  // re-weighting and resampling to find the one cluster that fits. 0: off.
  double handover_sigma_mm = 150.0;
  // As EkfConfig::multi_hypothesis_start: while the set is that wide and no global fix is
  // possible, the filter reports the mixture of the hypotheses spawned from ambiguous sightings
  // with the compass (solvers/global_fix_hypotheses.h); once the mixture's position spread is
  // below handover_sigma_mm, the particles are drawn from all its hypotheses, in proportion to
  // their weights. Only until the set has been narrower than handover_sigma_mm once.
  bool multi_hypothesis_start = true;
  HypothesisConfig hypotheses;
  // false: finish() returns only the newest estimate, so memory stays constant on an unbounded
  // stream (the Localizer's); true: one Estimate per step.
  bool keep_history = true;
  // Self-calibration of the odometry (wheel scales and wheel base, about 1, 1 and the odometry's
  // wheel base) and of the stereo head (the six corrections of CalibrationEstimate::head, about
  // the given rig), with the priors `calibration` states; the range and field blocks and
  // `consider` are the other estimators'. Needs the linearised optimal proposal; the stereo
  // block needs each sighting's pixels.
  SelfCalibrationConfig calibration;
  // With a calibration block: the rig that took the pixels and the pixel noise (its pixel_sigma
  // and unmodelled terms: the columns' covariance is the column block of pixelCovarianceFor; the
  // model field is not read), and the slip term of the prediction (unmodelled.slip_rel_sigma, as
  // the self-calibrating EKF's) and the wheels' drift per step.
  ObservationModelConfig observation_model;
  // Liu and West's discount factor delta of the calibration kernel (0 < delta <= 1): after each
  // resampling every (pose, calibration) moves to m + a (c - m) + N(0, (1 - a^2) C), a =
  // (3 delta - 1) / (2 delta), m and C the weighted mean and covariance; 1: no kernel (copies
  // only). 0.98 is within the range Liu and West recommend (0.95-0.99).
  double calibration_discount = 0.98;
};

// Standard normal deviates by the ziggurat method (Marsaglia & Tsang 2000, 128 layers), drawing
// from the caller's std::mt19937_64. Each 64-bit engine output feeds two deviates (7 bits layer,
// 1 bit sign, 24 bits uniform each), and about 99 % of the deviates need nothing else: several
// times cheaper than std::normal_distribution. The particle filter draws five deviates per
// particle and step, which dominated its time. The rejection steps make the output exactly
// N(0, 1) up to the 2^-24 resolution of the uniforms (2e-7 standard deviations).
// Holds half an engine output between calls; deterministic for a given engine state.
class ZigguratNormal {
 public:
  ZigguratNormal();
  double operator()(std::mt19937_64& rng) {
    uint32_t bits;
    if (have_spare_) {
      bits = spare_;
      have_spare_ = false;
    } else {
      const uint64_t b = rng();
      bits = static_cast<uint32_t>(b);
      spare_ = static_cast<uint32_t>(b >> 32);
      have_spare_ = true;
    }
    const int i = static_cast<int>(bits & 127u);
    const bool negative = (bits & 128u) != 0;
    const double x = static_cast<double>(bits >> 8) * 0x1.0p-24 * x_[i];
    if (x < x_[i + 1]) return negative ? -x : x;  // inside the layer's rectangle under the curve
    return slowPath(rng, i, negative, x);
  }

 private:
  double slowPath(std::mt19937_64& rng, int i, bool negative, double x);
  double x_[129];  // layer edges: x_[0] = V / f(R), x_[1] = R, ..., x_[128] = 0
  double f_[129];  // f(x_[i]) = exp(-x_[i]^2 / 2), f_[0] = 0 (the base strip)
  uint32_t spare_ = 0;
  bool have_spare_ = false;
};

// Resampling primitives (exposed for tests). They return, for each of the n new particles, the
// index of the particle it copies. `weights` must be normalised (sum 1, non-negative).
// KLD-sampling's sample size n(k) for k occupied bins (KldSamplingConfig); 1 for k < 2.
int kldSampleSize(int bins, double epsilon, double quantile);

std::vector<int> systematicResample(const std::vector<double>& weights, int n, std::mt19937_64& rng);
std::vector<int> sortedRouletteResample(const std::vector<double>& weights, int n, std::mt19937_64& rng);

// The kernel of the optimal proposal (ParticleFilterConfig::proposal_kernel_bandwidth).
struct ParticleProposalKernel {
  double h = 0.0;                                    // bandwidth; 0: no kernel
  Pose2 centre;                                      // the set's predicted mean
  Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();  // the set's covariance, mm^2, mm rad, rad^2
};

class ParticleFilter : public Estimator {
 public:
  ParticleFilter(const FieldMap& map, const OdometryParams& odometry, ParticleFilterConfig config, uint64_t seed);

  std::string name() const override { return "pf"; }
  // The first processed step defines the initial time: its odometry is not applied.
  // Throws stereoloc::Error on non-increasing steps, unknown landmark ids or invalid R.
  Estimate process(const Step& step) override;
  std::vector<Estimate> finish() override { return estimates_; }

  // Lower-level operations (benchmarks, tests).
  void initialiseGaussian(const Pose2& pose, const Eigen::Matrix3d& covariance);
  void initialiseUniform();
  // Particles drawn from a Gaussian mixture: round(N w_i) from hypothesis i (weights normalised).
  void initialiseMixture(const std::vector<PoseHypothesis>& components, const std::vector<double>& weights);
  void predict(double d_left, double d_right);
  // Multiplies the weights by the likelihood of identified observations (landmark positions
  // given) and of an optional compass reading; normalises in the log domain.
  void weight(const std::vector<Observation>& observations, const std::vector<Eigen::Vector2d>& landmarks,
              const std::optional<double>& compass = std::nullopt, double compass_sigma = 0.0);
  // The linearised optimal proposal (ParticleProposal::LinearisedOptimal) of one step: every
  // particle is moved by its own Kalman-corrected odometry prediction and weighted by its
  // predictive likelihood (landmarks as in weight()).
  // `wheels` (d_left, d_right, mm): the step's odometry; none on the first step (no motion).
  // With kernel.h > 0 each particle's prediction is first shrunk towards kernel.centre (the set's
  // predicted mean) by sqrt(1 - h^2) and widened by h^2 kernel.spread (proposal_kernel_bandwidth).
  void proposeAndWeight(const std::optional<Eigen::Vector2d>& wheels, const std::vector<Observation>& observations,
                        const std::vector<Eigen::Vector2d>& landmarks, const std::optional<double>& compass = std::nullopt,
                        double compass_sigma = 0.0, const ParticleProposalKernel& kernel = {});
  // Resamples to the configured count, or with KLD-sampling enabled to the adaptive count.
  void resample();
  void reinject(int count);
  // Moves every particle p to mean + a (p - mean) + N(0, h^2 covariance), a = sqrt(1 - h^2)
  // (see regularisation_bandwidth); 0 < h < 1, otherwise nothing happens.
  void regularise(const Pose2& mean, const Eigen::Matrix3d& covariance, double h);
  // Weighted mean (circular for theta) and weighted covariance of the current particles.
  void summarise(Pose2* mean, Eigen::Matrix3d* covariance) const;
  // With a calibration block: the particles' weighted mean and covariance of the wheels and the
  // stereo head at the last processed step (before its resampling), as the other estimators
  // report theirs; none without one.
  std::optional<CalibrationEstimate> calibration() const;
  // Particle i's calibration: wheels (c_l, c_r, w) then head (6), whichever blocks are on.
  Eigen::VectorXd particleCalibration(int i) const;
  double effectiveSampleSize() const;

  bool initialised() const { return initialised_; }
  int size() const { return static_cast<int>(x_.size()); }
  const std::vector<double>& xs() const { return x_; }
  const std::vector<double>& ys() const { return y_; }
  const std::vector<double>& thetas() const { return th_; }
  const std::vector<double>& weights() const { return w_; }  // normalised

  // Everything a processed step changes, to go back to: restoreState() and then the same steps
  // again give the same estimates, bit for bit, the random stream included (the Localizer
  // replays the steps since a late observation's step this way). finish() then holds no
  // estimate made after the save. A state holds the particle set: about 56 bytes per particle, and
  // 8 more per calibration value.
  class State;
  State saveState() const;
  // The same into `state`, reusing its buffers (no allocation once they are large enough).
  void saveState(State& state) const;
  void restoreState(const State& state);

 private:
  // The observations of one step the filter uses: identified (given or associated), with their
  // landmarks' positions and whether the summary's gate accepted each.
  struct StepObservations {
    std::vector<Observation> observations;
    std::vector<Eigen::Vector2d> landmarks;
    std::vector<char> accepted;
    bool lost = false;  // the gate's consecutive rejections reached GateConfig::lost_after
    Pose2 predicted;    // the previous summary pushed through the step's odometry
    Eigen::Matrix3d predicted_covariance = Eigen::Matrix3d::Zero();
  };
  void validateStep(const Step& step) const;  // throws stereoloc::Error naming the step
  Estimate recordEstimate(const Step& step, EstimateStatus status);
  std::optional<EstimateStatus> startFromWideBelief(const Step& step, bool first);
  StepObservations identifyObservations(const Step& step, bool first);
  void correct(const Step& step, bool first, const StepObservations& used, bool use_compass);
  void resampleIfDegenerate();
  bool tryGlobalFix(const Step& step);
  // A calibrating set that is lost re-anchors, as the self-calibrating EKF does, on a global fix
  // (seen through its calibration) that is not a kidnap: one within the EKF's re-anchoring
  // bound of the prediction. The set then keeps its poses and calibrations and is weighted by the
  // fix; a fix beyond the bound re-draws the set around it (tryGlobalFix).
  std::optional<PoseFix> reanchoringFix(const Step& step, const StepObservations& used) const;
  void weightByFix(const PoseFix& fix);
  // Particles [begin, end) drawn from N(pose, covariance); throws stereoloc::Error when it is not
  // finite or not positive semi-definite.
  void drawGaussian(size_t begin, size_t end, const Pose2& pose, const Eigen::Matrix3d& covariance);
  void finishInitialisation();  // uniform weights, summary, gate reset
  void setUpCalibration();  // the blocks, their layout and priors; throws stereoloc::Error
  // Calibrations of particles [begin, end) drawn from N(cal_mean_, cal_cov_).
  void drawCalibration(size_t begin, size_t end);
  // cal_mean_, cal_cov_ and joint_cov_ from the weighted particles, the pose about mean_.
  void summariseCalibration();
  void jitterCalibration();  // Liu and West's kernel on (pose, calibration) about mean_, cal_mean_, joint_cov_
  // Each particle's wheel calibration takes a step of its random walk (UnmodelledNoise::
  // wheel_scale_drift) over increments d_left, d_right (mm).
  void walkWheels(double d_left, double d_right);
  OdometryParams stepOdometry(double d_left, double d_right) const;  // with the slip term when calibrating
  const double* wheelsOf(size_t i) const { return cal_.data() + i * static_cast<size_t>(cal_dim_) + wheels_at_; }
  // The observation as the gate and the association see it: through the set's mean stereo
  // calibration, its covariance widened by the calibration's spread (calibratedObservation).
  Observation calibratedForGate(const Observation& obs, const Landmark& landmark) const;
  // The step with every sighting seen that way, for the global fixes.
  Step seenThroughCalibration(const Step& step) const;
  void normalise();
  void resizeParticles(size_t n);
  void setParticle(size_t i, double x, double y, double theta) {
    x_[i] = x;
    y_[i] = y;
    th_[i] = theta;
    fast_trig::sinCos(theta, &s_[i], &c_[i]);
  }

  FieldMap map_;  // a copy: the filter does not depend on the caller's lifetime
  OdometryParams odometry_;
  ParticleFilterConfig config_;
  std::mt19937_64 rng_;
  ValidationGate gate_;
  double log_floor_;
  ZigguratNormal normal_;
  // Particle i: (x_, y_, th_), with cos/sin of th_ cached (c_, s_) since prediction and the
  // circular mean both need them; log weight and normalised weight.
  std::vector<double> x_, y_, th_, c_, s_, logw_, w_;
  std::vector<double> scratch_x_, scratch_y_, scratch_th_, scratch_c_, scratch_s_;
  std::vector<int> resample_index_;
  std::vector<int> fresh_;  // particles re-injected since the last proposal
  bool uniform_weights_ = false;  // every weight is exactly 1/N (after resampling)
  bool initialised_ = false;
  bool have_step_ = false;
  long last_step_ = 0;
  Pose2 mean_;
  Eigen::Matrix3d cov_ = Eigen::Matrix3d::Zero();
  std::vector<Estimate> estimates_;
  HypothesisBank bank_;
  bool localised_ = false;  // the belief has been narrower than handover_sigma_mm once
  // Self-calibration: cal_dim_ values per particle (row i at cal_[i * cal_dim_]), the wheels at
  // wheels_at_ and the head at head_at_ (-1: not estimated); their weighted mean and covariance
  // at the last summary (the prior's until the first).
  int cal_dim_ = 0, wheels_at_ = -1, head_at_ = -1;
  std::vector<double> cal_, scratch_cal_;
  Eigen::VectorXd cal_mean_;
  Eigen::MatrixXd cal_cov_;
  Eigen::MatrixXd joint_cov_;  // (x, y, theta, calibration), for the kernel

 public:
  class State {
   private:
    friend class ParticleFilter;
    std::mt19937_64 rng;
    ZigguratNormal normal;
    ValidationGate gate;
    std::vector<double> x, y, th, c, s, logw, w, cal;
    Eigen::VectorXd cal_mean;
    Eigen::MatrixXd cal_cov, joint_cov;
    std::vector<int> fresh;
    bool uniform_weights = false, initialised = false, have_step = false, localised = false;
    long last_step = 0;
    Pose2 mean;
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    std::vector<PoseHypothesis> hypotheses;
    size_t estimates = 0;
  };
};

}  // namespace stereoloc
