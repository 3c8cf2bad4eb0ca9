#include "src/core/measurement_model.h"

#include "src/core/error.h"

namespace stereoloc {

Eigen::Vector2d predictRangeBearing(const Pose2& pose, const Eigen::Vector2d& landmark, Matrix23d* J_z_pose) {
  const double dx = landmark.x() - pose.x, dy = landmark.y() - pose.y;
  const double q = dx * dx + dy * dy;
  if (!(q > 1e-12)) throw GeometryError("range-bearing: landmark coincides with the robot position");
  const double r = std::sqrt(q);
  if (J_z_pose) {
    *J_z_pose << -dx / r, -dy / r, 0.0,  //
        dy / q, -dx / q, -1.0;
  }
  return Eigen::Vector2d(r, wrapAngle(std::atan2(dy, dx) - pose.theta));
}

}  // namespace stereoloc
