#pragma once
// The simulator's error profile: what separates the simulated robot from the one its estimators
// are told about. `ideal` (every value 0) is the exact world of simulator.h; `realistic` holds
// the defaults below; a YAML file (cv::FileStorage, keys as the field names, missing keys 0)
// gives any other mix. Values are drawn once per dataset (per step for vibration and slip) from
// one engine, and every drawn value is written to the dataset's truth (errors.yaml).
//
// Sources of the realistic defaults (the thesis gives the Tinyphoon's nominal geometry: 75 mm
// wheel base L1898, camera 70 mm above the floor; it gives no tolerances):
//   rig        focal 0.5 %, principal point 1 px, baseline 1 %, relative camera rotation 0.1 deg,
//              head tilt 0.5 deg, camera height 1 mm: typical residuals of a checkerboard
//              calibration of a small CMOS stereo head and of measuring its mounting by hand.
//   lens       k1 -0.20 +- 0.03, k2 0.05 +- 0.02, tangential 0 +- 0.001: a 60 deg M12 lens on
//              a small CMOS module (typical small stereo heads); the calibration handed to the
//              estimators has k1 +- 0.01, k2 +- 0.005, p +- 0.0003 estimation error.
//   images     10 ms exposure (indoor lighting, small CMOS at 10 Hz), averaged over 3
//              sub-exposures; left/right exposure offset uniform in +-5 ms (two cameras
//              triggered by one host loop, not hardware-synchronised).
//   vibration  pitch and roll 0.2 deg per step, independent (a 70 mm high camera on a small
//              robot on a real floor, typical).
//   odometry   wheel radius 0.5 % per wheel (moulded rubber tyres), effective wheel base 2 %
//              (the contact line of a 5 mm wide tyre moves by ~1.5 mm on 75 mm), slip on 2 % of
//              the steps with the slipping wheel's reading 10-30 % too large, odometry/image
//              time offset 5 ms (typical small diff-drive robots).
//   field      not in `realistic` (0): a field built and painted by hand has each of its
//              dimensions off by a few mm (field_dimension_sigma_mm; data/profile_hand_built_field.yaml
//              states 2 mm, typical of a hand-built field: no rule or source gives a tolerance).
// Sigmas are 1-sigma of zero-mean Gaussians unless stated otherwise. Units: rad, mm, px, s;
// relative errors as fractions.
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/stereo_calibration.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

struct ErrorProfile {
  std::string name = "ideal";
  // True rig against the given calibration, per dataset.
  double focal_rel_sigma = 0.0;            // fraction, per camera
  double principal_sigma_px = 0.0;         // px, per camera and axis
  double baseline_rel_sigma = 0.0;         // fraction
  double relative_rotation_sigma_rad = 0.0;  // rad, per axis of the right camera's rotation
  double tilt_sigma_rad = 0.0;             // rad, head tilt
  double height_sigma_mm = 0.0;            // mm, camera height
  // Lens distortion in the rendering (per camera) and the error of its calibrated estimate.
  double k1_mean = 0.0, k1_sigma = 0.0, k2_mean = 0.0, k2_sigma = 0.0, tangential_sigma = 0.0;
  double k1_estimate_sigma = 0.0, k2_estimate_sigma = 0.0, tangential_estimate_sigma = 0.0;
  // Images.
  double exposure_s = 0.0;                 // s, motion blur over this exposure
  int exposure_samples = 3;                // sub-exposures averaged when exposure_s > 0
  double exposure_offset_max_s = 0.0;      // s, right exposure offset uniform in +-this
  // Vibration per step.
  double pitch_sigma_rad = 0.0, roll_sigma_rad = 0.0;
  // Odometry.
  double wheel_radius_rel_sigma = 0.0;     // fraction, per wheel
  double wheel_base_rel_sigma = 0.0;       // fraction
  double slip_probability = 0.0;           // per step
  double slip_min = 0.0, slip_max = 0.0;   // slipping wheel reads (1 + U(min, max)) x its motion
  double time_offset_sigma_s = 0.0;        // s, odometry clock minus image clock
  // Wheels whose calibration wanders during the run (a random walk with distance, from the drawn
  // start): each wheel's radius by its own travel, the wheel base by the wheels' mean travel.
  // Not in `realistic` (0): a drive of the thesis's scenarios is too short for it to matter; a
  // long run's (UnmodelledNoise::wheel_scale_drift, the estimators' side).
  double wheel_radius_drift = 0.0;         // fraction per sqrt(m) of the wheel's travel
  double wheel_base_drift = 0.0;           // fraction per sqrt(m) of the wheels' mean travel
  // The field the robot drives on against the map it is given (a map with MiroSot field
  // geometry): each of the dimensions kFieldDimensions names is off by this, per dataset, and
  // the true landmarks follow from the true dimensions (FieldMap::miroSot). Drawn after all
  // others, so that a profile without it draws as before.
  double field_dimension_sigma_mm = 0.0;   // mm

  static ErrorProfile ideal();
  static ErrorProfile realistic();
  // "ideal", "realistic" or a YAML file; errors name the file and key.
  static ErrorProfile named(const std::string& name_or_path);
  static ErrorProfile load(const std::string& path);
  void save(const std::string& path) const;
  void validate() const;  // throws stereoloc::Error naming the field
  bool isIdeal() const;   // every error zero: the simulator's exact world
};

// One dataset's draw. "true" is the world the simulator renders and drives; the estimators get
// the nominal rig and odometry plus `given` (the calibration with its estimated distortion).
struct DrawnErrors {
  double focal_rel[2] = {0, 0};            // per camera
  double principal_px[2][2] = {{0, 0}, {0, 0}};  // [camera][u, v]
  double baseline_rel = 0.0;
  double relative_rotation_rad[3] = {0, 0, 0};   // right camera, rotation vector (OpenCV axes)
  double tilt_rad = 0.0, height_mm = 0.0;
  double distortion[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};  // true k1 k2 p1 p2 per camera
  double distortion_given[2][4] = {{0, 0, 0, 0}, {0, 0, 0, 0}};
  double exposure_offset_s = 0.0;
  double wheel_radius_rel[2] = {0, 0};     // left, right: true radius = nominal (1 + e)
  double wheel_base_rel = 0.0;             // true effective wheel base = nominal (1 + e)
  double time_offset_s = 0.0;
  std::vector<double> pitch_rad, roll_rad;  // per step
  std::vector<double> slip_left, slip_right;  // per step: reading = (1 + slip) x motion
  // Per step, with a drift: the walk of each wheel's radius and of the wheel base (fractions) on
  // top of wheel_radius_rel and wheel_base_rel; empty without one.
  std::vector<double> wheel_radius_drift_left, wheel_radius_drift_right, wheel_base_drift;
  // True minus given field dimension (mm), one per kFieldDimensions entry (src/core/field_map.h);
  // empty without a field error.
  std::vector<double> field_dimension_mm;

  void save(const std::string& path, const ErrorProfile& profile) const;  // the dataset's truth
};

// The field the world is built on: `given` itself without a field error; otherwise the MiroSot
// field of the given geometry with each dimension off by its drawn error, with the given
// landmarks' ids and names. Throws Error when a field error is drawn and `given` is not the
// field its geometry derives (a map without geometry, or with landmarks of its own).
FieldMap trueFieldMap(const FieldMap& given, const DrawnErrors& e);

// `travel`: each step's wheel travel (mm, the scenario's motion), which the wheels' drift walks
// with; needed (one per step) only when the profile has a drift, whose draws come after all
// others so that a profile without one draws as before. Throws Error for a missing travel.
DrawnErrors drawErrors(const ErrorProfile& profile, size_t steps, std::mt19937_64& rng,
                       const std::vector<WheelIncrements>& travel = {});

// Camera matrices of the nominal rectified rig (K of both cameras), OpenCV layout.
cv::Mat nominalCameraMatrix(const StereoRig& nominal);

// The true raw camera at a step: camera matrix, distortion (k1 k2 p1 p2) and the rotation of
// camera i's raw frame relative to the ideal C2-aligned camera (X_raw = R X_ideal, OpenCV axes):
// the right camera's relative rotation, then the step's roll about the optical axis. (Roll
// turns each camera about its own centre; the 0.1 mm the cameras would move in a 0.2 deg roll
// about the head's centre is neglected.)
struct RawCamera {
  cv::Mat K, D, R;
};
RawCamera trueCamera(const StereoRig& nominal, const DrawnErrors& e, int camera, size_t step);

// The calibration handed to the estimators: nominal cameras, the estimated distortion, an
// exact rectified baseline (no extrinsic error is known to the user).
StereoCalibration givenCalibration(const StereoRig& nominal, const DrawnErrors& e);

// The true raw cameras as an OpenCV stereo calibration, without the steps' vibration: what a
// perfect calibration of this robot's head would find (K1, D1, K2, D2 of trueCamera; R the right
// camera's relative rotation, T = -R (b_true, 0, 0)), rectified. The target a checkerboard
// calibration is scored against.
StereoCalibration trueCameraCalibration(const StereoRig& nominal, const DrawnErrors& e);

// The rig geometry of the true world at a step (baseline, height, tilt + pitch); image size
// and pinhole are the nominal ones.
StereoRigParams trueRigParams(const StereoRigParams& nominal, const DrawnErrors& e, size_t step);

}  // namespace stereoloc
