#pragma once
// Test helpers: a simulated random walk with a few sightings per step of up to 1.8 m, and the same
// walk with its odometry running late against its sightings (the readings lead the motion), the
// data the odometry delay's estimation is tested on.
#include <cstdint>

#include "solvers/smoother_common.h"
#include "src/core/odometry_delay.h"

namespace stereoloc::test {

// makeRandomWalkProblem's options for `steps` steps with up to three sightings per step of up to
// 1.8 m, range sigma 10 mm, bearing sigma 0.01 rad.
inline SyntheticProblemOptions sightedWalkOptions(int steps) {
  SyntheticProblemOptions o;
  o.steps = steps;
  o.max_observations = 3;
  o.max_range = 1800.0;
  o.sigma_range = 10.0;
  o.sigma_bearing = 0.01;
  return o;
}

// That walk with its steps re-timed so that the motion follows the readings delay_s later.
inline SyntheticProblem lateOdometryWalk(int steps, uint64_t seed, double delay_s) {
  SyntheticProblem p = makeRandomWalkProblem(sightedWalkOptions(steps), seed);
  p.steps = delayOdometry(p.steps, -delay_s);
  return p;
}

}  // namespace stereoloc::test
