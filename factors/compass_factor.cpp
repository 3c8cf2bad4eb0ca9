#include "factors/compass_factor.h"

#include <ceres/autodiff_cost_function.h>

namespace stereoloc {

ceres::CostFunction* CompassFactor::Create(double heading, double sigma) {
  if (!std::isfinite(heading)) throw Error("compass factor: heading is not finite");
  if (!(std::isfinite(sigma) && sigma > 0)) throw Error("compass factor: sigma must be a positive number");
  return new ceres::AutoDiffCostFunction<CompassFactor, 1, 3>(new CompassFactor(heading, sigma));
}

}  // namespace stereoloc
