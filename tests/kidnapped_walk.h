#pragma once
// Test helper: a random walk whose robot is kidnapped, for the trackers' lost and restart paths.
#include <cstddef>

#include "solvers/smoother_common.h"

namespace stereoloc::test {

// The 200-step random walk of seed 31 kidnapped at step `at`: from there the steps and the
// truth are those of seed 32's walk, and the odometry of step `at` says nothing (the robot is
// elsewhere without having moved).
inline SyntheticProblem kidnappedWalk(size_t at = 100) {
  SyntheticProblemOptions o;
  o.steps = 200;
  SyntheticProblem p = makeRandomWalkProblem(o, 31);
  const SyntheticProblem q = makeRandomWalkProblem(o, 32);
  for (size_t k = at; k < p.steps.size(); ++k) {
    const long idx = p.steps[k].step;
    p.steps[k] = q.steps[k];
    p.steps[k].step = idx;
    p.truth[k] = q.truth[k];
  }
  p.steps[at].d_left = p.steps[at].d_right = 0.0;
  return p;
}

}  // namespace stereoloc::test
