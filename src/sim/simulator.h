#pragma once
// The simulator of thesis chapter 6: a robot driving a scenario (src/sim/scenario.h) on the MiroSot
// field, with noisy wheel encoders, a compass and a stereo rig that observes the visible
// landmarks in pixels.
//
// Noise model (what each sensor reports, given the TRUE motion; the ground truth is the
// scenario's nominal path, so the geometry tests hold exactly):
//   encoders  d_meas = d_true + N(0, k |d_true|) per wheel (B.6), independent; a carried robot
//             (kidnap) reads exactly 0. d_true comes from the arc between successive true poses
//             (arcBetween, src/sim/scenario.h) through wheelIncrementsForArc. For the global-fix
//             scenarios (independent poses) that arc is only an approximation of "how the wheels
//             would get there": it keeps the chord length and the heading change but not the
//             lateral offset, so odometry and ground truth disagree there by construction.
//   compass   theta_meas = wrap(theta_true + bias + N(0, sigma^2)) (section 6.4).
//   stereo    the exact projection of every visible landmark (StereoRig::project) plus pixel
//             noise from one of two models (PixelNoiseModel), optionally rounded to whole pixels
//             (quantisation, "the major source of error", L1213):
//             independent  N(0, sigma_px^2) on each of u_l, v_l, u_r, v_r (the thesis's 5.28);
//                          the effective sigma written to the rig and the observations is
//                          sqrt(sigma_px^2 + q/12), q = 1 when quantised;
//             per_kind     the vision frontend's model: per landmark kind a Gaussian in (u, v, d)
//                          with correlated column and disparity errors (StereoPixelNoise,
//                          src/core/measurement_model.h stereoPixelCovariance), drawn as L n with
//                          L the lower Cholesky factor of its 4x4 covariance C; each observation
//                          carries C (+ q/12 I when quantised) as its pixel covariance, so the
//                          estimators model exactly the noise that was drawn.
// Visibility: in front of both cameras, inside both images, horizontal range from the robot
// centre <= rig max_range_mm, disparity >= rig min_disparity_px, and the line of sight from
// EACH camera not blocked by walls, goals, corner triangles or obstacles (src/sim/simulator_scene.h).
//
// Default encoder noise k = 0.05 mm^2/mm (sigma = 1.25 mm per wheel for a 31.4 mm circle step,
// 4 %). The thesis gives no value. With it, odometry alone on `circle` drifts to 68 mm (1 sigma,
// sqrt of the position trace; 66 mm RMS in a 500-run Monte Carlo) and 7.5 deg by step 31, the
// step before the first sighting (thesis step 32) -- the thesis's own reference lines of Figs.
// 6.26-6.31 are 100 mm and 7.5 deg -- so an EKF with a known start has errors of the order of
// Table 6.14 (mean 60 mm over steps 33-79, 33 mm over 80-100). k = 0.02 gives 42 mm, 4.8 deg;
// k = 0.1 gives 96 mm, 10.7 deg. See docs/dataset_format.md.
#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "src/io/dataset.h"
#include "src/sim/error_profile.h"
#include "src/sim/scenario.h"
#include "src/sim/simulator_scene.h"

namespace stereoloc {

// The pixel noise of one landmark kind in (u, v, d): left column, row, disparity (px) and the
// correlation of the u and d errors (src/core/measurement_model.h).
struct StereoPixelNoise {
  double sigma_u = 0.5, sigma_v = 0.5, sigma_d = 0.5, corr_ud = 0.0;
  Eigen::Matrix4d covariance() const;  // px^2, of (u_l, v_l, u_r, v_r); throws Error when invalid
};

// The simulated detector's pixel noise (see the header comment).
enum class PixelNoiseModel {
  Independent,  // pixel_sigma on each coordinate
  PerKind,      // SimulationConfig::kind_noise
};
std::string toString(PixelNoiseModel model);                   // "independent", "per_kind"
PixelNoiseModel pixelNoiseModelFromString(const std::string& name);  // throws stereoloc::Error

// Per-kind pixel noise; the defaults are the vision frontend's (frontend/stereo_match.h
// StereoParams, measured in docs/estimators.md "Observation covariance"; a test keeps the two equal).
struct KindPixelNoise {
  StereoPixelNoise corner{0.45, 0.13, 0.5, 0.08};      // marking L corners and other point features
  StereoPixelNoise junction{0.45, 0.05, 0.5, -0.13};   // T-junctions
  StereoPixelNoise intersection{0.5, 0.17, 0.5, 0.48};  // X crossings
  StereoPixelNoise goal{0.15, 0.61, 0.21, 0.707};      // goal corners
  const StereoPixelNoise& of(LandmarkType type) const;
};

// Which landmarks the simulated detector reports.
enum class LandmarkSet {
  GoalCorners,  // the thesis's landmarks (colour transitions at the goal mouths, section 3.6)
  All,          // every landmark of the map (corners, junctions, intersections, wall corners)
};
std::string toString(LandmarkSet set);
LandmarkSet landmarkSetFromString(const std::string& name);  // "goal_corners" | "all"

struct SimulationConfig {
  FieldMap map = FieldMap::miroSot();
  StereoRigParams rig;                     // pixel_sigma here is ignored; see pixel_sigma below
  double wheel_base_mm = 75.0;             // w (L1898)
  double encoder_k = 0.05;                 // wheel variance per mm travelled, mm^2/mm (B.6); 0 = exact
  bool compass = true;                     // write compass readings
  double compass_sigma = deg2rad(3.5);     // rad, noise of the compass (section 6.4); 0 allowed
  double compass_bias = 0.0;               // rad, constant offset added to every reading
  // The sigma DECLARED with the readings is max(compass_sigma, compass_sigma_floor), so that a
  // noise-free compass (Table 6.9, row 0 deg) still has a usable positive sigma.
  double compass_sigma_floor = deg2rad(0.01);  // rad
  PixelNoiseModel pixel_noise = PixelNoiseModel::Independent;
  double pixel_sigma = 0.5;                // px, independent model: noise on each of u_l, v_l, u_r, v_r
  KindPixelNoise kind_noise;               // per_kind model
  bool quantise = false;                   // round the noisy pixel coordinates to whole pixels
  LandmarkSet landmarks = LandmarkSet::GoalCorners;
  int obstacles = 0;                       // K other robots (75 mm cubes) plus, if K > 0, a ball
  double obstacle_speed = 15.0;            // mm per step (the ball moves twice as fast)
  bool images = false;                     // render stereo pairs (stage 2: simulate --images)
  ScenarioOptions scenario;                // steps (0 = default), head scan
  double dt = 0.1;                         // s per step (the thesis gives none)
  // What separates the simulated world from the rig and odometry the dataset declares
  // (src/sim/error_profile.h). Ideal: the exact world described above. Otherwise the dataset's
  // rig carries the given calibration (nominal cameras, estimated distortion; its pairs need
  // rectification), observations are true raw projections undistorted with that calibration,
  // and odometry reads the true motion through the true wheel radii, wheel base, slip and
  // clock offset.
  ErrorProfile profile;

  void validate() const;  // throws stereoloc::Error naming the field
};

// Per-step world state that the dataset does not carry but the renderer needs.
struct SimulationTrace {
  Scenario scenario;
  std::vector<std::vector<Obstacle>> obstacles;  // per step
  ErrorProfile profile;
  DrawnErrors errors;                  // all zero for the ideal profile
  StereoRigParams nominal_rig;         // the rig before the given calibration replaced it
};

// The true pose at a fractional step (s + a, 0 <= a < 1 between poses s and s + 1), on the arc
// between them; clamped to the first and last pose.
Pose2 poseAtStep(const Scenario& scenario, double step);

// Runs a scenario. Deterministic per seed: the same arguments give the same Dataset (and the
// same files). One std::mt19937_64 seeded with `seed` derives independent engines for the
// scenario (random walk), the encoders, the compass, the obstacles and the pixels, so that
// switching one sensor on or off does not change the noise of the others.
Dataset simulate(const std::string& scenario, int trial, const SimulationConfig& cfg, uint64_t seed,
                 SimulationTrace* trace = nullptr);

// The landmarks visible from a pose (see the header comment), with their exact pixels.
struct VisibleLandmark {
  int id = -1;
  StereoPixels pixels;
};
std::vector<VisibleLandmark> visibleLandmarks(const FieldMap& map, const StereoRig& rig, const Scene& scene,
                                              const Pose2& robot, double head_pan, LandmarkSet set);

// World position (mm) of camera 0 = left, 1 = right, for a robot pose and head pan.
Eigen::Vector3d cameraCentreWorld(const StereoRig& rig, const Pose2& robot, double head_pan, int camera);

}  // namespace stereoloc
