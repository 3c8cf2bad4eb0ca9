#include <gtest/gtest.h>

#include <algorithm>

#include "cli_util.h"

namespace stereoloc {

TEST(CliSelfcheck, PassesAndPrintsMapSummary) {
  const test::CliRun r = test::runCli("selfcheck --samples 300");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("32 landmarks"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("all model checks passed"), std::string::npos) << r.output;
}

TEST(CliSelfcheck, UsageAndDataErrorsHaveDistinctExitCodes) {
  test::CliRun r = test::runCli("");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = test::runCli("selfcheck --samples zero");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = test::runCli("selfcheck --map " + std::string(STEREOLOC_SOURCE_DIR) + "/README.md");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("README.md"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << "one-line error expected:\n" << r.output;
  r = test::runCli("--help");
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.output.find("selfcheck"), std::string::npos);
}

}  // namespace stereoloc
