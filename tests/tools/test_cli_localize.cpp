// `localize` and `refine` with a noise model whose wheels drift (UnmodelledNoise::
// wheel_scale_drift): the batch, which holds one wheel calibration for the run, says so in one
// line; the window and the EKF, which follow the drift, do not.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

TEST(CliLocalize, TheBatchSaysItHoldsDriftingWheelsConstant) {
  test::TempDir dir("cli_localize_drift");
  const std::string ds = dir.file("ds");
  const test::CliRun sim = test::runCli("simulate --scenario random-walk --steps 300 --seed 3 --out " + ds);
  ASSERT_EQ(sim.exit_code, 0) << sim.output;
  const std::string drifting = dir.file("drift.yaml");
  std::ofstream(drifting) << "%YAML:1.0\n---\nwheel_scale_drift: 0.01\nwheel_base_drift: 0.02\n";
  const std::string note = "the batch estimates one wheel calibration for the whole run";
  for (const std::string& command : {"localize " + ds + " --method batch", "refine " + ds}) {
    const std::string run = command + " --calibrate odometry --out " + dir.file("est.csv");
    const test::CliRun with = test::runCli(run + " --noise-model " + drifting);
    ASSERT_EQ(with.exit_code, 0) << with.output;
    EXPECT_NE(with.output.find(note), std::string::npos) << with.output;
    const test::CliRun without = test::runCli(run);
    ASSERT_EQ(without.exit_code, 0) << without.output;
    EXPECT_EQ(without.output.find(note), std::string::npos) << without.output;
  }
  for (const std::string method : {"window", "ekf"}) {
    const test::CliRun r = test::runCli("localize " + ds + " --method " + method + " --calibrate odometry --noise-model " +
                                        drifting + " --out " + dir.file("est.csv"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_EQ(r.output.find(note), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("calibration: wheel scales"), std::string::npos) << r.output;
  }
}

}  // namespace
}  // namespace stereoloc
