#pragma once
// Import of the UTIAS Multi-Robot Cooperative Localization and Mapping dataset (MR.CLAM,
// Leung et al. 2011) into stereoloc's Step stream: real differential-drive robots with
// commanded velocities, barcode range-bearing measurements of 15 point landmarks and Vicon
// ground truth.
//
// Files (whitespace separated, '#' comment lines): Barcodes.dat (subject, barcode),
// Landmark_Groundtruth.dat (subject, x, y, sx, sy [m]), RobotN_Odometry.dat (t [s], v [m/s],
// omega [rad/s]), RobotN_Measurement.dat (t, BARCODE, range [m], bearing [rad]),
// RobotN_Groundtruth.dat (t, x, y, theta). Metres become mm on reading.
//
// Time base: Step::t is seconds since the first odometry row (ImportReport::epoch_s holds that
// row's Unix time). Steps: a fixed grid at `rate_hz` from the first to the last odometry row
// (and a final step at the last row, so the whole commanded motion is in the steps),
// plus one step at every measurement time (measurements closer than merge_tolerance_s share a
// step; a grid time that close to a measurement step is replaced by it), so no measurement is
// moved in time by more than merge_tolerance_s.
//
// Odometry: each command (v, omega) is held from its row's time to the next row's. Over a
// piece of constant (v, omega) lasting dt the wheels travel exactly
//   d_left = (v - omega w/2) dt,   d_right = (v + omega w/2) dt,
// and the arc model of src/core/odometry_model.h, alpha = (d_r - d_l)/w = omega dt, arc length
// (d_r + d_l)/2 = v dt, reproduces the exact unicycle motion. A step spanning several pieces
// gets the sum of their wheel travels (exact wheel distances; the pose is then the
// constant-curvature arc through them, second order in the command change within the step).
#include <Eigen/Core>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/measurement_model.h"
#include "src/core/observation_correlation.h"
#include "src/core/odometry_model.h"
#include "src/core/pose2.h"
#include "src/core/types.h"

namespace stereoloc {

// ---- raw rows (units converted: mm, rad, s absolute) ----
struct MrclamOdometryRow {
  double t = 0;      // s (Unix time)
  double v = 0;      // mm/s, forward
  double omega = 0;  // rad/s, counter-clockwise
};
struct MrclamMeasurementRow {
  double t = 0;        // s (Unix time)
  int barcode = 0;     // the BARCODE read, not the subject
  double range = 0;    // mm
  double bearing = 0;  // rad
  long line = 0;       // 1-based line in the file (for messages)
};
struct MrclamPoseRow {
  double t = 0;  // s (Unix time)
  Pose2 pose;    // mm, rad
};

// Readers: every malformed row (wrong field count, not a finite number, time going backwards,
// duplicate subject/barcode) throws stereoloc::Error "FILE:LINE: reason"; a file with no data
// row throws "FILE: no data rows".
std::map<int, int> readMrclamBarcodes(const std::string& path);  // barcode -> subject
std::map<int, Eigen::Vector2d> readMrclamLandmarks(const std::string& path);  // subject -> (x, y) mm
std::vector<MrclamOdometryRow> readMrclamOdometry(const std::string& path);
std::vector<MrclamMeasurementRow> readMrclamMeasurements(const std::string& path);
std::vector<MrclamPoseRow> readMrclamGroundtruth(const std::string& path);

// Subjects 1-5 are the robots; 6-20 the landmarks.
constexpr int kMrclamRobotCount = 5;

// Wheel travels (mm) of a differential drive with wheel base w (mm) moving at constant forward
// speed v (mm/s) and turn rate omega (rad/s) for dt seconds.
WheelIncrements wheelIncrementsForTwist(double v, double omega, double dt, double wheel_base_mm);

// Cumulative wheel travel of piecewise-constant commands (each held until the next row's time;
// the last row has no duration). Queries are exact; times outside the rows are clamped.
class WheelOdometer {
 public:
  WheelOdometer(const std::vector<MrclamOdometryRow>& rows, double wheel_base_mm);
  WheelIncrements travelAt(double t) const;  // total (left, right) mm from the first row to t
  WheelIncrements between(double t0, double t1) const;

 private:
  std::vector<MrclamOdometryRow> rows_;
  std::vector<WheelIncrements> cumulative_;  // at each row's time
  double w_;
};

// Ground truth at time t, linear in x, y and on the circle in theta (via wrapAngle); nullopt
// outside the rows' span or when the bracketing rows are more than max_gap_s apart.
std::optional<Pose2> interpolateGroundtruth(const std::vector<MrclamPoseRow>& gt, double t, double max_gap_s);

// Robust error statistics: median (bias) and sigma = 1.4826 MAD, plus the plain moments.
struct RobustErrorStats {
  size_t count = 0;
  double median = 0, mad_sigma = 0;  // robust location and scale
  double mean = 0, std = 0, max_abs = 0;
  size_t outliers = 0;               // |e - median| > 5 mad_sigma
};
RobustErrorStats robustErrorStats(std::vector<double> errors);

// Odometry noise fitted against ground truth over non-overlapping windows of about window_s.
// Per window, with S = sum |d_l| + |d_r| over its steps (the model's wheel variance sum for k=1):
//   heading error e_th = dtheta_gt - dtheta_odo, var = k S / w^2       (B.1, B.6)
//   along-track error e_a (gt relative pose in the odometry's end frame), var ~= k S / 4
// k = median(e^2 / (S/w^2)) / median(chi2_1) (robust against slip and Vicon dropouts), likewise
// for the along-track error; windows with S < min_travel_mm are left out. The commanded
// velocities' errors are mostly a common speed error of both wheels, which independent wheel
// noise cannot express (it would need k_along >> k_heading): importMrclam takes k from the
// heading and puts the along-track and lateral excess into the per-step control floor.
struct OdometryNoiseFit {
  size_t windows = 0;
  double k_heading = 0;   // mm^2/mm, from the heading errors
  double k_along = 0;     // mm^2/mm, from the along-track errors
  double lateral_sigma_per_m = 0;  // robust sigma of the cross-track error per metre travelled
  double median_travel_mm = 0;     // median S over the windows
  double mean_steps = 0;           // mean number of steps per window
  RobustErrorStats heading_error, along_error, lateral_error;  // rad, mm, mm per window
};
OdometryNoiseFit fitOdometryNoise(const std::vector<Step>& steps, const std::vector<std::optional<Pose2>>& groundtruth,
                                  double wheel_base_mm, double window_s = 1.0, double min_travel_mm = 20.0);

// The barcode camera's range error depends on where the landmark is in the image (its
// bearing): measured against the motion capture, ranges near the image centre read about 2 %
// long and ranges 25 degrees off-axis 4-8 % short, on both robots. The model:
//   measured range = (1 + c0 + c1 b + c2 b^2) true range,   b the measured bearing (rad),
// and the correction divides by that factor.
struct RangeCorrection {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();  // (c0, c1 [1/rad], c2 [1/rad^2])
  double factor(double bearing) const { return rangeFactorAt(c.data(), bearing); }
  // The corrected range; throws stereoloc::Error when the factor is outside [0.5, 2] (a
  // correction that halves or doubles a range is not a calibration of this camera).
  double correct(double range, double bearing) const;
};

// Fits c by iteratively reweighted least squares (Huber, 1.345 robust sigmas) of
// measured / true - 1 on (1, b, b^2). Throws stereoloc::Error with fewer than 10 samples or a
// singular design (every bearing the same).
struct RangeSample {
  double measured = 0, truth = 0, bearing = 0;  // mm, mm, rad
};
RangeCorrection fitRangeCorrection(const std::vector<RangeSample>& samples);

// The robot's drive follows a command some time after its row's timestamp (the drive's
// latency, or the odometry log's clock running ahead of the camera's). Against the motion
// capture MR.CLAM's robots turn as commanded 0.25-0.3 s after the command's time, while the
// barcode sightings agree with it to within 0.05 s. The import then holds each command from its
// row's time + delay; the delay is fitted as the one that minimises the robust spread of the
// commanded heading change against the ground truth's over windows of window_s (a grid over
// [min_s, max_s] at step_s, refined by a parabola through the best grid point and its
// neighbours).
struct CommandDelayFit {
  double delay_s = 0;
  size_t windows = 0;              // windows with ground truth at both ends
  double heading_sigma_at_zero = 0;  // rad, robust sigma of the window's heading error at delay 0
  double heading_sigma = 0;          // rad, at the fitted delay
};
struct CommandDelaySearch {
  double window_s = 0.5;
  double min_s = -0.5, max_s = 1.0, step_s = 0.01;
  double max_groundtruth_gap_s = 0.1;  // no window across a longer Vicon gap
};
// Throws stereoloc::Error with fewer than 20 windows, commands that never turn, or a minimum
// on the search interval's edge (no delay inside it explains the motion better).
CommandDelayFit fitCommandDelay(const std::vector<MrclamOdometryRow>& odometry, const std::vector<MrclamPoseRow>& gt,
                                const CommandDelaySearch& search = {});

// Where a correction of the import comes from: none, fitted against this run's ground truth, or
// given (fitted on another run).
enum class CorrectionSource { None, Fit, Given };

struct MrclamImportConfig {
  int robot = 1;                    // 1..5 (the files RobotN_*.dat)
  double rate_hz = 10.0;            // fixed step rate
  // Wheel base (mm) used to turn (v, omega) into wheel travels. MR.CLAM's robots are iRobot
  // Create bases (about 260 mm); the trajectory is exact for any value, only the noise model
  // (k per mm of wheel travel) depends on it.
  double wheel_base_mm = 260.0;
  double merge_tolerance_s = 1.5e-3;  // timestamps have 1 ms resolution
  double max_groundtruth_gap_s = 1.0; // no ground truth interpolated across a longer Vicon gap
  double map_margin_mm = 1000.0;      // added around the landmarks and the robot's ground truth
  std::optional<double> sigma_range_mm;     // default: estimated (robust sigma vs ground truth)
  std::optional<double> sigma_bearing_rad;  // default: estimated
  // Window of the odometry noise fit, s. The commands' errors are slow: the fitted k per mm
  // grows with the window up to about 4 s (MR.CLAM robot 1: 0.13 at 1 s, 0.21 at 4 s), so a
  // 1 s fit understates the error over the gaps between sightings that the filters integrate.
  double odometry_window_s = 1.0;
  // Multiplies the fitted wheel variance k and the x, y control floors. The 1 s fit is
  // robust (medians) and sees no slow biases of the commanded velocities, so over a whole run
  // the model is optimistic (dead-reckoning NEES ~40); 4 makes the filters gate less.
  double odometry_noise_scale = 1.0;
  // The barcode camera's errors repeat over consecutive sightings (src/core/
  // observation_correlation.h). The import always fits their correlation against the ground
  // truth (pairs up to correlation_max_lag_s apart) and reports it; with correlated_errors it
  // also inflates each sighting's sigmas by it, so that estimators fusing the sightings as
  // independent take from a burst the information it holds.
  bool correlated_errors = false;
  double correlation_max_lag_s = 120.0;
  // Range correction (RangeCorrection): none, fitted against this run's ground truth, or given
  // (coefficients fitted on another run). Applied to every range before the sigmas and the
  // error correlation are estimated.
  CorrectionSource range_correction = CorrectionSource::None;
  RangeCorrection given_range_correction;  // used with CorrectionSource::Given
  // Command delay (CommandDelayFit): none, fitted against this run's ground truth, or given (s).
  CorrectionSource command_delay = CorrectionSource::None;
  double given_command_delay_s = 0;  // used with CorrectionSource::Given; |delay| <= 2 s
  void validate() const;              // throws stereoloc::Error naming the field
};

struct ImportReport {
  int robot = 0;
  double epoch_s = 0;     // Unix time of Step::t = 0 (the first odometry row)
  double duration_s = 0;  // last step time
  size_t odometry_rows = 0, measurement_rows = 0, groundtruth_rows = 0;
  size_t steps = 0, grid_steps = 0, measurement_steps = 0;  // measurement_steps: steps with observations
  size_t steps_with_groundtruth = 0;
  size_t observations = 0;                // kept (landmark) measurements
  size_t dropped_other_robot = 0;         // barcodes of subjects 1-5
  size_t dropped_unknown_barcode = 0;     // barcodes not in Barcodes.dat
  size_t dropped_outside_odometry = 0;    // before the first or after the last odometry row
  size_t measurements_outside_groundtruth = 0;  // kept, but no ground truth to evaluate them
  double max_time_shift_s = 0;            // largest |measurement time - its step time|
  RobustErrorStats range_error;           // mm, measured - true (ground-truth pose)
  RobustErrorStats bearing_error;         // rad, wrapped measured - true
  double sigma_range_mm = 0, sigma_bearing_rad = 0;  // the sigmas written into the observations
  bool sigmas_estimated = true;
  // Correlation of the errors of two sightings dt apart, of the same landmark and of different
  // ones (range in mm, bearing in rad; fitted whether or not applied).
  ErrorCorrelationFit range_same, range_other, bearing_same, bearing_other;
  CorrectionSource range_correction_mode = CorrectionSource::None;
  RangeCorrection range_correction;         // applied (identity with None)
  RobustErrorStats range_error_uncorrected;  // mm, measured - true before the correction
  CorrectionSource command_delay_mode = CorrectionSource::None;
  CommandDelayFit command_delay;  // delay_s applied (0 with None); the fit's figures with Fit
  bool correlated_errors = false;          // the sigmas were inflated by the fit
  double mean_range_variance_factor = 1;   // mean over the observations of the variance factor
  double mean_bearing_variance_factor = 1;
  ObservationCorrelation correlation() const;  // the four fits' correlations
  OdometryNoiseFit odometry_fit;
  OdometryParams odometry;                // the noise model chosen from the fit (times the scale)
  std::string summary() const;            // multi-line human-readable text (degrees for angles)
};

struct MrclamImport {
  std::string name;  // "mrclam6_robotN"-style
  FieldMap map;
  OdometryParams odometry;
  std::vector<Step> steps;
  std::vector<std::optional<Pose2>> groundtruth;  // one per step
  std::optional<Pose2> initial_pose;              // ground truth at the first step, if any
  ImportReport report;
};

// The 15-landmark map: ids = subject numbers, type Point, unique, z = 0; bounds = bounding box
// of the landmarks and `extent` points plus margin; no field geometry.
FieldMap mrclamMap(const std::map<int, Eigen::Vector2d>& landmarks, const std::vector<Eigen::Vector2d>& extent,
                   double margin_mm, const std::string& name);

// Reads SRC_DIR/{Barcodes,Landmark_Groundtruth,RobotN_*}.dat and builds the step stream.
MrclamImport importMrclam(const std::string& src_dir, const MrclamImportConfig& config);

}  // namespace stereoloc
