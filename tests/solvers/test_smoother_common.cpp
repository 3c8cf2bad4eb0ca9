// makeObservationFactor (solvers/smoother_common.h): the factor chosen by observation model and
// data, and the model names.
#include <gtest/gtest.h>

#include <memory>

#include "solvers/smoother_common.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "stereo_sighting.h"

namespace stereoloc {
namespace {

using test::evaluateResidual;
using test::sight;
using test::Sighting;

TEST(ObservationFactor, ChoosesTheFactorByModelAndData) {
  const StereoRig rig;
  const Pose2 pose(100, 200, 0.2);
  const Sighting s = sight(rig, pose, 0.0, 700, -0.2, 25.0);
  Landmark lm;
  lm.id = 4;
  lm.position = s.landmark;
  const Observation with_pixels = observationFromPixels(rig, 4, LandmarkType::GoalCorner, s.pixels, 0.0, 0.5);
  const Observation range_bearing = observationFromRangeBearing(4, LandmarkType::GoalCorner, 700, -0.2, 10, 0.01);
  const double p[3] = {pose.x, pose.y, pose.theta};
  for (ObservationModel m : {ObservationModel::RangeBearing, ObservationModel::PixelColumns, ObservationModel::Pixels}) {
    const ObservationModelConfig config{m, rig};
    std::unique_ptr<ceres::CostFunction> a(makeObservationFactor(with_pixels, lm, config));
    std::unique_ptr<ceres::CostFunction> b(makeObservationFactor(range_bearing, lm, config));
    EXPECT_EQ(a->num_residuals(), m == ObservationModel::Pixels ? 4 : 2) << toString(m);
    EXPECT_EQ(b->num_residuals(), 2) << toString(m);  // no pixels: range-bearing whatever the model
    EXPECT_LT(evaluateResidual(*a, p).norm(), 1e-6) << toString(m);
    EXPECT_EQ(observationModelFromString(toString(m)), m);
  }
  Observation no_sigma = with_pixels;
  no_sigma.pixel_covariance.setZero();
  EXPECT_THROW(makeObservationFactor(no_sigma, lm, {ObservationModel::Pixels, rig}), Error);
  EXPECT_THROW(observationModelFromString("pixel"), Error);
}

}  // namespace
}  // namespace stereoloc
