#pragma once
// Self-calibration: the batch problem of solvers/batch_smoother.h (known start, odometry,
// compass, stereo observations) with the robot's calibration as extra global parameter blocks,
// so that systematic odometry and stereo errors are estimated instead of absorbed by the poses.
//
//   odometry  c = (c_l, c_r, w): wheel scales and effective wheel base
//             (factors/odometry_calibration_factor.h)
//   stereo    q = (dbeta, k): head tilt correction and baseline scale, entering every pixel
//             factor (factors/stereo_pixel_calibration_factor.h); observations without pixels
//             stay range-bearing factors, which do not see q
// Each block has a Gaussian prior (factors/calibration_prior_factor.h) centred on the nominal
// calibration with the stated uncertainty of SelfCalibrationConfig, so a run that does not
// excite a parameter leaves it at its prior. Poses and calibration come with their marginal
// covariances (ceres::Covariance). Observations of unidentified landmarks (landmark_id -1) are
// not used here and are counted in the result.
#include <string>
#include <vector>

#include "factors/stereo_pixel_factor.h"
#include "solvers/initialisation.h"
#include "src/core/angles.h"
#include "src/core/odometry_model.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "src/io/dataset.h"

namespace stereoloc {

struct SelfCalibrationConfig {
  bool odometry = false;  // estimate wheel scales and wheel base
  bool stereo = false;    // estimate tilt correction and baseline scale
  // Prior 1-sigma: twice the spread of the realistic error profile (src/sim/error_profile.h),
  // so that the prior does not pull a real robot's parameters back.
  double wheel_scale_sigma = 0.01;          // dimensionless
  double wheel_base_rel_sigma = 0.04;       // fraction of the nominal wheel base
  double tilt_sigma_rad = deg2rad(1.0);     // rad
  double baseline_scale_sigma = 0.02;       // dimensionless
  PixelResiduals residuals = PixelResiduals::All;
  bool use_compass = true;
  int max_iterations = 100;

  // "" or "none", "odometry", "stereo", "odometry,stereo" (any order); throws stereoloc::Error.
  static SelfCalibrationConfig parse(const std::string& list);
  void validate() const;
};

struct CalibrationEstimate {
  bool odometry = false, stereo = false;               // which blocks were estimated
  Eigen::Vector3d wheels = Eigen::Vector3d(1, 1, 75);  // c_l, c_r, w (mm)
  Eigen::Matrix3d wheels_covariance = Eigen::Matrix3d::Zero();
  Eigen::Vector2d head = Eigen::Vector2d(0, 1);        // dbeta (rad), k
  Eigen::Matrix2d head_covariance = Eigen::Matrix2d::Zero();

  // The rig with the estimated tilt and baseline (and the odometry estimate with its standard
  // deviations as extra keys wheel_scale_left, wheel_scale_right, wheel_base_mm, *_sigma), in
  // the rig YAML a user can pass back as --rig. A rig carrying an OpenCV calibration gets its T
  // and P2 scaled.
  void saveAsRig(const std::string& path, const StereoRig& rig) const;
};

struct SelfCalibrationResult {
  std::vector<Estimate> trajectory;  // one per step
  CalibrationEstimate calibration;
  bool converged = false;
  int iterations = 0;
  int unidentified_observations = 0;
  bool covariance_ok = false;
};

SelfCalibrationResult selfCalibratingBatch(const Dataset& dataset, const InitialBelief& start,
                                           const SelfCalibrationConfig& config);

}  // namespace stereoloc
