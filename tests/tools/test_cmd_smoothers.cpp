// `stereoloc smoothers`: a 4-trial run prints and writes the comparison table with one row per
// method and scenario, finite figures, RMSE / sqrt(CRLB) not below the bound (within Monte
// Carlo noise), the same file for 1 and 2 threads; bad arguments are usage errors.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::vector<std::string> cells(const std::string& row) {
  std::vector<std::string> out;
  std::stringstream ss(row);
  std::string c;
  std::getline(ss, c, '|');  // before the first bar
  while (std::getline(ss, c, '|')) {
    const size_t b = c.find_first_not_of(' '), e = c.find_last_not_of(' ');
    out.push_back(b == std::string::npos ? "" : c.substr(b, e - b + 1));
  }
  if (!out.empty() && out.back().empty()) out.pop_back();
  return out;
}

TEST(CliSmoothers, PrintsTheComparisonTableWithFiniteFiguresAboveTheBound) {
  test::TempDir dir("smoothers");
  const std::string args = "smoothers --scenarios circle,line --trials 4 --seed 5 --windows 5,20 --particles 500";
  const test::CliRun r = test::runCli(args + " --threads 2 --out " + dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string md = test::readFile(dir.file("smoothers.md"));
  ASSERT_FALSE(md.empty());
  EXPECT_NE(r.output.find(md.substr(0, 200)), std::string::npos) << "the table is printed too";

  // Per scenario: a header, a separator and one row per method, in this order.
  const std::vector<std::string> methods = {"batch", "window W=5", "window W=20", "ekf", "pf"};
  const std::vector<std::string> bounds = {"smoothing", "lag 4", "lag 19", "filtering", "filtering"};
  for (const std::string scenario : {"circle", "line"}) {
    const size_t at = md.find("## " + scenario + "\n");
    ASSERT_NE(at, std::string::npos) << scenario;
    std::stringstream ss(md.substr(at));
    std::string line;
    std::getline(ss, line);  // "## scenario"
    std::getline(ss, line);  // blank
    std::getline(ss, line);
    const std::vector<std::string> header = cells(line);
    // The default observation model (pixel columns) adds the ratio to the range-bearing bound.
    ASSERT_EQ(header.size(), 11u) << line;
    EXPECT_EQ(header[9], "RMSE/sqrt(CRLB)");
    EXPECT_EQ(header[10], "RMSE/sqrt(CRLB r-b)");
    std::getline(ss, line);  // |---|
    for (size_t m = 0; m < methods.size(); ++m) {
      ASSERT_TRUE(std::getline(ss, line));
      const std::vector<std::string> c = cells(line);
      ASSERT_EQ(c.size(), 11u) << line;
      EXPECT_EQ(c[0], methods[m]);
      EXPECT_EQ(c[7], bounds[m]);
      for (size_t i : {1u, 2u, 3u, 4u, 5u, 6u, 8u, 9u, 10u}) {
        const double v = std::stod(c[i]);  // "n/a" would throw
        EXPECT_TRUE(std::isfinite(v)) << line;
        EXPECT_GE(v, 0.0) << line;
      }
      EXPECT_GT(std::stod(c[1]), 1.0) << "position RMSE in mm: " << line;
      // No estimator beats the bound beyond the Monte Carlo noise of 4 trials (a smoothed
      // trajectory is about one independent sample of the position error per trial).
      EXPECT_GE(std::stod(c[9]), 0.75) << line;
      if (methods[m] == "ekf") {
        EXPECT_EQ(c[2], "1.00");
      }
    }
  }
  EXPECT_NE(md.find("## Mean over the scenarios"), std::string::npos);
  EXPECT_NE(md.find("batch position RMSE <= 0.6x EKF"), std::string::npos);
  EXPECT_NE(md.find("batch RMSE/sqrt(CRLB) <= 1.15, line:"), std::string::npos);

  // Deterministic whatever the thread count.
  test::TempDir one("smoothers1");
  const test::CliRun r1 = test::runCli(args + " --threads 1 --out " + one.path());
  ASSERT_EQ(r1.exit_code, 0) << r1.output;
  EXPECT_EQ(test::readFile(one.file("smoothers.md")), md);
}

TEST(CliSmoothers, RangeBearingModelComparesWithItsOwnBound) {
  const test::CliRun r = test::runCli(
      "smoothers --scenarios line --trials 2 --windows 5 --particles 100 --threads 2 --observation-model range_bearing");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("Observation model of batch and window: range_bearing"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("RMSE/sqrt(CRLB r-b)"), std::string::npos) << "one bound only: " << r.output;
}

TEST(CliSmoothers, BadArgumentsAreUsageErrors) {
  for (const char* args : {"smoothers --trials 0", "smoothers --scenarios kidnap", "smoothers --scenarios bogus",
                                  "smoothers --windows 5,x", "smoothers --windows 0", "smoothers --threads -1",
                                  "smoothers --observation-model pixel",
                                  "smoothers --scenarios ,"}) {
    const test::CliRun r = test::runCli(std::string(args));
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.output;
  }
}

}  // namespace
}  // namespace stereoloc
