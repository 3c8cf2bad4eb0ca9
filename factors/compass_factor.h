#pragma once
// Compass factor on the absolute heading.
//
//   r = wrapAngle(theta - z) / sigma                                          1 residual
//
// theta: heading of the pose (x, y, theta) in the world frame, rad; z: measured heading, rad;
// sigma: its standard deviation, rad (the 1x1 upper square-root information is 1 / sigma).
#include <ceres/cost_function.h>

#include <cmath>

#include "src/core/angles.h"
#include "src/core/error.h"

namespace stereoloc {

struct CompassFactor {
  CompassFactor(double heading, double sigma) : z_(heading), inv_sigma_(1.0 / sigma) {}

  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    residual[0] = T(inv_sigma_) * wrapAngle<T>(pose[2] - T(z_));
    return true;
  }

  static ceres::CostFunction* Create(double heading, double sigma);

 private:
  double z_;
  double inv_sigma_;
};

}  // namespace stereoloc
