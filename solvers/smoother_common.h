#pragma once
// Pieces shared by the batch and sliding-window smoothers (solvers/batch_smoother.h,
// solvers/sliding_window_smoother.h): robust losses, step validation, the dense normal
// equations of a few factors and the Schur complement that turns them into a marginal prior.
#include <ceres/cost_function.h>
#include <ceres/loss_function.h>

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "src/core/exposure_offset.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc {

enum class RobustLoss { None, Huber, Cauchy };
std::string toString(RobustLoss loss);                  // "none", "huber", "cauchy"
RobustLoss robustLossFromString(const std::string& name);  // throws stereoloc::Error

struct RobustLossConfig {
  RobustLoss type = RobustLoss::None;
  // Scale in whitened units: a residual block whose whitened norm |S e| exceeds `scale` is
  // down-weighted (Huber: linear beyond it; Cauchy: logarithmic). 1.345 / 2.3849 are the 95 %
  // efficiency constants for Huber / Cauchy with unit-variance residuals.
  double scale = 1.345;
};
// nullptr for RobustLoss::None. The caller owns the result.
std::unique_ptr<ceres::LossFunction> makeLossFunction(const RobustLossConfig& config);

// How an identified observation enters the smoothers (batch and sliding window) and the bound.
enum class ObservationModel {
  RangeBearing,  // (range, bearing) with R (3.6, 3.7, 5.32): the thesis's form, and the only one
                 // for observations without pixels (real range-bearing sensors)
  PixelColumns,  // StereoPixelFactor on u_l, u_r (factors/stereo_pixel_factor.h): the same data (untilted rig),
                 // compared where the noise is (no conversion bias, weights at the estimate)
  Pixels,        // StereoPixelFactor on u_l, v_l, u_r, v_r: also range from the known heights
};
std::string toString(ObservationModel model);                       // "range_bearing", "pixel_columns", "pixels"
ObservationModel observationModelFromString(const std::string& name);  // throws stereoloc::Error

// Errors of a real robot that neither the rig's pixel sigma nor the odometry's k |d| states and
// the self-calibration does not estimate, stated as the noise they add (docs/realistic_world.md,
// "Noise model"): the error left in the calibration's lens distortion estimate, per-step camera
// vibration and wheel slip. All 0 (the default) adds nothing. A YAML file (cv::FileStorage) with
// these keys, missing keys 0, is what a user writes for a robot (data/noise_realistic.yaml).
struct UnmodelledNoise {
  double k1_sigma = 0.0;          // error of each camera's calibrated radial k1 (dimensionless)
  double k2_sigma = 0.0;          // ... k2
  double tangential_sigma = 0.0;  // ... p1 and p2
  double pitch_sigma_rad = 0.0;   // camera pitch vibration per image pair, rad (both cameras)
  double roll_sigma_rad = 0.0;    // camera roll vibration per image pair, rad (both cameras)
  // Rotation of the right camera against the left that the given calibration does not know, per
  // axis, rad: it bends the right image against the left (OpenCV's rotation Jacobian; its
  // constant column shift f eps is the disparity offset, which the self-calibration estimates,
  // so only the rest enters).
  double relative_rotation_sigma_rad = 0.0;
  // Error of the right column (the disparity) of features the frontend matches along a floor
  // marking (marking corners and T-junctions; X-intersections), px: on a rectified pair whose
  // rows the calibration's errors misalign, the right feature found on the left's row slides
  // along the marking (docs/realistic_world.md, "Noise model").
  double marking_disparity_sigma_px = 0.0;
  double intersection_disparity_sigma_px = 0.0;
  // The misalignment of the rectified rows that makes the slide (right row minus left row of
  // one scene point, px): the raw principal points' row difference and f times the cameras'
  // relative pitch. With it the stereo self-calibration estimates the misalignment as the row
  // offset dv (its prior sigma; factors/stereo_pixel_row_calibration_factor.h), each feature's
  // u_r error then is its slide gain times dv, and the two terms above give way to the two below.
  double row_offset_sigma_px = 0.0;
  // What remains of the two marking terms when dv is estimated, px: the error of u_r about
  // s dv (docs/realistic_world.md, "Noise model"). Per sighting of a marking corner or
  // T-junction a white part, sqrt(floor^2 + (per_gain |s|)^2) with the floor the least white
  // disparity error (the frontend's and the terms above count toward it); of an X-intersection
  // (no slide gain) a white sigma. Per feature a constant, the same in every sighting: the
  // batch estimates it as the feature's column offset (a zero-mean parameter with this prior
  // sigma); where it is not estimated it is added to the white part.
  double marking_slide_residual_sigma_px = 0.0;
  double marking_slide_residual_per_gain_px = 0.0;
  double marking_feature_offset_sigma_px = 0.0;
  double intersection_slide_residual_sigma_px = 0.0;
  double intersection_feature_offset_sigma_px = 0.0;
  // A feature's column error common to both images (its bearing), px, also repeats from
  // sighting to sighting: per kind the sigma of that constant (the batch estimates it with the
  // feature offsets; white noise elsewhere).
  double goal_feature_column_sigma_px = 0.0;
  double marking_feature_column_sigma_px = 0.0;
  double intersection_feature_column_sigma_px = 0.0;
  // The error of the rig's exposure offset (StereoRigParams::exposure_offset_s), s: the right
  // image is taken that much earlier or later than the rig says, which while the robot moves
  // shifts its columns by the motion of that interval (src/core/exposure_offset.h). It depends
  // on the motion, so it is not pixel noise: the stereo self-calibration estimates it as the
  // image block's last entry with this prior; without the image block it is not modelled.
  double exposure_offset_sigma_s = 0.0;
  // Wheel slip: a wheel's increment's error sigma as a fraction of the increment, added in
  // quadrature to (B.6)'s k |d| (slip on a fraction p of the steps, one wheel at a time, reading
  // (1 + s) times the motion: sqrt(p / 2 E[s^2])).
  double slip_rel_sigma = 0.0;
  // The wheels' calibration wanders during a run (tyres warming and wearing, another floor, a
  // velocity controller whose scale follows the battery): a random walk with distance. Each
  // wheel's scale by its own travel, the effective wheel base by the wheels' mean travel,
  // variance sigma^2 |d| / 1000 mm (wheelDriftVariance, solvers/calibrated_models.h). The
  // window and the EKF that estimate or consider the wheels let them follow it; the batch
  // estimates one wheel calibration per run and does not read these.
  double wheel_scale_drift = 0.0;  // fraction per sqrt(m) of the wheel's travel
  double wheel_base_drift = 0.0;   // fraction of the wheel base per sqrt(m) of the mean travel
  bool wheelsDrift() const { return wheel_scale_drift > 0 || wheel_base_drift > 0; }

  bool isZero() const;
  void validate() const;  // throws stereoloc::Error naming the field
  static UnmodelledNoise load(const std::string& path);  // errors name the file and key
  void save(const std::string& path) const;
};

// The pixel covariance (u_l, v_l, u_r, v_r; px^2) the lens, vibration and relative rotation
// terms of `noise` add to an observation at rectified pixels `px` of `rig`: J diag(sigma^2) J^T,
// J the pixels' first-order change with each camera's k1, k2, p1, p2 (independent between the
// cameras), with the pair's common pitch and roll, and with the right camera's own rotation
// (without the constant column shift of its yaw, the disparity offset).
Eigen::Matrix4d unmodelledPixelCovariance(const StereoRig& rig, const StereoPixels& px, const UnmodelledNoise& noise);

// The odometry parameters of one step with the slip term: each wheel's variance grows by
// (slip_rel_sigma d)^2; as the floor of both wheels, it takes the larger increment's.
OdometryParams withSlip(const OdometryParams& params, double d_left, double d_right, double slip_rel_sigma);

// The body rate at `step` (src/core/exposure_offset.h) from `tracker`, made with the odometry's
// wheel base at the first step; the step's rotation variance is the odometry's with the slip term.
BodyRate stepBodyRate(std::optional<BodyRateTracker>& tracker, const Step& step, const OdometryParams& params,
                      double slip_rel_sigma);

// Where the image factors that estimate the cameras' exposure offset take each image's body
// rate from (docs/realistic_world.md, "Estimating the offset").
enum class BodyRateSource {
  Odometry,       // the wheels' rate over the last 0.5 s (BodyRateTracker), as the EKF
  // The central difference of the smoothed poses around the image: the batch solves with the
  // odometry's rate first, then again with its solution's (solvers/batch_solve.cpp,
  // ratesFromSolution); the window re-makes the factors of each pose between two others at
  // their latest estimates before it solves (refreshExposureRates).
  SmoothedPoses,
};

struct ObservationModelConfig {
  ObservationModel model = ObservationModel::RangeBearing;
  StereoRig rig;  // the rig that took the pixels (Dataset::rig); used by the pixel models
  // px; > 0 replaces every observation's own pixel covariance by sigma^2 I in the pixel models:
  // an honest noise for a world the ideal sigma understates (vibration, blur, unsynchronised
  // cameras).
  double pixel_sigma = 0.0;
  // Pixel noise the rig does not state (the lens and vibration terms; slip is the odometry's).
  UnmodelledNoise unmodelled{};
};

// The pixel covariance the pixel models use for `obs`: its own, or sigma^2 I when
// config.pixel_sigma > 0, plus unmodelledPixelCovariance of config.unmodelled and, for a feature
// matched along a marking (landmark.type), its disparity term on u_r: the marking terms, or with
// `slide_modelled` (the row offset dv estimated) the slide residual terms, with the feature's
// constant offset as white noise unless `feature_offset_modelled` (the caller estimates it,
// featureOffsetSigma). Throws stereoloc::Error when the observation carries none.
Eigen::Matrix4d pixelCovarianceFor(const Observation& obs, const Landmark& landmark, const ObservationModelConfig& config,
                                   bool slide_modelled = false, bool feature_offset_modelled = false);

// The prior sigmas (px) of a feature's constant offsets when the row offset is estimated
// (UnmodelledNoise): of its column in both images (its bearing) and of its u_r alone (the
// disparity; features matched along a marking only); 0 where the noise model states none.
struct FeatureOffsetSigma {
  double column = 0.0;
  double disparity = 0.0;
};
FeatureOffsetSigma featureOffsetSigma(LandmarkType type, const UnmodelledNoise& noise);

// The cost function of one observation of `landmark`: a StereoPixelFactor when the model asks
// for pixels and the observation has them (with its own Observation::pixel_covariance), the
// range-bearing factor otherwise. The caller owns the result. Throws stereoloc::Error when a
// pixel observation carries no pixel covariance.
ceres::CostFunction* makeObservationFactor(const Observation& obs, const Landmark& landmark,
                                           const ObservationModelConfig& config);
// Whether makeObservationFactor makes a range-bearing factor of obs (not a pixel factor): the
// observations the range self-calibration block enters.
bool isRangeBearingFactor(const Observation& obs, const ObservationModelConfig& config);

// Throws stereoloc::Error "WHO: step N: ..." when wheel increments, compass or an
// observation (range, bearing, R) is not finite / not positive definite.
void validateStep(const Step& step, const std::string& who);

// Adds one factor's Gauss-Newton contribution to the dense normal equations H dx = -g of the
// variables at `offsets` (3 per pose, tangent order x, y, theta). The factor is linearised at
// `linearisation` (its Jacobian J and residual r_lin there) and the linear model is moved to
// the current point: b = r_lin + sum_i J_i (current_i [-] linearisation_i); then H += J^T J and
// g += J^T b. With linearisation == current this is the usual Gauss-Newton system; with the
// first estimates it is the first-estimate-Jacobian (FEJ) system. Returns false when the
// factor cannot be evaluated there.
bool accumulateNormalEquations(const ceres::CostFunction& cost, const std::vector<const double*>& current,
                               const std::vector<const double*>& linearisation, const std::vector<int>& offsets,
                               Eigen::MatrixXd& H, Eigen::VectorXd& g);

// The Schur complement that marginalises the FIRST m variables of (H, g):
//   H' = H_rr - H_rm H_mm^-1 H_mr,   g' = g_r - H_rm H_mm^-1 g_m.
// Throws stereoloc::Error when H_mm is not positive definite (the marginalised poses are not
// determined by their factors: rank deficiency).
void schurComplement(const Eigen::MatrixXd& H, const Eigen::VectorXd& g, int m, Eigen::MatrixXd* H_marginal,
                     Eigen::VectorXd* g_marginal);

// A Gaussian in information form, quadratic 1/2 dx^T H dx + g^T dx, whose variables
// offset..offset+k-1 then take a random walk with independent variances `variance` (k of them,
// >= 0; zero ones stay): the information of the walked variables, with the walk's noise w
// marginalised out,
//   H' = H - H E M^-1 E^T H,   g' = g - H E M^-1 E^T g,   M = Q^-1 + E^T H E,
// E selecting the walked variables, Q = diag of their positive variances. Valid for a singular
// H (no information in some direction stays none) and the mean unchanged. The sliding window's
// marginal prior on a drifting wheel calibration (UnmodelledNoise::wheel_scale_drift). Throws
// stereoloc::Error for bad dimensions or a negative or non-finite variance.
void addRandomWalk(Eigen::MatrixXd& H, Eigen::VectorXd& g, int offset, const Eigen::VectorXd& variance);

// Marginal covariances of a chain: the poses 0..N-1 linked only to their neighbours, so the
// information matrix is block tridiagonal with diagonal blocks D_i (3x3) and off-diagonal
// blocks B_i = H(i-1, i) (B_0 unused). Forward elimination Lambda_i = D_i - B_i^T Lambda_{i-1}^-1 B_i
// (the filtered information), then the backward (Rauch-Tung-Striebel) pass
//   Sigma_{N-1} = Lambda_{N-1}^-1,  Sigma_i = Lambda_i^-1 + G_i Sigma_{i+1} G_i^T,  G_i = Lambda_i^-1 B_{i+1}
// gives the diagonal blocks of H^-1 exactly in O(N). Returns false (rank deficient) when a
// Lambda_i is not positive definite or its smallest eigenvalue (bounded below by
// 1 / |Lambda_i^-1|_F) is below 1e-14 of D_i's largest entry (the threshold ceres::Covariance uses).
bool chainMarginalCovariances(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                              std::vector<Eigen::Matrix3d>* covariances);

// A small in-process problem for tests and benchmarks that must not depend on the simulator:
// a random walk of a differential-drive robot inside a 1500 x 1300 mm field with `landmarks`
// point landmarks, noisy wheel increments (B.6 with odometry.k_*), range-bearing observations
// of at most `max_observations` landmarks in a forward field of view, optional compass.
// Deterministic for a seed (one std::mt19937_64).
struct SyntheticProblemOptions {
  int steps = 200;
  int landmarks = 10;                 // 1..10, fixed positions around and inside the field
  int max_observations = 2;           // per step, the nearest visible landmarks
  double max_range = 1000.0;          // mm
  double half_fov = 1.05;             // rad (about 60 deg)
  double observation_probability = 1.0;  // each visible landmark is reported with it
  double sigma_range = 15.0;          // mm
  double sigma_bearing = 0.02;        // rad
  double compass_sigma = 0.0;         // rad, 0 = no compass
  double outlier_fraction = 0.0;      // observations whose range is multiplied by 1.5
  double step_length = 20.0;          // mm, mean arc length per step
  double turn_sigma = 0.1;            // rad per step
  bool noisy_odometry = true;
};
struct SyntheticProblem {
  FieldMap map;
  OdometryParams odometry;            // the noise model the steps were generated with
  std::vector<Step> steps;            // step 0 has zero odometry and is the initial pose
  std::vector<Pose2> truth;           // true pose per step
};
SyntheticProblem makeRandomWalkProblem(const SyntheticProblemOptions& options, uint64_t seed);

}  // namespace stereoloc
