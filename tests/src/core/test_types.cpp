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
