#pragma once
// The data that flows between stereoloc's parts (see DESIGN.md): Step in, Estimate out.
#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

// A range-bearing observation of a landmark, in the robot frame C0.
struct Observation {
  int landmark_id = -1;                                   // -1: not identified (needs association)
  LandmarkType type = LandmarkType::Point;                // what kind of feature was seen
  double range = 0.0;                                     // mm (3.6)
  double bearing = 0.0;                                   // rad (3.7)
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();  // R of (range, bearing), mm^2 / rad^2
  std::optional<StereoPixels> pixels;                     // when it came from the stereo rig
  // px^2, covariance of the pixel errors (u_l, v_l, u_r, v_r) (src/core/measurement_model.h);
  // set with pixels, zero without.
  Eigen::Matrix4d pixel_covariance = Eigen::Matrix4d::Zero();
  double head_pan = 0.0;                                  // rad, gamma at the time of the images
  // Slide gain (dimensionless): how far u_right moves per px of row misalignment of the
  // rectified pair (right row minus left row of the same scene point) for a feature the
  // frontend matched along the left feature's row. A patch whose edges are not vertical slides
  // along them: s = sum(Ix Iy) / sum(Ix^2) over the matched patch plus the floor's disparity
  // change per row (frontend/stereo_match.h).
  // 0 for features whose right column does not depend on the row (goal corners, simulated
  // pixels) and for X-intersections, whose two crossing lines the one-edge model does not
  // describe (measured on realistic images, s dv anticorrelates with their u_right error:
  // docs/realistic_world.md). The self-calibration's row offset enters u_right as s * dv.
  double slide_gain = 0.0;
  // The share of `covariance` and `pixel_covariance` that one view's own errors make, in (0, 1].
  // The frontend states a goal corner's noise wider than one view's error because its errors
  // repeat over consecutive sightings of the same landmark, which a tracker fuses as
  // independent; a global fix on its own uses each sighting once and takes this share of them
  // (GlobalFixOptions::single_view_covariance). 1: the covariance is one view's (simulated
  // pixels, range sensors, a covariance rebuilt with terms of another source).
  double single_view_share = 1.0;

  Eigen::Vector2d z() const { return Eigen::Vector2d(range, bearing); }
};

// Turns a stereo pixel observation into range, bearing and R (5.26, 5.32) with the rig model,
// R = J C J^T from the pixel covariance C (px^2, order u_l, v_l, u_r, v_r). Throws
// GeometryError when it cannot be triangulated (disparity too small), Error for a C that is not
// symmetric positive definite.
Observation observationFromPixels(const StereoRig& rig, int landmark_id, LandmarkType type,
                                  const StereoPixels& pixels, double head_pan, const Eigen::Matrix4d& pixel_covariance);
// The same with each pixel coordinate independent with sigma `pixel_sigma` (px): C = sigma^2 I (5.28).
Observation observationFromPixels(const StereoRig& rig, int landmark_id, LandmarkType type,
                                  const StereoPixels& pixels, double head_pan, double pixel_sigma);

// A range-bearing observation with independent sigmas (mm, rad), as real sensors report them.
Observation observationFromRangeBearing(int landmark_id, LandmarkType type, double range, double bearing,
                                        double sigma_range, double sigma_bearing);

// Throws stereoloc::Error "<where>: ..." unless range and bearing are finite, R is symmetric
// positive definite and the single-view share lies in (0, 1]. Every estimator checks its input
// observations with this.
void validateObservation(const Observation& obs, const std::string& where);

// One time step: odometry since the previous step, optional compass, observations.
struct Step {
  long step = 0;                       // index, strictly increasing
  double t = 0.0;                      // s
  double d_left = 0.0;                 // mm travelled by the left wheel since the previous step
  double d_right = 0.0;                // mm travelled by the right wheel since the previous step
  std::optional<double> compass;       // absolute heading measurement, rad
  double compass_sigma = 0.0;          // rad (used when compass is set)
  double head_pan = 0.0;               // rad
  std::vector<Observation> observations;
};

// The compass standard deviations a heading update can weigh (rad): at least a microradian
// (below it 1/sigma^2 heads for overflow, and no compass is that good) and at most 2 pi (beyond
// it the reading says nothing). Step::compass_sigma, dataset.yaml's noise.compass_sigma.
inline constexpr double kMinCompassSigmaRad = 1e-6;
inline constexpr double kMaxCompassSigmaRad = 6.283185307179586;
bool usableCompassSigma(double sigma_rad);
// The largest wheel increment of one step (mm): a kilometre; beyond, (B.10)'s variances overflow.
inline constexpr double kMaxWheelIncrementMm = 1e6;
// Throws stereoloc::Error "<where>: ..." unless the step's wheel increments are finite and within
// kMaxWheelIncrementMm and its compass (when it has one) is finite with a usable sigma. Every
// estimator checks its input steps' odometry and compass with this.
void validateStepOdometryAndCompass(const Step& step, const std::string& where);

enum class EstimateStatus {
  Uninitialised,  // no pose yet (e.g. waiting for the first global fix)
  Tracking,       // normal operation
  Predicted,      // this step had no fused observation
  Lost,           // too many gated observations; predicting from odometry only
  Reinitialised,  // this step re-initialised from a global fix
};
std::string toString(EstimateStatus status);
EstimateStatus estimateStatusFromString(const std::string& name);

struct Estimate {
  long step = 0;
  double t = 0.0;
  Pose2 pose;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();  // (x, y, theta): mm^2, mm*rad, rad^2
  EstimateStatus status = EstimateStatus::Uninitialised;
  int particles = 0;  // the particle filter's sample size after this step; 0 for the other estimators
};

// The estimate of `step` (its number and time): pose, covariance and status.
inline Estimate stepEstimate(const Step& step, const Pose2& pose, const Eigen::Matrix3d& covariance,
                             EstimateStatus status) {
  Estimate e;
  e.step = step.step;
  e.t = step.t;
  e.pose = pose;
  e.covariance = covariance;
  e.status = status;
  return e;
}

}  // namespace stereoloc
