#pragma once
// Test helpers for the self-calibrating filters: a simulated drive whose given calibration is
// wrong in the ways their blocks model, and the mean NEES of a run against its truth.
#include <Eigen/Cholesky>
#include <cmath>
#include <vector>

#include "src/core/angles.h"
#include "src/core/estimator.h"
#include "src/core/pose2.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc::test {

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
