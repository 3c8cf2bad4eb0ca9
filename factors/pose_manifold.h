#pragma once
// The pose manifold R^2 x SO(2) of src/core/pose2.h as a ceres::Manifold. Ambient and tangent are
// both (x, y, theta) in (mm, mm, rad):
//   Plus(x, d)  = (x + dx, y + dy, wrapAngle(theta + dtheta))
//   Minus(y, x) = (y_x - x_x, y_y - x_y, wrapAngle(y_theta - x_theta))
// so PlusJacobian and MinusJacobian are the identity: the Jacobians the factors report with
// respect to the ambient parameters are already the J_out_pose of the stereoloc convention.
#include <ceres/manifold.h>

#include "src/core/angles.h"

namespace stereoloc {

class PoseManifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return 3; }
  int TangentSize() const override { return 3; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override {
    x_plus_delta[0] = x[0] + delta[0];
    x_plus_delta[1] = x[1] + delta[1];
    x_plus_delta[2] = wrapAngle(x[2] + delta[2]);
    return true;
  }
  bool PlusJacobian(const double* /*x*/, double* jacobian) const override {
    setIdentity(jacobian);
    return true;
  }
  bool Minus(const double* y, const double* x, double* y_minus_x) const override {
    y_minus_x[0] = y[0] - x[0];
    y_minus_x[1] = y[1] - x[1];
    y_minus_x[2] = wrapAngle(y[2] - x[2]);
    return true;
  }
  bool MinusJacobian(const double* /*x*/, double* jacobian) const override {
    setIdentity(jacobian);
    return true;
  }

 private:
  static void setIdentity(double* m) {  // 3x3, row-major
    for (int i = 0; i < 9; ++i) m[i] = (i % 4 == 0) ? 1.0 : 0.0;
  }
};

}  // namespace stereoloc
