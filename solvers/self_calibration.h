#pragma once
// Self-calibration: the robot's calibration as global parameter blocks of the batch smoother
// (solvers/batch_smoother.h, BatchSmootherConfig::calibration), so that systematic odometry and
// stereo errors are estimated instead of absorbed by the poses.
//
//   odometry  c = (c_l, c_r, w): wheel scales and effective wheel base
//             (factors/odometry_calibration_factor.h)
//   stereo    q = (dbeta, k, delta_d, delta_u, phi, psi): head tilt correction, baseline scale,
//             disparity offset, column offset, the right camera's focal length error relative
//             to the left's and the left camera's focal length error,
//             entering every pixel factor
//             (factors/stereo_pixel_calibration_factor.h); observations without pixels stay
//             range-bearing factors, which do not see q
//   image     e = the error of each camera's calibrated lens distortion (dk1, dk2, dp1, dp2),
//             the right camera's rotation against the left (pitch, yaw, roll) and the error of
//             its exposure offset (src/core/exposure_offset.h), with the stereo
//             block when the noise model (UnmodelledNoise) states their sigmas (batch, window, EKF;
//             SelfCalibrationConfig::image_errors; factors/stereo_pixel_image_calibration_factor.h)
//   row       dv = the rectified rows' misalignment (px), with the stereo block when the noise
//             model states it (UnmodelledNoise::row_offset_sigma_px; batch, window, EKF;
//             SelfCalibrationConfig::row_offset; factors/stereo_pixel_row_calibration_factor.h)
//   range     k = (c0, c1, c2, d_b): a range-bearing sensor's range factor 1 + c0 + c1 b + c2 b^2
//             at the measured bearing b and its bearing offset, in every factor of an observation
//             without pixels (batch, window, EKF; factors/range_bearing_calibration_factor.h)
//   field     f = the change of the field's nine dimensions (mm; kFieldDimensions of
//             src/core/field_map.h), with the stereo block, in the batch and the window: every pixel factor
//             sees its landmark where the changed field puts it (factors/field_shifted_factor.h)
//   features  b_j = constant offsets (px) of each feature j's column (both images) and u_r, with
//             the row block when the noise model states them (batch, window, EKF)
//             (UnmodelledNoise::*_feature_offset_sigma_px, *_feature_column_sigma_px;
//             SelfCalibrationConfig::feature_offsets; factors/stereo_pixel_feature_calibration_factor.h)
// Each block has a Gaussian prior (factors/calibration_prior_factor.h) centred on the nominal
// calibration with the stated uncertainty of SelfCalibrationConfig, so a run that does not
// excite a parameter leaves it at its prior.
// Why the image block: the lens estimate's error and the cameras' relative rotation are fixed
// for a run, so they repeat at every sighting of a landmark from a similar view; as white pixel
// noise (unmodelledPixelCovariance) they average out over the run and the stereo parameters
// that partly absorb them (baseline and focal scales) come out with sigmas too small. As
// parameters with the noise model's sigmas as their priors, their uncertainty enters the
// marginal covariance of every other parameter, and the data correct them where they can. The smoother returns the estimate with its marginal
// covariance beside the poses' (CalibrationEstimate).
// Why the row block: the frontend matches marking features along the left feature's row, and
// the rows' misalignment is the same in every pair of a run, so each such feature's u_r is off by
// its slide gain times that misalignment (1.6 px RMS for marking corners on the realistic
// profile) in every sighting; one parameter takes it, and the pixel covariance keeps only what
// the slide model leaves (pixelCovarianceFor's slide residual terms). Of what it leaves, a part
// is constant per feature (its slide gain's error is the same from similar views, and so is
// its edge's): the batch estimates it as one u_r offset per marking feature, zero-mean with the
// noise model's sigma (factors/stereo_pixel_feature_calibration_factor.h).
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "factors/stereo_pixel_calibration_factor.h"
#include "factors/stereo_pixel_factor.h"
#include "solvers/initialisation.h"
#include "solvers/smoother_common.h"
#include "src/core/angles.h"
#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "src/io/dataset.h"

namespace stereoloc {

struct SelfCalibrationConfig {
  bool odometry = false;  // estimate wheel scales and wheel base
  bool stereo = false;    // estimate tilt correction, baseline scale, pixel offsets, focal errors
  // Estimate a range-bearing sensor's range factor and bearing offset (batch, window, EKF; the
  // observations not seen through the stereo block; RangeBearingCalibrationFactor).
  bool range = false;
  // With the stereo block, the batch, the window and the EKF (a pixel model): estimate the field's dimensions
  // (a field built by hand is a few mm off the map's; the map must be FieldMap::miroSot of its geometry).
  bool field = false;
  // The EKF only: the blocks above (and the image, row and feature blocks they bring) are
  // considered, not estimated: a Schmidt-Kalman filter, whose gain leaves them at the given
  // calibration while their uncertainty (the priors below) enters every covariance. For a robot
  // whose calibration is to stay as given but must not make the filter over-confident.
  bool consider = false;
  // Prior 1-sigma: twice the spread of the realistic error profile (src/sim/error_profile.h),
  // so that the prior does not pull a real robot's parameters back.
  double wheel_scale_sigma = 0.01;          // dimensionless
  double wheel_base_rel_sigma = 0.04;       // fraction of the nominal wheel base
  double tilt_sigma_rad = deg2rad(1.0);     // rad
  double baseline_scale_sigma = 0.02;       // dimensionless
  // Disparity offset: the principal points' difference (1 px each) and the cameras' relative
  // yaw (0.1 deg, f * 0.1 deg ~ 0.5 px), ~1.5 px together; column offset: their mean (~0.7 px)
  // and a head pan offset.
  double disparity_offset_sigma_px = 3.0;   // px
  double column_offset_sigma_px = 2.0;      // px
  // The focal lengths' difference: 0.5 % per camera, 0.7 % between them.
  double focal_ratio_sigma = 0.014;         // dimensionless
  // The left camera's focal length: 0.5 % per camera.
  double focal_scale_sigma = 0.01;          // dimensionless
  // What a drive adds to the disparity offset that another drive does not share: two cameras
  // exposing dt apart on a robot turning at w shift every disparity by f w dt (the realistic
  // world's circle: ~0.3 px), which the estimated offset absorbs for that drive's motion only.
  // Added in quadrature to the offset's standard deviation handed to the next run
  // (CalibrationEstimate::saveAsRig), as `calibrate --rig-out` does, unless the exposure offset
  // models that part: the rig states it (StereoRigParams::exposure_offset_s, the pixels moved to
  // one instant) or the run estimated it (the image block's last entry); 0 for cameras exposing
  // together.
  double drive_disparity_sigma_px = 0.3;    // px
  // The range block's priors: a range sensor's scale error of a few per cent (MR.CLAM's barcode
  // camera: +2.6 and +5.2 % on axis, docs/results.md), its change across the field of view
  // (there -0.46 and -0.51 per rad^2) and a bearing offset of a degree.
  double range_scale_sigma = 0.05;              // c0, dimensionless
  double range_scale_slope_sigma = 0.05;        // c1, 1/rad
  double range_scale_curvature_sigma = 0.5;     // c2, 1/rad^2
  double bearing_offset_sigma_rad = deg2rad(1.0);  // d_b, rad
  // The field's prior: twice the hand-built field's 2 mm per dimension (data/profile_hand_built_field.yaml),
  // on a map that does not state its own (fieldPriorCovariance).
  double field_dimension_sigma_mm = 4.0;        // mm, per dimension
  // With the stereo block, in the batch, the window and the EKF (pixel model): estimate the
  // image errors the noise model states (lens estimate, relative rotation) as the image block
  // instead of adding them to the pixel noise. The window's gate keeps them as pixel noise, and
  // the window estimates them only after its first steps (SlidingWindowConfig::
  // image_errors_after_steps).
  bool image_errors = true;
  // With the stereo block, in the batch, the window and the EKF: estimate the rows'
  // misalignment when the noise model states it (rowOffsetSigma).
  bool row_offset = true;
  // With the row block, in the batch, the window and the EKF: estimate each feature's constant
  // column offset and a marking feature's constant u_r offset when the noise model states them
  // (featureOffsetSigmas); off, they stay in the white pixel noise.
  bool feature_offsets = true;
  // selfCalibratingBatch only (the batch smoother takes them from its own configuration).
  PixelResiduals residuals = PixelResiduals::All;
  bool use_compass = true;
  int max_iterations = 100;

  // "" or "none", or a comma-separated list of odometry, stereo, range and field (any order);
  // throws stereoloc::Error.
  static SelfCalibrationConfig parse(const std::string& list);
  void validate() const;
  bool any() const { return odometry || stereo || range; }  // a block is estimated or considered
};

struct CalibrationEstimate {
  bool odometry = false, stereo = false, range = false;  // which blocks were estimated
  // The field block: the change of each of kFieldDimensions (mm) and its covariance (mm^2); not
  // part of the rig (a property of the field), written by saveAsRig as keys field_<name>_mm.
  bool field = false;
  using FieldVector = Eigen::Matrix<double, kFieldDimensionCount, 1>;
  FieldVector field_dimensions_mm = FieldVector::Zero();
  Eigen::Matrix<double, kFieldDimensionCount, kFieldDimensionCount> field_covariance =
      Eigen::Matrix<double, kFieldDimensionCount, kFieldDimensionCount>::Zero();
  FieldVector field_prior_sigma_mm = FieldVector::Zero();  // the prior's standard deviations (fieldPriorCovariance)
  Eigen::Vector3d wheels = Eigen::Vector3d(1, 1, 75);  // c_l, c_r, w (mm)
  Eigen::Matrix3d wheels_covariance = Eigen::Matrix3d::Zero();
  // What a drifting wheel calibration (UnmodelledNoise::wheel_scale_drift) walked over the run,
  // the variances of (c_l, c_r, w) wheelDriftVariance summed over its steps; zero for a constant
  // one. The prior an estimate is measured against (furthestFromPrior) widens by it.
  Eigen::Vector3d wheels_walk_variance = Eigen::Vector3d::Zero();
  // dbeta (rad), k, delta_d (px), delta_u (px), phi, psi: factors/stereo_pixel_calibration_factor.h
  using StereoVector = Eigen::Matrix<double, 6, 1>;
  using StereoMatrix = Eigen::Matrix<double, 6, 6>;
  StereoVector head = (StereoVector() << 0, 1, 0, 0, 0, 0).finished();
  StereoMatrix head_covariance = StereoMatrix::Zero();
  // The image block (imageErrorSigmas), in its units (dimensionless lens terms, rad, s): left
  // dk1 dk2 dp1 dp2, right dk1 dk2 dp1 dp2, right pitch yaw roll, the exposure offset's error
  // against the rig's (src/core/exposure_offset.h).
  bool image = false;
  using ImageVector = stereo_pixel_calibration::ImageErrorVector;
  using ImageMatrix = Eigen::Matrix<double, stereo_pixel_calibration::kImageErrorSize, stereo_pixel_calibration::kImageErrorSize>;
  ImageVector image_errors = ImageVector::Zero();
  ImageMatrix image_covariance = ImageMatrix::Zero();
  // The row block: the rectified rows' misalignment dv (px, right minus left) and its variance.
  bool row = false;
  double row_offset_px = 0.0;
  double row_offset_variance = 0.0;  // px^2
  // The range block (c0, c1 [1/rad], c2 [1/rad^2], d_b [rad]; RangeBearingCalibrationFactor) and
  // its covariance. Not part of the rig; saveAsRig writes it as keys, whose c0..c2 are
  // `import mrclam --range-correction`'s.
  Eigen::Vector4d range_bearing = Eigen::Vector4d::Zero();
  Eigen::Matrix4d range_bearing_covariance = Eigen::Matrix4d::Zero();
  // The feature offsets (featureOffsetSigmas; the window's: of the landmarks it has fused so far,
  // in the map's order): each feature's constant column offset (both
  // images) and u_r offset (px) with their variances (px^2; 0 where not estimated); not part of
  // the rig written back (a property of the run).
  struct FeatureOffset {
    int landmark_id = -1;
    double column_px = 0.0;
    double column_variance = 0.0;  // px^2
    double offset_px = 0.0;
    double variance = 0.0;  // px^2
  };
  std::vector<FeatureOffset> feature_offsets;
  // The odometry's delay against the camera the run used (s; src/core/odometry_delay.h): fitted
  // (sigma > 0, solvers/odometry_delay_profile.h) or given (sigma 0); not part of the rig,
  // handed over as keys.
  std::optional<double> odometry_delay_s;
  double odometry_delay_sigma_s = 0.0;

  // The rig a user passes back as --rig: with a stereo estimate, selfCalibratedRig
  // (solvers/self_calibrated_rig.h) — tilt in the mounting, every pixel correction folded into an
  // OpenCV calibration written beside it — so the frontend measures with the calibrated cameras.
  // The estimate itself and every standard deviation follow as extra keys the rig reader ignores
  // (tilt_correction_rad, baseline_scale, disparity_offset_px, column_offset_px, focal_ratio,
  // focal_scale, row_offset_px, exposure_offset_sigma_s (the offset itself is the rig's key), wheel_scale_left, wheel_scale_right, wheel_base_mm,
  // range_scale_c0, range_scale_c1, range_scale_c2, bearing_offset_rad, odometry_delay_s,
  // *_sigma). The disparity offset's standard deviation is handed over with
  // `drive_disparity_sigma_px` (SelfCalibrationConfig) added in quadrature unless the exposure
  // offset is modelled (stated by `rig` or estimated); throws Error for a
  // negative one.
  void saveAsRig(const std::string& path, const StereoRig& rig, double drive_disparity_sigma_px) const;
};

// What a rig file written by CalibrationEstimate::saveAsRig hands to the next run besides the
// rig itself (whose stereo head already has the estimate folded in): the wheel estimate with its
// standard deviations, and the stereo head's standard deviations. A run handed the file (`--rig`)
// scales its wheel increments and takes the wheel base (applyWheelCalibration), and a further
// self-calibration starts from these standard deviations as its priors instead of the wide
// defaults (applyPriors); its own estimate is then relative to the handed-over one, and carriedOn
// composes the two for the file the run writes. A user may widen the sigmas in the file for a
// robot whose calibration may have drifted since. A group whose first key is present must be
// complete (wheels: wheel_scale_left, wheel_scale_right, wheel_base_mm and their *_sigma*; stereo:
// the six *_sigma* of the head); row_offset_sigma_px and exposure_offset_sigma_s stand alone, and
// odometry_delay_s with its optional odometry_delay_sigma_s. (The exposure offset itself is the
// rig's: StereoRigParams::exposure_offset_s.)
struct CalibrationHandover {
  std::optional<Eigen::Vector3d> wheels;        // c_l, c_r (dimensionless), w (mm)
  std::optional<Eigen::Vector3d> wheel_sigmas;  // their standard deviations, same units
  std::optional<CalibrationEstimate::StereoVector> head_sigmas;  // CalibrationEstimate::head's order and units
  std::optional<double> row_offset_sigma_px;
  std::optional<double> exposure_offset_sigma_s;  // s
  // The odometry's delay (s, within +-2) and its sigma (0: given): a run handed the file re-times
  // its odometry by it unless told another delay.
  std::optional<double> odometry_delay_s;
  double odometry_delay_sigma_s = 0.0;

  bool empty() const {
    return !wheels && !head_sigmas && !row_offset_sigma_px && !exposure_offset_sigma_s && !odometry_delay_s;
  }
  // Reads the keys from a rig YAML; none of them: empty. Errors name the file and the key.
  static CalibrationHandover load(const std::string& rig_path);
  // The priors of a self-calibration from the handed-over sigmas: both wheel scales' the larger
  // of the two, the wheel base's relative to the handed-over wheel base, the head's one by one;
  // the row offset's and the exposure offset's replace the noise model's when that states one
  // (otherwise the row block, or the image block's exposure entry, is not estimated). Parameters the file does not hand over keep `config`'s priors.
  void applyPriors(SelfCalibrationConfig& config, UnmodelledNoise& noise) const;
  // The estimate of a run that was handed this calibration, in terms of the raw wheel increments
  // (what the next run needs): its wheel scales multiplied by the handed-over ones (covariance
  // scaled alike); a run that did not estimate the wheels passes the handed-over estimate on,
  // and one without an odometry delay of its own the handed-over delay.
  CalibrationEstimate carriedOn(const CalibrationEstimate& run) const;
};

// Runs the dataset with a wheel calibration (c_l, c_r, w mm): every step's wheel increments
// scaled by c_l and c_r, the odometry model's wheel base set to w. Throws Error for a
// non-positive or non-finite value.
void applyWheelCalibration(Dataset& dataset, const Eigen::Vector3d& wheels);

struct SelfCalibrationResult {
  std::vector<Estimate> trajectory;  // one per step
  CalibrationEstimate calibration;
  bool converged = false;
  int iterations = 0;
  int unidentified_observations = 0;
  bool covariance_ok = false;
};

// The named calibration parameter of the estimated blocks (wheel scales, wheel base, tilt
// correction, baseline scale, disparity and column offsets, focal ratio and scale; the keys of
// CalibrationEstimate::saveAsRig) that lies furthest from its nominal value, in the prior sigmas
// of `config` (the wheels' widened by the estimate's wheels_walk_variance). Beyond about 5 the
// solve has failed (a wrong data association, a false kidnap cut) or the prior is wrong; the
// batch acts on it (docs/estimators.md, "Where a cut goes"), and the CLI reports it. `nominal_wheel_base_mm`: the odometry model's wheel base. Empty parameter and 0
// when no block was estimated.
constexpr double kImplausiblePriorSigmas = 5.0;
struct PriorDistance {
  std::string parameter;
  double sigmas = 0.0;
};
PriorDistance furthestFromPrior(const CalibrationEstimate& estimate, const SelfCalibrationConfig& config,
                                double nominal_wheel_base_mm);

// The sigmas of the image block (CalibrationEstimate::image_errors' order) that `noise` states:
// k1_sigma, k2_sigma, tangential_sigma per camera, relative_rotation_sigma_rad per axis,
// exposure_offset_sigma_s; nullopt
// without the stereo block, with image_errors off, or when the noise model states none of them.
std::optional<CalibrationEstimate::ImageVector> imageErrorSigmas(const SelfCalibrationConfig& config,
                                                                 const UnmodelledNoise& noise);

// The row block's prior sigma (px): the noise model's row_offset_sigma_px; nullopt without the
// stereo block, with row_offset off, or when the noise model states no misalignment.
std::optional<double> rowOffsetSigma(const SelfCalibrationConfig& config, const UnmodelledNoise& noise);

// The pixel covariance of a calibrated pixel factor: pixelCovarianceFor (solvers/smoother_common.h)
// with the slide residual terms when the row block is estimated (without the feature's constant
// offset when `feature_offsets` says the caller estimates it) and, with the image block, its
// lens and relative-rotation terms on the rows only (the block carries their column errors;
// StereoPixelImageCalibrationFactor moves only the columns).
Eigen::Matrix4d calibratedPixelCovariance(const Observation& obs, const Landmark& landmark,
                                          const ObservationModelConfig& config, bool image_block,
                                          bool row_block = false, bool feature_offsets = false);

// The feature offsets' prior sigmas (px) per landmark of `map` that gets any: when the row block
// is estimated, each landmark whose kind the noise model states a constant for
// (featureOffsetSigma); empty otherwise.
struct FeatureOffsetPrior {
  int landmark_id = -1;
  FeatureOffsetSigma sigma;
};
std::vector<FeatureOffsetPrior> featureOffsetSigmas(const FieldMap& map, const SelfCalibrationConfig& config,
                                                    const UnmodelledNoise& noise);

// The batch smoother with `config` over a whole dataset from a known start (pixel observation
// model of config.residuals, no robust loss, no kidnap cuts).
SelfCalibrationResult selfCalibratingBatch(const Dataset& dataset, const InitialBelief& start,
                                           const SelfCalibrationConfig& config);

}  // namespace stereoloc
