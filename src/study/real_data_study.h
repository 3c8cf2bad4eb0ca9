#pragma once
// `stereoloc realdata DATASET_DIR`: runs every estimator on an imported real dataset (e.g.
// `stereoloc import mrclam`) from the same initial belief and prints the results table against
// ground truth: position and theta RMSE, NEES (whether the covariance is honest), ms per step,
// non-finite estimates, and each estimator's position RMSE relative to the EKF's.
//
// Estimators: dead reckoning (odometry only, predictPose), EKF, particle filter, sliding window
// (W keyframes; its fixed-lag output from finish() and its real-time output from process()),
// without and with a robust loss, batch smoother without and with a robust loss on the
// range-bearing factors; the EKF, the window and the batch calibrating the odometry (wheel
// scales and wheel base), and calibrating the odometry and the range sensor (its range factor
// across the field of view and its bearing offset, the range block of solvers/self_calibration.h).
// With an odometry delay every estimator runs on the odometry re-timed by it (given, or fitted
// by the batch calibrating odometry and range, solvers/odometry_delay_profile.h).
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include "solvers/odometry_delay_profile.h"
#include "solvers/sliding_window_smoother.h"
#include "src/pipeline/methods.h"

namespace stereoloc {

struct RealDataStudyOptions {
  std::string dataset_dir, csv_path;
  int window = 20;
  int keyframe_max_steps = SlidingWindowConfig().keyframe_max_steps;  // 1: every step a window pose
  int window_lost_after = SlidingWindowConfig().gate.lost_after;
  bool gate = true;                   // false: the EKF and the window fuse every observation
  int particles = 2000;
  unsigned long seed = 1;
  std::string robust = "huber";
  double robust_scale = 1.345;
  long max_steps = 0;                 // 0: all
  double init_sigma_xy = 50.0;        // mm
  double init_sigma_theta_deg = 2.0;  // deg
  std::string batch_guess = "filter"; // initial guess of the batch: "filter" (EKF pass) or "odometry"
  std::string only;                   // comma-separated subset of estimator keys
  // The odometry runs late against the camera (src/core/odometry_delay.h): every estimator runs
  // on the steps re-timed by the given delay, or by the one the batch calibrating odometry and
  // range finds (solvers/odometry_delay_profile.h).
  OdometryDelayMode odometry_delay = OdometryDelayMode::None;
  double given_odometry_delay_s = 0.0;  // s
  OdometryDelaySearch odometry_delay_search;
  std::FILE* console = stdout;        // settings and the table
  std::FILE* log = stderr;            // per-estimator progress; null: none
};

// The estimators' keys, in the table's order: what RealDataStudyOptions::only may name.
const std::vector<std::string>& realDataEstimatorKeys();

// Whether the study runs an estimator whose key starts with one of `prefixes` (every estimator
// runs when `only` is empty): which options a run uses, e.g. {"window"} for the window's size.
bool realDataRunsAny(const RealDataStudyOptions& options, const std::vector<std::string>& prefixes);

// Throws UsageError naming the option for an unknown --only key, --batch-guess or --robust.
void checkRealDataStudyOptions(const RealDataStudyOptions& options);

// Runs the study: prints the settings and the table to `console`, per-estimator progress to `log`,
// and writes csv_path when set. Bad options throw UsageError; non-finite estimates Error.
void runRealDataStudy(const RealDataStudyOptions& options);

}  // namespace stereoloc
