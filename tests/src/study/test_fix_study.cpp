// fixstudy's self-calibrated column: on a short realistic run through the image frontend, the
// rig the self-calibrating batch estimates on each trial's own sequence brings the goal corners'
// range error well below the one with the given calibration.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "src/pipeline/usage_error.h"
#include "src/study/fix_study.h"

namespace stereoloc {
namespace {

std::string runToText(const FixStudyOptions& options) {
  std::FILE* f = std::tmpfile();
  FixStudyOptions o = options;
  o.console = f;
  o.log = nullptr;
  runFixStudy(o);
  std::fflush(f);
  std::rewind(f);
  std::string out;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof(buf), f)) > 0;) out.append(buf, n);
  std::fclose(f);
  return out;
}

// The first two groups' means of a Table 6.3 row: with the given calibration, self-calibrated.
std::pair<double, double> rowMeans(const std::string& text, const std::string& label) {
  const size_t t63 = text.find("Table 6.3");
  const size_t at = text.find(label, t63);
  if (t63 == std::string::npos || at == std::string::npos) return {-1, -1};
  const std::string row = text.substr(at + label.size(), text.find('\n', at) - at - label.size());
  double given = -1, calibrated = -1;
  if (std::sscanf(row.c_str(), "%lf %*f %*f %*f | %lf", &given, &calibrated) != 2) return {-1, -1};
  return {given, calibrated};
}

TEST(FixStudySelfCalibration, RangeErrorWellBelowTheGivenCalibrations) {
  FixStudyOptions o;
  o.category = "rect";
  o.method = "fix2";
  o.frontend = "images";
  o.profiles = {"realistic"};
  o.steps = 4;  // 4 trials x 4 poses: ~24 goal corners per column
  o.seed = 1;
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "stereoloc_fixstudy_selfcal";
  std::filesystem::remove_all(dir);
  o.out = dir.string();
  const std::string text = runToText(o);
  ASSERT_NE(text.find("ours (images, realistic, self-cal.)"), std::string::npos) << text;
  ASSERT_NE(text.find("self-calibration, realistic: 4 trials, 0 without an estimate"), std::string::npos) << text;
  const auto [given, calibrated] = rowMeans(text, "normalised (%)");
  ASSERT_GT(given, 0.0) << text;
  ASSERT_GT(calibrated, 0.0) << text;
  EXPECT_LT(calibrated, 0.5 * given) << text;
  // The per-trial bias of the given calibration is what the self-calibration removes.
  const size_t t63 = text.find("Table 6.3");
  const size_t bias = text.find("trial bias (%)", t63);
  ASSERT_NE(bias, std::string::npos) << text;
  double given_std = -1, calibrated_std = -1;
  ASSERT_EQ(std::sscanf(text.c_str() + bias, "trial bias (%%) %*f %lf %*f %*f | %*f %lf", &given_std, &calibrated_std), 2);
  EXPECT_LT(calibrated_std, 0.6 * given_std) << text;

  // range_trials.csv: per trial a row per column, the estimate only in the self-calibrated one.
  std::ifstream trials(dir / "range_trials.csv");
  std::vector<std::string> lines;
  for (std::string line; std::getline(trials, line);) lines.push_back(line);
  ASSERT_EQ(lines.size(), 1u + 2u * 4u);
  EXPECT_EQ(lines[0].rfind("category,trial,run,profile,column,goal_corners,range_bias_pct,", 0), 0u);
  for (size_t i = 1; i < lines.size(); ++i) {
    const bool self_calibrated = i % 2 == 0;
    EXPECT_NE(lines[i].find(self_calibrated ? ",self_calibrated," : ",given,"), std::string::npos) << lines[i];
    // 23 fields; the given calibration's row ends in 7 empty estimate fields.
    EXPECT_EQ(std::count(lines[i].begin(), lines[i].end(), ','), 22) << lines[i];
    EXPECT_EQ(lines[i].size() >= 7 && lines[i].compare(lines[i].size() - 7, 7, ",,,,,,,") == 0, !self_calibrated) << lines[i];
  }
  std::filesystem::remove_all(dir);
  o.out.clear();

  // Without the stereo part there is no such column.
  o.steps = 1;
  o.calibrate = "none";
  EXPECT_EQ(runToText(o).find("self-cal."), std::string::npos);
  o.calibrate = "odometry";
  EXPECT_THROW(runToText(o), UsageError);
  o.calibrate = "wheels";
  EXPECT_THROW(runToText(o), UsageError);
}

}  // namespace
}  // namespace stereoloc
