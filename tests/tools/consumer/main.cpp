// Uses the installed library: the default map, the rig and the odometry model.
#include <cstdio>

#include "src/core/field_map.h"
#include "src/core/odometry_model.h"
#include "src/core/stereo_rig.h"

int main() {
  const stereoloc::FieldMap map = stereoloc::FieldMap::miroSot();
  const stereoloc::StereoRig rig;
  const Eigen::Vector3d u = stereoloc::controlVector(10, 12, 75);
  std::printf("consumer ok: %zu landmarks, f = %.2f, u = %.3f\n", map.landmarks().size(), rig.focal(), u.x());
  return map.landmarks().size() == 32 ? 0 : 1;
}
