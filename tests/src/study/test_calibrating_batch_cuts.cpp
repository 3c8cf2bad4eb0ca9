// The self-calibrating batch where a miscalibrated filter pass loses track without a kidnap: a
// study trial (spin-at at (1150, 350), realistic world, images through the frontend) whose
// kept cuts let the segments and the calibration settle on a wrong solution (baseline scale
// 0.72, wheel base 36 mm, 160 mm RMSE) unless the batch checks the calibration against its
// prior and solves the chain whole. About 6 s of CPU: 100 raw pairs rendered and rectified.
#include <gtest/gtest.h>

#include <cmath>

#include "src/study/study.h"
#include "src/study/study_trial.h"

namespace stereoloc {
namespace {

TEST(CalibratingBatchCuts, FalseAlarmsOfAMiscalibratedFilterDoNotCutTheChain) {
  StudyConfig c;
  c.seed = 7;
  c.methods = {"batch:calib"};
  const study::TrialOutput out = study::runTrial(c, "realistic", "spin-at", 12, nullptr);
  ASSERT_EQ(out.rows.size(), 1u);
  ASSERT_TRUE(out.failures.empty()) << out.failures.front();
  const study::TrialRow& r = out.rows.front();
  ASSERT_GE(r.estimates, 100);
  const double rmse = std::sqrt(r.sse_position / static_cast<double>(r.estimates));
  EXPECT_LT(rmse, 5.0);
  for (const study::CalibrationRow& p : out.calibration)
    EXPECT_LT(std::fabs(p.estimate - p.truth), 4.0 * p.sigma) << p.parameter;
}

}  // namespace
}  // namespace stereoloc
