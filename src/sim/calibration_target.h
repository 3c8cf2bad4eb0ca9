#pragma once
// Checkerboard views for calibrating a stereo head: what a user photographs with the robot's own
// cameras before calibrating them (`simulate --calibration-views N`, `stereoloc calibrate`).
//
// Each view places the board (src/core/checker_board.h) in front of the head at a random
// distance and attitude such that the board and its white margin lie inside both raw images,
// and renders both raw cameras of `truth` (distortion and the right camera's rotation included)
// by casting each pixel's rays onto the board plane: `supersampling`^2 rays per pixel, averaged
// (the antialiasing a real sensor's pixel area gives), then Gaussian sensor noise. Grey images
// (CV_8UC1), deterministic for a seed.
#include <opencv2/core.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "src/core/checker_board.h"
#include "src/core/stereo_calibration.h"

namespace stereoloc {

struct CalibrationViewOptions {
  int views = 20;
  double min_distance_mm = 180.0;  // board centre from the left camera, along its optical axis
  double max_distance_mm = 400.0;
  double max_tilt_rad = 0.6;       // the board's normal off the line of sight, about each board axis
  double max_spin_rad = 0.3;       // the board's rotation about its own normal
  int supersampling = 4;           // rays per pixel and axis (>= 1)
  double noise_sigma = 2.0;        // grey levels, Gaussian, per pixel
  int dark = 30, light = 220, background = 110;  // grey levels of the squares and the scene behind
  int max_attempts_per_view = 200;  // poses drawn until one fits in both images
};

struct CalibrationView {
  cv::Mat left, right;  // CV_8UC1, the raw images
  cv::Matx33d R;        // board -> left raw camera: X_left = R X_board + t (mm)
  cv::Vec3d t;
};

// Throws Error for invalid options or a board that does not fit both images at any drawn pose.
std::vector<CalibrationView> renderCalibrationViews(const StereoCalibration& truth, const CheckerBoard& board,
                                                    const CalibrationViewOptions& options, uint64_t seed);

// Renders the views and writes them as `dir`/left_NNN.png and right_NNN.png, with the cameras
// they were taken with as `dir`/true_calibration.yml (the score a calibration is checked
// against; `simulate --calibration-views`). Creates `dir`.
void writeCalibrationViews(const std::string& dir, const StereoCalibration& truth, const CheckerBoard& board,
                           const CalibrationViewOptions& options, uint64_t seed);

}  // namespace stereoloc
