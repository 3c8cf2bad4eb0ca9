#pragma once
// Test helpers for factors on stereo observations: a landmark placed in view of a pose and its
// exact pixels, and a one-block cost function's residual.
#include <ceres/cost_function.h>
#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cmath>
#include <optional>

#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"

namespace stereoloc::test {

// A landmark at `range` (mm) and `bearing` (rad, from the head direction `pan`) of `pose`, at
// `height` (mm) above the floor: its world position and its exact pixels (StereoRig::project).
struct Sighting {
  Eigen::Vector3d landmark;
  StereoPixels pixels;
};
inline Sighting sight(const StereoRig& rig, const Pose2& pose, double pan, double range, double bearing,
                      double height) {
  const Eigen::Vector2d local(range * std::cos(pan + bearing), range * std::sin(pan + bearing));
  const Eigen::Vector2d world = transformToWorld(pose, local);
  const std::optional<StereoPixels> px = rig.project(Eigen::Vector3d(local.x(), local.y(), height), pan);
  EXPECT_TRUE(px.has_value());
  return {Eigen::Vector3d(world.x(), world.y(), height), px.value_or(StereoPixels{})};
}

// The residual of a cost function with one parameter block at `parameters` (expects success).
inline Eigen::VectorXd evaluateResidual(const ceres::CostFunction& f, const double* parameters) {
  Eigen::VectorXd r(f.num_residuals());
  const double* p[1] = {parameters};
  EXPECT_TRUE(f.Evaluate(p, r.data(), nullptr));
  return r;
}

}  // namespace stereoloc::test
