#pragma once
// What `localize` and `refine` share: their options and the run.
#include <CLI/CLI.hpp>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "src/pipeline/frontend_source.h"
#include "src/eval/evaluation.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/rig_handover.h"

namespace stereoloc::cli {

struct LocalizeArgs {
  std::string dataset, method = "ekf", init = "known", out, tum;
  uint64_t seed = 1;
  MethodOptions options;
  std::string loss = "none";
  std::string observation_model = "pixel_columns";  // batch and window: range_bearing | pixel_columns | pixels
  std::string frontend = "pixels";            // pixels | images (src/pipeline/frontend_source.h)
  std::string frontend_landmarks = "all";     // all | goal_corners (with --frontend images)
  std::string frontend_params;                // frontend parameters YAML (empty: defaults)
  std::string calibrate;                      // "", "odometry", "stereo", "odometry,stereo"
  std::string consider;                       // the same blocks considered, not estimated (ekf)
  std::string calibration_out;                // rig YAML with the calibration estimate
  std::string field_out;                      // map YAML of the field the field block measured
  double drive_disparity_sigma_px = SelfCalibrationConfig().drive_disparity_sigma_px;  // px, added to its offset's sigma
  std::string noise_model;                    // UnmodelledNoise YAML (solvers/smoother_common.h)
  std::string rig;                            // rig YAML in place of the dataset's (src/pipeline/rig_handover.h)
  std::string map;                            // map YAML in place of the dataset's (useMap, same header)
  std::optional<std::string> odometry_delay;   // "fit" or seconds (src/core/odometry_delay.h)
  std::string odometry_delay_search;          // "MIN,MAX,STEP" seconds (solvers/odometry_delay_profile.h)
  std::string odometry_delay_profile;         // CSV of the fit's profile (delay_s, cost)

};

// Each method's options are refused with a method that does not use them (UsageError naming the
// option), rather than silently ignored.
void checkMethodOptions(const LocalizeArgs& args, const CLI::App& sub);
void runLocalize(const LocalizeArgs& args);
// The line `localize` and `refine` print against the ground truth: RMSE, mean NEES and its
// position (2 dof) and heading (1 dof) parts; nothing without ground truth.
void printAgainstTruth(const TrajectoryMetrics& metrics);
// The method options with the parsed --init, --loss, --observation-model and --calibrate;
// throws UsageError.
MethodOptions parseMethodOptions(const LocalizeArgs& args);
// --odometry-delay: none (not given), "fit", or seconds (*given_s); UsageError otherwise.
OdometryDelayMode parseOdometryDelay(const std::optional<std::string>& text, double* given_s);
// The odometry delay the run used, into the calibration estimate it writes (--calibration-out):
// a fitted one with its sigma, a given one (--odometry-delay S) with sigma 0; a delay the rig
// file handed over is left for CalibrationHandover::carriedOn to pass on with its own sigma.
void recordOdometryDelay(CalibrationEstimate& calibration, const MethodOptions& options,
                         const std::optional<OdometryDelayEstimate>& fitted, const CalibrationHandover& handover);
// The line `localize` and `refine` print for the odometry delay: given, handed over by the rig
// file, or fitted (estimate, standard deviation, the search); nothing without a delay.
void printOdometryDelay(const MethodOptions& options, const std::optional<OdometryDelayEstimate>& fitted,
                        const CalibrationHandover& handover);
// Writes --odometry-delay-profile (when given): the fit's profile as CSV `delay_s,cost`, one row
// per batch solve in the order of the delays (cost: 1/2 sum |r|^2 with the delay's prior).
void writeOdometryDelayProfile(const std::string& path, const std::optional<OdometryDelayEstimate>& fitted);
// --calibrate or --consider (at most one given; "": none) as the self-calibration's blocks, with
// SelfCalibrationConfig::consider set for --consider; throws UsageError naming the option.
SelfCalibrationConfig calibrationOptions(const std::string& calibrate, const std::string& consider);
// The batch holds the wheel calibration constant over the run: says so on stdout when `o` asks it
// to calibrate the wheels with a noise model whose wheels drift (the window and EKF follow that).
void noteConstantWheelsInTheBatch(const MethodOptions& o);
// Writes `calibration_out` (--calibration-out, when not empty) and prints the estimate to `out`
// (calibration null: no --calibrate, and --calibration-out is then a usage error): the run's,
// carried on from the calibration --rig handed over (CalibrationHandover::carriedOn), and how
// far the run's own lies from its priors.
void reportCalibration(const std::string& calibration_out, std::FILE* out, const CalibrationEstimate* calibration,
                       const StereoRig& rig, const SelfCalibrationConfig& config, double nominal_wheel_base_mm,
                       const CalibrationHandover& handover);
// --frontend, --frontend-landmarks, --frontend-params (shared with `stream`).
void addFrontendOptions(CLI::App* sub, std::string& frontend, std::string& landmarks, std::string& params_path);
// --field-out: the map of the field as `calibration`'s field block measured it, with the
// estimate's covariance (nothing when `path` is empty; UsageError without the field block).
void writeMeasuredField(const std::string& path, const FieldMap& map, const CalibrationEstimate* calibration);
// The dataset of localize and refine: loaded, on --map's map when given (useMap), on --rig's rig
// when given (useRig; `handover` receives what the file hands over, and `options` its priors),
// then with --frontend images the frontend's observations in place of its own (a one-line
// summary on stdout).
Dataset loadRunDataset(const LocalizeArgs& args, MethodOptions& options, CalibrationHandover& handover);
// Adds the options; `method_option` false for refine (always the batch smoother: no --method,
// --particles or --window).
void addLocalizeOptions(CLI::App* sub, const std::shared_ptr<LocalizeArgs>& args, bool method_option);

}  // namespace stereoloc::cli
