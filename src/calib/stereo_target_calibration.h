#pragma once
// Calibrating a stereo head from checkerboard pairs (`stereoloc calibrate`): the OpenCV stereo
// calibration a rig file names (src/core/stereo_calibration.h), with the standard deviations of
// what it estimates, so that a self-calibration can start from the calibration's stated
// uncertainty instead of a guess.
//
//   detect      cv::findChessboardCorners (global threshold), else the sector-based detector,
//               else the classic with adaptive thresholds, refined by cv::cornerSubPix; a pair
//               is used when both images show the whole board, its two corner lists put in the
//               same order (the board's half turn is ambiguous to the detector)
//   calibrate   cv::calibrateCamera per camera, cv::stereoCalibrate for both together, then a few
//               damped Gauss-Newton steps of the joint problem (src/calib/stereo_target_problem.h:
//               both images of every pair, both cameras' intrinsics, R, T and every board pose);
//               before it, pairs whose two images do not fit the others' stereo geometry are
//               left out
//   uncertainty each standard deviation the larger of the fit's, Sigma = s^2 (J^T J)^-1 at that
//               optimum (s^2 the residuals' variance per coordinate), and the pairs' spread,
//               leave-one-pair-out (jackknife): on real photographs a view's corner errors are
//               not independent, and the fit's alone was 1.8 times too small (docs/
//               realistic_world.md, "Calibrating the stereo head")
//
// What a checkerboard cannot tell: the head's mounting on the robot (height, tilt, the rectified
// camera's yaw against the robot's heading). Those stay in the rig YAML with their own sigmas.
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "src/core/checker_board.h"
#include "src/core/stereo_calibration.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

struct TargetCalibrationOptions {
  int distortion_coefficients = 4;  // 4 (k1 k2 p1 p2), 5 (+ k3) or 8 (rational: + k3 k4 k5 k6)
  bool same_focal_axes = false;     // true: fx = fy per camera (CALIB_FIX_ASPECT_RATIO)
  int min_views = 6;                // usable pairs needed
  // A pair whose right corners lie further than outlier_factor times the pairs' median (and
  // kOutlierFloorPx) from where its left image and the pairs' median stereo geometry put them
  // is left out, the worst first, while more than min_views remain; 0 keeps every pair the
  // detector found.
  double outlier_factor = 3.0;
  static constexpr double kOutlierFloorPx = 0.5;
};

// One image pair as handed in: a name for messages (its file) and the two raw images.
struct TargetPair {
  std::string name;
  cv::Mat left, right;  // 8-bit, grey or BGR, both of one size
};

struct TargetPairResult {
  std::string name;
  bool used = false;
  std::string reason;    // why not used ("" when used)
  double rms_px = 0.0;   // reprojection RMS over both images after calibration (used pairs)
  // The board's corners in the raw images (px), in one order in both, when both show it.
  std::vector<cv::Point2f> left_corners, right_corners;
};

// Standard deviations (first order) of the calibration's parameters and of the rectified head
// quantities the smoothers' stereo self-calibration estimates (solvers/self_calibration.h).
struct TargetCalibrationSigmas {
  double focal_px[2][2] = {{0, 0}, {0, 0}};      // [camera][fx, fy]
  double principal_px[2][2] = {{0, 0}, {0, 0}};  // [camera][cx, cy]
  std::vector<double> distortion[2];             // per camera, OpenCV order
  double rotation_rad[3] = {0, 0, 0};            // R's rotation vector, per axis
  double translation_mm[3] = {0, 0, 0};
  double baseline_mm = 0.0;                      // |T|
  // Rectified head (solvers/self_calibration.h's q): baseline scale |T| / |T_true|, the right
  // camera's focal length against the left's (fx2 / fx1), the left's focal scale, and the
  // disparity error at infinity, d = cx1 - cx2 - fx1 w_y (px) with w the rotation vector of R.
  double baseline_scale = 0.0;
  double focal_ratio = 0.0;
  double focal_scale = 0.0;
  double disparity_offset_px = 0.0;
  // Per camera, where a ray lands at the image's corners relative to one at its principal point
  // (the largest standard deviation of the four, px; cv::projectPoints' Jacobian in the camera's
  // intrinsics): the lens model is fitted where the board's corners were and extrapolated
  // beyond, so views that miss the image's edges leave it wide (`calibrate` warns above
  // kEdgeWarningPx).
  double image_corner_px[2] = {0.0, 0.0};
  static constexpr double kEdgeWarningPx = 1.0;
  // The rectified left camera's direction: stereoRectify turns it half the way to the right
  // camera and lines its x up with T, so errors in R and T turn the frame the rig measures
  // bearings and tilt in: its yaw as a column offset (px at the rectified focal length) and its
  // pitch as a tilt (rad). From R1's central differences in R's rotation vector and T.
  double column_offset_px = 0.0;
  double tilt_rad = 0.0;
};

struct TargetCalibrationResult {
  StereoCalibration calibration;  // rectified (R1 ... Q filled)
  double rms_px = 0.0;            // stereo reprojection RMS over every used corner, px
  // How far apart in row a used corner's two images are once rectified with the calibration
  // (RMS, px): what stereo matching along rows needs near zero.
  double rectified_row_rms_px = 0.0;
  int used_pairs = 0;
  int corners_per_image = 0;
  std::vector<TargetPairResult> pairs;  // in the order handed in
  TargetCalibrationSigmas sigmas;              // stated: each the larger of the two below
  TargetCalibrationSigmas fit_sigmas;          // the fit's covariance, s^2 (J^T J)^-1
  TargetCalibrationSigmas pair_spread_sigmas;  // the leave-one-pair-out (jackknife) covariance
};

// Throws Error naming the pair for images of different sizes or types, and for fewer than
// options.min_views usable pairs (listing why the others were not used); an invalid board or
// options name the field.
TargetCalibrationResult calibrateStereoFromTargets(const std::vector<TargetPair>& pairs, const CheckerBoard& board,
                                                   const TargetCalibrationOptions& options = TargetCalibrationOptions());

// Writes the rig a calibrated head gives (`calibrate --rig-out`): `mounting`'s height, tilt,
// offset and noise fields with `result`'s calibration (StereoRig::save, the calibration beside it
// as <rig stem>_calibration.yml), and the standard deviations a self-calibration takes as its
// priors when the rig is handed to it (`--rig`; CalibrationHandover in solvers/self_calibration.h):
// baseline_scale_sigma, disparity_offset_sigma_px, focal_ratio_sigma and focal_scale_sigma from
// the calibration; tilt_correction_sigma_rad and column_offset_sigma_px the mounting's, which the
// board does not see (the head's pitch and yaw on the robot), combined in quadrature with the
// calibration's own (TargetCalibrationSigmas::tilt_rad, column_offset_px); the disparity offset's
// likewise with `drive_disparity_sigma_px`, what a drive adds that a still board cannot show (two
// cameras exposing dt apart on a robot turning at w shift the disparity by f w dt; on the
// realistic world's circle ~0.3 px, and without it the self-calibrations were over-confident,
// docs/realistic_world.md), unless the mounting states the cameras' exposure offset
// (StereoRigParams::exposure_offset_s: the pairs are then moved to one instant), which the rig
// keeps. Atomic; throws Error for a mounting sigma that is not positive.
void saveCalibratedRig(const std::string& path, const StereoRigParams& mounting, const TargetCalibrationResult& result,
                       double tilt_sigma_rad, double column_offset_sigma_px, double drive_disparity_sigma_px);

// The corners of `board` in one image, in the detector's order (sub-pixel, px); empty when the
// whole board is not found. Exposed for tests and overlays.
std::vector<cv::Point2f> detectBoardCorners(const cv::Mat& image, const CheckerBoard& board);

// Reverses `corners` (one board's, as detectBoardCorners gives them) when they run the other way
// from `reference`, another image's of the same board: the detector may list a board from either
// end, and two views from nearly the same direction show its first-to-last diagonal pointing the
// same way whatever the disparity.
void orderLike(const std::vector<cv::Point2f>& reference, std::vector<cv::Point2f>& corners);

}  // namespace stereoloc
