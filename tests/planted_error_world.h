#pragma once
// Test helpers for the self-calibrating filters: a simulated drive whose given calibration is
// wrong in the ways their blocks model, their known-start and calibrating configurations, a drive
// that loses a filter on one outlier, and the mean NEES of a run against its truth.
#include <Eigen/Cholesky>
#include <cmath>
#include <string>
#include <vector>

#include "src/core/angles.h"
#include "src/core/estimator.h"
#include "solvers/initialisation.h"
#include "solvers/self_calibration.h"
#include "src/core/pose2.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc::test {

// The wheels' calibration (c_l, c_r, w) a simulated world drew, on the nominal 75 mm wheel base.
inline Eigen::Vector3d drawnWheels(const SimulationTrace& trace) {
  const DrawnErrors& e = trace.errors;
  return Eigen::Vector3d(1 + e.wheel_radius_rel[0], 1 + e.wheel_radius_rel[1], 75.0 * (1 + e.wheel_base_rel));
}

// A 600-step random walk whose given calibration has wheel radii and base, head tilt, baseline
// and principal points all wrong; sightings of identified landmarks only.
inline Dataset plantedErrorWorld(SimulationTrace* trace) {
  SimulationConfig sc;
  sc.profile.name = "modelled";
  sc.profile.wheel_radius_rel_sigma = 0.01;
  sc.profile.wheel_base_rel_sigma = 0.03;
  sc.profile.baseline_rel_sigma = 0.01;
  sc.profile.tilt_sigma_rad = deg2rad(0.5);
  sc.profile.principal_sigma_px = 1.0;
  sc.scenario.steps = 600;
  Dataset d = simulate("random-walk", 0, sc, 5, trace);
  keepIdentifiedSightings(d);
  return d;
}

// A filter's configuration (EkfConfig, ParticleFilterConfig) with the known start: the first
// true pose, 10 mm and 2 degrees of standard deviation.
template <typename Config>
Config knownStartConfig(const Dataset& d) {
  Config c;
  c.init = knownBelief(*d.groundtruth.front(), Eigen::Vector3d(10.0, 10.0, deg2rad(2.0)).cwiseAbs2().asDiagonal());
  return c;
}

// The same self-calibrating the comma-separated `blocks` on the dataset's rig.
template <typename Config>
Config calibratingConfig(const Dataset& d, const std::string& blocks) {
  Config c = knownStartConfig<Config>(d);
  c.calibration = SelfCalibrationConfig::parse(blocks);
  c.observation_model.rig = d.rig;
  return c;
}

// A 40-step circle without sightings (and without its compass unless `compass`), and the step 30
// with one gross outlier instead: a landmark 50 mm ahead, far from any pose of the circle, which
// a gate with lost_after 1 rejects and so declares the filter lost there.
struct OutlierDrive {
  Dataset d;
  Step outlier;
};
inline OutlierDrive outlierDrive(bool compass) {
  SimulationConfig sc;
  sc.scenario.steps = 40;
  OutlierDrive drive{simulate("circle", 0, sc, 3), Step()};
  for (Step& s : drive.d.steps) s.observations.clear();
  if (!compass)
    for (Step& s : drive.d.steps) s.compass.reset();
  drive.outlier = drive.d.steps[30];
  Observation o;
  o.landmark_id = 0;
  o.range = 50.0;
  o.bearing = 0.0;
  o.covariance = Eigen::Vector2d(1.0, 1e-4).asDiagonal();
  drive.outlier.observations = {o};
  return drive;
}

// The mean over the estimates of e^T P^-1 e, e the pose error (x, y, theta) against the truth.
inline double meanNees(const Dataset& d, const std::vector<Estimate>& estimates) {
  double sum = 0;
  for (const Estimate& e : estimates) {
    const Pose2& t = *d.groundtruth[static_cast<size_t>(e.step)];
    const Eigen::Vector3d err = minus(e.pose, t);
    sum += err.dot(e.covariance.ldlt().solve(err));
  }
  return sum / static_cast<double>(estimates.size());
}

}  // namespace stereoloc::test
