// The data between stereoloc's parts (src/core/types.h): every estimator's check of an
// observation it is handed.
#include "src/core/types.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "src/core/error.h"

namespace stereoloc {
namespace {

// A step's odometry and compass as every estimator checks them: a compass sigma whose inverse
// square overflows, or that says nothing, and a wheel increment beyond a kilometre are refused.
TEST(Step, ValidationRefusesUnusableCompassAndOdometry) {
  Step s;
  s.step = 4;
  s.d_left = 10.0;
  s.d_right = 11.0;
  EXPECT_NO_THROW(validateStepOdometryAndCompass(s, "ekf: step 4"));
  s.compass = 0.3;
  for (const double sigma : {0.0, 1e-300, 1e-7, 7.0, 1e300, std::nan("")}) {
    s.compass_sigma = sigma;
    EXPECT_THROW(validateStepOdometryAndCompass(s, "ekf: step 4"), Error) << sigma;
  }
  for (const double sigma : {kMinCompassSigmaRad, 0.05, kMaxCompassSigmaRad}) {
    s.compass_sigma = sigma;
    EXPECT_NO_THROW(validateStepOdometryAndCompass(s, "ekf: step 4")) << sigma;
  }
  s.d_left = 1e150;
  try {
    validateStepOdometryAndCompass(s, "ekf: step 4");
    ADD_FAILURE() << "a 1e150 mm step was taken";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), "ekf: step 4: wheel increment beyond 1 km in one step");
  }
}

std::string refusal(const Observation& o) {
  try {
    validateObservation(o, "step 7: observations[1]");
  } catch (const Error& e) {
    return e.what();
  }
  return "accepted";
}

TEST(Observation, ValidationRefusesWhatNoEstimatorCanUseNamingWhere) {
  const Observation ok = observationFromRangeBearing(3, LandmarkType::GoalCorner, 800.0, 0.2, 20.0, 0.01);
  EXPECT_EQ(refusal(ok), "accepted");
  Observation o = ok;
  o.range = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(refusal(o), "step 7: observations[1]: not finite");
  o = ok;
  o.covariance(0, 1) = 1.0;  // not symmetric
  EXPECT_EQ(refusal(o), "step 7: observations[1]: covariance R is not symmetric positive definite");
  o = ok;
  o.covariance(1, 1) = 0.0;
  EXPECT_EQ(refusal(o), "step 7: observations[1]: covariance R is not symmetric positive definite");
  for (double share : {0.0, -0.25, 1.5, std::nan("")}) {
    o = ok;
    o.single_view_share = share;
    EXPECT_EQ(refusal(o), "step 7: observations[1]: single-view share is not in (0, 1]") << share;
  }
  o = ok;
  o.single_view_share = 0.25;
  EXPECT_EQ(refusal(o), "accepted");
}

}  // namespace
}  // namespace stereoloc
