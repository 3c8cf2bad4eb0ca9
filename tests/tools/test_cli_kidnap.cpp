// `stereoloc kidnap`: a short run of the kidnapped-robot study meets its targets and writes
// plot-ready CSV; bad arguments are usage errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::vector<std::string> readLines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string l; std::getline(in, l);) lines.push_back(l);
  return lines;
}

size_t columns(const std::string& line) { return static_cast<size_t>(std::count(line.begin(), line.end(), ',')) + 1; }

TEST(CliKidnap, DetectsAndRecoversAndWritesPlotReadyCsv) {
  test::TempDir dir("kidnap");
  const test::CliRun r = test::runCli("kidnap --seeds 12 --seed 3 --out " + dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // Both targets are met on these seeds.
  EXPECT_NE(r.output.find("detected within 3 observation steps"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("MISSED"), std::string::npos) << r.output;

  const std::vector<std::string> seeds = readLines(dir.file("kidnap_seeds.csv"));
  ASSERT_EQ(seeds.size(), 13u);
  EXPECT_EQ(seeds[0].rfind("seed,kidnap_step,", 0), 0u);
  for (size_t i = 1; i < seeds.size(); ++i) {
    std::stringstream ss(seeds[i]);
    std::string seed, kidnap, err, detected, obs_steps;
    std::getline(ss, seed, ',');
    std::getline(ss, kidnap, ',');
    std::getline(ss, err, ',');
    std::getline(ss, detected, ',');
    std::getline(ss, obs_steps, ',');
    EXPECT_EQ(std::stol(kidnap), 100) << seeds[i];
    EXPECT_GT(std::stod(err), 300.0) << "the kidnap moves the robot far: " << seeds[i];
    EXPECT_GE(std::stol(detected), 100) << seeds[i];
    EXPECT_LE(std::stoi(obs_steps), 3) << seeds[i];
  }

  const std::vector<std::string> trace = readLines(dir.file("kidnap_trace.csv"));
  ASSERT_GT(trace.size(), 300u);  // two runs of 200 steps
  const size_t cols = columns(trace[0]);
  EXPECT_EQ(cols, 20u);
  bool nogate_fused_outlier = false, recovery_lost = false;
  for (size_t i = 1; i < trace.size(); ++i) {
    EXPECT_EQ(columns(trace[i]), cols) << trace[i];
    EXPECT_EQ(trace[i].find("nan"), std::string::npos) << trace[i];
    if (trace[i].rfind("recovery,", 0) == 0 && (trace[i].find(",lost,") != std::string::npos ||
                                                trace[i].find(",reinitialised,") != std::string::npos))
      recovery_lost = true;
    if (trace[i].rfind("nogate,", 0) == 0) {  // fields 17..19: observations, accepted, e2_max
      std::vector<std::string> f;
      std::stringstream ss(trace[i]);
      for (std::string x; std::getline(ss, x, ',');) f.push_back(x);
      ASSERT_EQ(f.size(), cols);
      if (std::stol(f[1]) >= 100 && std::stoi(f[17]) > 0 && std::stod(f[18]) > 100.0) nogate_fused_outlier = true;
    }
  }
  EXPECT_TRUE(recovery_lost);
  EXPECT_TRUE(nogate_fused_outlier) << "without the gate the observations after the kidnap are fused (Fig. 5.3)";

  const std::vector<std::string> innov = readLines(dir.file("kidnap_innovations.csv"));
  ASSERT_GT(innov.size(), 100u);
  EXPECT_EQ(innov[0], "run,step,landmark_id,innov_range,innov_bearing,sigma_range,sigma_bearing,e2,gate_threshold,accepted");
}

TEST(CliKidnap, BadArgumentsAreUsageErrors) {
  EXPECT_EQ(test::runCli("kidnap --seeds 0").exit_code, 2);
  EXPECT_EQ(test::runCli("kidnap --gate-probability 1.5").exit_code, 2);
  EXPECT_EQ(test::runCli("kidnap --landmarks trees").exit_code, 2);
  // A plot seed the study does not run, or without a directory to write its trace to.
  test::TempDir dir("kidnap_plot_seed");
  const test::CliRun outside = test::runCli("kidnap --seeds 3 --seed 5 --plot-seed 8 --out " + dir.path());
  EXPECT_EQ(outside.exit_code, 2);
  EXPECT_EQ(outside.output, "stereoloc: --plot-seed: 8 is not one of the seeds 5..7 (see --help)\n");
  const test::CliRun unused = test::runCli("kidnap --seeds 3 --seed 5 --plot-seed 6");
  EXPECT_EQ(unused.exit_code, 2);
  EXPECT_EQ(unused.output, "stereoloc: --plot-seed: for --out only (see --help)\n");
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  const test::CliRun help = test::runCli("kidnap --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("--lost-after"), std::string::npos);
}

}  // namespace
}  // namespace stereoloc
