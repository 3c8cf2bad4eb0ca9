#pragma once
// Test helper: a simulated random walk whose odometry runs late against its sightings (the
// readings lead the motion), the data the odometry delay's estimation is tested on.
#include <cstdint>

#include "solvers/smoother_common.h"
#include "src/core/odometry_delay.h"

namespace stereoloc::test {

// makeRandomWalkProblem with three sightings of up to 1.8 m per step (10 mm, 0.01 rad), its
// steps re-timed so that the motion follows the readings delay_s later.
inline SyntheticProblem lateOdometryWalk(int steps, uint64_t seed, double delay_s) {
  SyntheticProblemOptions o;
  o.steps = steps;
  o.max_observations = 3;
  o.max_range = 1800.0;
  o.sigma_range = 10.0;
  o.sigma_bearing = 0.01;
  SyntheticProblem p = makeRandomWalkProblem(o, seed);
  p.steps = delayOdometry(p.steps, -delay_s);
  return p;
}

}  // namespace stereoloc::test
