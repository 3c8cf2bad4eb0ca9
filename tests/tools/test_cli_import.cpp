// `stereoloc import mrclam` and `stereoloc realdata` on a short slice of the shared MR.CLAM
// Dataset 6 (skipped when ../shared is absent): exit codes, the printed summary, the written
// dataset, and an end-to-end run of every estimator with a sanity bound on the error; on the
// whole of robot 1, what the sigmas inflated for correlated errors do to the smoothers.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "cli_util.h"
#include "src/core/yaml_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::string sharedDir() { return std::string(STEREOLOC_SHARED_DIR) + "/data/mrclam6"; }

// Copies the header and the rows of `src` whose time lies in [t0, t1] (at most max_rows).
void copySlice(const std::string& src, const std::string& dst, double t0, double t1, size_t max_rows) {
  std::ifstream in(src);
  std::ofstream out(dst);
  std::string line;
  size_t n = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '#') {
      out << line << "\n";
      continue;
    }
    const double t = std::stod(line);
    if (t < t0) continue;
    if (t > t1 || n >= max_rows) break;
    out << line << "\n";
    ++n;
  }
}

// realdata's CSV: estimator -> (position RMSE mm, theta RMSE rad, mean NEES, ...).
std::map<std::string, std::vector<double>> readRealdataCsv(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  std::map<std::string, std::vector<double>> rows;
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string name, field;
    std::getline(ss, name, ',');
    while (std::getline(ss, field, ',')) rows[name].push_back(std::stod(field));
  }
  return rows;
}

class CliImport : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::filesystem::exists(sharedDir() + "/Robot1_Odometry.dat"))
      GTEST_SKIP() << "shared MR.CLAM data not found at " << sharedDir();
    std::filesystem::create_directories(src_);
    std::filesystem::copy_file(sharedDir() + "/Barcodes.dat", src_ + "/Barcodes.dat");
    std::filesystem::copy_file(sharedDir() + "/Landmark_Groundtruth.dat", src_ + "/Landmark_Groundtruth.dat");
    // 30 s of robot 1 (it sees landmarks from 2.4 s on).
    const double t0 = 1248444187.156, t1 = t0 + 30.0;
    copySlice(sharedDir() + "/Robot1_Odometry.dat", src_ + "/Robot1_Odometry.dat", t0, t1, 3000);
    copySlice(sharedDir() + "/Robot1_Measurement.dat", src_ + "/Robot1_Measurement.dat", t0, t1, 400);
    copySlice(sharedDir() + "/Robot1_Groundtruth.dat", src_ + "/Robot1_Groundtruth.dat", t0 - 1.0, t1 + 1.0, 3000);
  }
  test::TempDir tmp_{"cli_import"};
  std::string src_ = tmp_.file("src");
};

TEST_F(CliImport, WritesDatasetAndPrintsSummary) {
  const std::string out = tmp_.file("robot1");
  test::CliRun r = test::runCli("import mrclam " + src_ + " --robot 1 --out " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("of other robots"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("range error"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("15 landmarks"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::exists(out + "/dataset.yaml"));
  EXPECT_TRUE(std::filesystem::exists(out + "/observations.csv"));
  EXPECT_TRUE(std::filesystem::exists(out + "/groundtruth.csv"));
  // An existing dataset is not overwritten without --force.
  r = test::runCli("import mrclam " + src_ + " --robot 1 --out " + out);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  r = test::runCli("import mrclam " + src_ + " --robot 1 --rate 20 --out " + out + " --force");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  // The rate changes the grid: at 20 Hz there are about twice as many odometry rows.
  std::ifstream odo(out + "/odometry.csv");
  const long lines = std::count(std::istreambuf_iterator<char>(odo), std::istreambuf_iterator<char>(), '\n');
  EXPECT_GT(lines, 20 * 29);
  // Without --out only the summary is printed.
  r = test::runCli("import mrclam " + src_ + " --robot 1");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("nothing written"), std::string::npos) << r.output;
}

TEST_F(CliImport, RangeCorrectionOption) {
  const std::string out = tmp_.file("robot1");
  test::CliRun r = test::runCli("import mrclam " + src_ + " --robot 1 --range-correction fit");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("range correction (fitted against ground truth): range / (1 "), std::string::npos)
      << r.output;
  r = test::runCli("import mrclam " + src_ + " --robot 1 --range-correction 0.02,0,-0.4");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("range correction (given): range / (1 +0.0200 +0.0000 b -0.4000 b^2)"), std::string::npos)
      << r.output;
  for (const char* bad : {"0.02,0", "0.02,0,-0.4,1", "a,b,c", "0.02,,0.1", "nan,0,0", "fitted", ""}) {
    r = test::runCli("import mrclam " + src_ + " --robot 1 --range-correction '" + bad + "'");
    EXPECT_NE(r.exit_code, 0) << bad;
    EXPECT_NE(r.output.find("--range-correction"), std::string::npos) << bad << ": " << r.output;
  }
}

TEST_F(CliImport, CommandDelayAndOdometryWindowOptions) {
  test::CliRun r = test::runCli("import mrclam " + src_ + " --robot 1 --command-delay 0.25 --odometry-window 2");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("command delay (given): 0.250 s"), std::string::npos) << r.output;
  r = test::runCli("import mrclam " + src_ + " --robot 1 --command-delay fit");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("command delay (fitted against ground truth over "), std::string::npos) << r.output;
  for (const char* bad : {"2.5", "-3", "nan", "0.2s", "", "fitted"}) {
    r = test::runCli("import mrclam " + src_ + " --robot 1 --command-delay '" + bad + "'");
    EXPECT_NE(r.exit_code, 0) << bad;
    EXPECT_NE(r.output.find("--command-delay"), std::string::npos) << bad << ": " << r.output;
  }
  r = test::runCli("import mrclam " + src_ + " --robot 1 --odometry-window 0");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--odometry-window"), std::string::npos) << r.output;
}

TEST_F(CliImport, OdometryDelayOptionsOfLocalizeAndRefine) {
  const std::string out = tmp_.file("robot1");
  ASSERT_EQ(test::runCli("import mrclam " + src_ + " --robot 1 --out " + out).exit_code, 0);
  const std::string est = tmp_.file("est.csv");
  test::CliRun r = test::runCli("localize " + out + " --method ekf --odometry-delay 0.25 --out " + est);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("odometry delay (given): 0.250 s"), std::string::npos) << r.output;
  for (const char* bad : {"2.5", "abc", "", "0.1,0.2", "0.2s"}) {
    r = test::runCli("refine " + out + " --odometry-delay '" + bad + "' --out " + est);
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << r.output;
    EXPECT_NE(r.output.find("--odometry-delay"), std::string::npos) << bad << ": " << r.output;
  }
  r = test::runCli("localize " + out + " --odometry-delay-search 0,1,0.1 --out " + est);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("needs --odometry-delay fit"), std::string::npos) << r.output;
  r = test::runCli("localize " + out + " --odometry-delay 0.2 --odometry-delay-profile p.csv --out " + est);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--odometry-delay-profile: needs --odometry-delay fit"), std::string::npos) << r.output;
  r = test::runCli("refine " + out + " --odometry-delay fit --odometry-delay-search 0,0.1,0.1 --out " + est);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("step_s"), std::string::npos) << r.output;
  r = test::runCli("realdata " + out + " --only ekf --odometry-delay 0.25");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("odometry delay (given): 0.250 s"), std::string::npos) << r.output;
  r = test::runCli("realdata " + out + " --only ekf --odometry-delay 0.25s");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("--odometry-delay"), std::string::npos) << r.output;
}

TEST_F(CliImport, UsageAndDataErrors) {
  test::CliRun r = test::runCli("import mrclam " + src_ + " --robot 9");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = test::runCli("import mrclam --robot 1");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = test::runCli("import");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = test::runCli("import mrclam " + src_ + " --robot 2");  // not in the slice
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("Robot2_Odometry.dat"), std::string::npos) << r.output;
  // A truncated row: one line naming file and line.
  std::ofstream(src_ + "/Robot1_Measurement.dat", std::ios::app) << "1248444216.000 \t 63 \t 2.1";
  r = test::runCli("import mrclam " + src_ + " --robot 1");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("Robot1_Measurement.dat:"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("expected 4 fields"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
}

TEST_F(CliImport, EveryEstimatorRunsOnTheSliceWithBoundedError) {
  const std::string out = tmp_.file("robot1");
  test::CliRun r = test::runCli("import mrclam " + src_ + " --robot 1 --out " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string csv = tmp_.file("results.csv");
  r = test::runCli("realdata " + out + " --particles 300 --csv " + csv);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // The printed table is aligned: its two header lines and every row have the same width,
  // whatever the longest estimator label.
  {
    std::istringstream text(r.output);
    std::string line;
    size_t width = 0, table_lines = 0;
    bool in_table = false;
    while (std::getline(text, line)) {
      if (line.rfind("estimator ", 0) == 0) in_table = true;
      if (!in_table) continue;
      if (line.empty() || line[0] == '(') break;
      if (width == 0) width = line.size();
      EXPECT_EQ(line.size(), width) << line;
      ++table_lines;
    }
    EXPECT_GE(table_lines, 9u) << r.output;
  }
  {
    std::ifstream in(csv);
    std::string header;
    std::getline(in, header);
    ASSERT_EQ(header.rfind("estimator,position_rmse_mm,theta_rmse_rad", 0), 0u) << header;
  }
  std::map<std::string, std::vector<double>> rows = readRealdataCsv(csv);
  for (const char* name : {"dead_reckoning", "ekf", "ekf_calib", "pf", "pf_calib", "window", "window_online", "window_calib",
                           "window_calib_online", "batch", "batch_robust", "batch_calib"}) {
    ASSERT_TRUE(rows.count(name)) << name << "\n" << r.output;
    const std::vector<double>& v = rows[name];
    ASSERT_EQ(v.size(), 12u) << name;
    EXPECT_GT(v[9], 200) << name << ": steps with ground truth";
    EXPECT_EQ(v[8], 0) << name << ": non-finite estimates";
    // The NEES's position and heading parts: positive, and each at most the whole
    // (a quadratic form is at least that of any marginal block of its covariance).
    EXPECT_GT(v[10], 0.0) << name;
    EXPECT_GT(v[11], 0.0) << name;
    EXPECT_LE(v[10], v[2] * (1 + 1e-12)) << name;
    EXPECT_LE(v[11], v[2] * (1 + 1e-12)) << name;
    // 30 s, about 2.5 m of travel, landmarks 2-7 m away seen with ~8 cm range noise: the
    // Gaussian estimators stay within half a metre RMS; dead reckoning and the (small) particle
    // filter within 1.5 m. Sanity bounds: a divergence gives metres.
    const std::string n(name);
    EXPECT_LT(v[0], n == "dead_reckoning" || n.rfind("pf", 0) == 0 ? 1500.0 : 500.0) << name << "\n" << r.output;
    EXPECT_LT(v[1], 0.35) << name << ": theta RMSE (rad)";
  }
}


// The whole of robot 1: imported with `import_flags` into the fixture's directory, then
// `realdata --only ONLY` on it; the import's output in *import_output.
class CliImportRobot1 : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::filesystem::exists(sharedDir() + "/Robot1_Odometry.dat"))
      GTEST_SKIP() << "shared MR.CLAM data not found at " << sharedDir();
  }
  std::map<std::string, std::vector<double>> importAndRun(const std::string& name, const std::string& import_flags,
                                                          const std::string& only, std::string* import_output = nullptr) {
    const std::string out = tmp_.file(name);
    test::CliRun r = test::runCli("import mrclam " + sharedDir() + " --robot 1 --out " + out + " " + import_flags);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    if (import_output) *import_output = r.output;
    const std::string csv = out + ".csv";
    r = test::runCli("realdata " + out + " --only " + only + " --csv " + csv);
    EXPECT_EQ(r.exit_code, 0) << r.output;
    return readRealdataCsv(csv);
  }
  test::TempDir tmp_{"cli_import_robot1"};
};

// The barcode camera's errors repeat over consecutive sightings of a landmark (correlation
// about 0.7 a second apart): fused as independent, a burst counts many times over. With the
// sigmas inflated for it, the smoothers' covariance is less overconfident and the batch, whose
// every pose a burst pulls, more accurate.
TEST_F(CliImportRobot1, SigmasInflatedForCorrelatedErrorsMakeTheSmoothersLessOverconfident) {
  std::map<std::string, std::vector<double>> result[2];
  for (int correlated = 0; correlated < 2; ++correlated) {
    std::string printed;
    result[correlated] = importAndRun(correlated ? "correlated" : "independent",
                                      correlated ? "--correlated-errors" : "", "window,batch", &printed);
    EXPECT_NE(printed.find("error correlation of two sightings dt apart: range 0."), std::string::npos) << printed;
    EXPECT_EQ(printed.find("sigmas inflated for it") != std::string::npos, correlated == 1) << printed;
  }
  for (const char* name : {"window", "batch"}) {
    const std::vector<double>& independent = result[0][name];
    const std::vector<double>& correlated = result[1][name];
    ASSERT_EQ(independent.size(), 12u) << name;
    ASSERT_EQ(correlated.size(), 12u) << name;
    EXPECT_LT(correlated[2], 0.7 * independent[2]) << name << ": mean NEES";
    EXPECT_LT(correlated[0], independent[0]) << name << ": position RMSE";
  }
  EXPECT_LT(result[1]["batch"][0], 0.85 * result[0]["batch"][0]);
}

// The camera's range error depends on the bearing (about +2 % on axis, -6 to -7 % 20-35 degrees
// off it): calibrated against the motion capture, the correction makes every estimator more
// accurate.
TEST_F(CliImportRobot1, RangeCorrectionFittedAgainstGroundTruthMakesTheEstimatorsMoreAccurate) {
  std::map<std::string, std::vector<double>> plain = importAndRun("plain", "", "ekf,window,batch");
  std::map<std::string, std::vector<double>> corrected =
      importAndRun("corrected", "--range-correction fit", "ekf,window,batch");
  for (const char* name : {"ekf", "window", "batch"}) {
    ASSERT_EQ(plain[name].size(), 12u) << name;
    ASSERT_EQ(corrected[name].size(), 12u) << name;
    EXPECT_LT(corrected[name][0], 0.8 * plain[name][0]) << name << ": position RMSE";
  }
}

// The robots move as commanded about a quarter of a second after the command's time: fitted
// against the motion capture, the delay makes the commanded odometry, and with it the
// smoothers, more accurate (with the odometry noise fitted over 4 s windows in both runs, so
// that both state the noise of the odometry they integrate).
TEST_F(CliImportRobot1, CommandDelayFittedAgainstGroundTruthMakesTheSmoothersMoreAccurate) {
  const std::string only = "window,batch,window_calib_range,batch_calib_range";
  std::map<std::string, std::vector<double>> plain = importAndRun("plain", "--odometry-window 4", only);
  std::string printed;
  std::map<std::string, std::vector<double>> delayed =
      importAndRun("delayed", "--odometry-window 4 --command-delay fit", only, &printed);
  const std::string key = "command delay (fitted against ground truth over ";
  const size_t at = printed.find(key);
  ASSERT_NE(at, std::string::npos) << printed;
  const double delay = std::stod(printed.substr(printed.find("): ", at) + 3));
  EXPECT_GT(delay, 0.2) << printed;
  EXPECT_LT(delay, 0.35) << printed;
  for (const char* name : {"window", "batch", "window_calib_range", "batch_calib_range"}) {
    ASSERT_EQ(plain[name].size(), 12u) << name;
    ASSERT_EQ(delayed[name].size(), 12u) << name;
    EXPECT_LT(delayed[name][0], 0.97 * plain[name][0]) << name << ": position RMSE";
    EXPECT_LT(delayed[name][2], plain[name][2]) << name << ": mean NEES";
  }
}

// Without ground truth the batch finds the same delay (0.24 s; the motion capture's fit 0.29 s),
// and the smoothers on the odometry re-timed by it are more accurate.
TEST_F(CliImportRobot1, TheBatchFindsTheOdometryDelayFromTheDataAlone) {
  const std::string out = tmp_.file("robot1"), est = tmp_.file("est.csv");
  ASSERT_EQ(test::runCli("import mrclam " + sharedDir() + " --robot 1 --out " + out).exit_code, 0);
  const auto rmse = test::printedPositionRmse;
  for (const std::string method : {"batch", "window"}) {
    const std::string run = "localize " + out + " --method " + method + " --calibrate odometry,range --out " + est;
    const test::CliRun plain = test::runCli(run), delayed = test::runCli(run + " --odometry-delay fit");
    ASSERT_EQ(plain.exit_code, 0) << plain.output;
    ASSERT_EQ(delayed.exit_code, 0) << delayed.output;
    const std::string key = "odometry delay (fitted by the batch): ";
    const size_t at = delayed.output.find(key);
    ASSERT_NE(at, std::string::npos) << delayed.output;
    const double delay = std::stod(delayed.output.substr(at + key.size()));
    EXPECT_GT(delay, 0.18) << delayed.output;
    EXPECT_LT(delay, 0.32) << delayed.output;
    EXPECT_GT(rmse(plain.output), 0.0) << plain.output;
    EXPECT_LT(rmse(delayed.output), 0.97 * rmse(plain.output)) << method << ": " << delayed.output;
  }
  const std::string rig = tmp_.file("delay.yaml"), profile = tmp_.file("profile.csv");
  const test::CliRun refined =
      test::runCli("refine " + out + " --calibrate odometry,range --odometry-delay fit --odometry-delay-profile " +
                   profile + " --calibration-out " + rig + " --out " + est);
  ASSERT_EQ(refined.exit_code, 0) << refined.output;
  EXPECT_NE(refined.output.find("odometry delay (fitted by the batch): 0.2"), std::string::npos) << refined.output;
  const YamlReader written(rig);
  EXPECT_NEAR(written.getDouble("odometry_delay_s"), 0.25, 0.07);
  EXPECT_GT(written.getDouble("odometry_delay_sigma_s"), 0.0);
  // The profile: one row per solve, least near the estimate.
  std::ifstream in(profile);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "delay_s,cost");
  double least_delay = 0, least = 1e300;
  int rows = 0;
  while (std::getline(in, line)) {
    const double delay = std::stod(line), cost = std::stod(line.substr(line.find(',') + 1));
    if (cost < least) least = cost, least_delay = delay;
    ++rows;
  }
  EXPECT_EQ(rows, 18);
  EXPECT_NEAR(least_delay, written.getDouble("odometry_delay_s"), 0.05);
}

// Without ground truth: the smoothers and the EKF estimate the camera's range factor across its
// field of view and its bearing offset (`--calibrate range`), close to the correction fitted
// against the motion capture, and are more accurate for it.
TEST_F(CliImportRobot1, TheEstimatorsCalibrateTheRangeSensorFromTheDataAlone) {
  std::map<std::string, std::vector<double>> rows =
      importAndRun("robot1", "", "ekf_calib,ekf_calib_range,window,batch,window_calib_range,batch_calib_range");
  ASSERT_EQ(rows["ekf_calib"].size(), 12u);
  ASSERT_EQ(rows["ekf_calib_range"].size(), 12u);
  EXPECT_LT(rows["ekf_calib_range"][0], rows["ekf_calib"][0]) << "EKF: position RMSE";
  EXPECT_LT(rows["ekf_calib_range"][2], rows["ekf_calib"][2]) << "EKF: mean NEES";
  for (const char* name : {"window", "batch"}) {
    const std::string calibrating = std::string(name) + "_calib_range";
    ASSERT_EQ(rows[name].size(), 12u) << name;
    ASSERT_EQ(rows[calibrating].size(), 12u) << calibrating;
    EXPECT_LT(rows[calibrating][0], 0.85 * rows[name][0]) << name << ": position RMSE";
    EXPECT_LT(rows[calibrating][2], rows[name][2]) << name << ": mean NEES";
  }
  // The estimate, printed and written: the on-axis scale and the curvature of the fit against
  // the motion capture (1 + 0.026 + 0.006 b - 0.461 b^2) within a few of their sigmas.
  const std::string out = tmp_.file("robot1"), rig = tmp_.file("calibrated.yaml");
  test::CliRun r = test::runCli("localize " + out + " --method batch --calibrate range --calibration-out " + rig +
                                " --out " + tmp_.file("est.csv"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("calibration: range factor 1 +0.0"), std::string::npos) << r.output;
  const YamlReader y(rig);
  EXPECT_NEAR(y.getDouble("range_scale_c0"), 0.026, 0.01);
  EXPECT_NEAR(y.getDouble("range_scale_c2"), -0.461, 0.08);
  EXPECT_GT(y.getDouble("range_scale_c2_sigma"), 0.0);
  EXPECT_GT(y.getDouble("bearing_offset_sigma_rad"), 0.0);
  // The real-time window estimates it too.
  const std::string streamed = tmp_.file("streamed.yaml");
  r = test::runCli("stream --from " + out + " --method window --calibrate range --calibration-out " + streamed);
  ASSERT_EQ(r.exit_code, 0);
  EXPECT_NEAR(YamlReader(streamed).getDouble("range_scale_c2"), -0.461, 0.08);
  // The EKF estimates it too, in `localize` and in `stream` alike.
  const std::string ekf_rig = tmp_.file("ekf.yaml"), ekf_stream_rig = tmp_.file("ekf_stream.yaml");
  r = test::runCli("localize " + out + " --method ekf --calibrate range --calibration-out " + ekf_rig + " --out " +
                   tmp_.file("ekf.csv"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NEAR(YamlReader(ekf_rig).getDouble("range_scale_c2"), -0.461, 0.08);
  r = test::runCli("stream --from " + out + " --method ekf --calibrate range --calibration-out " + ekf_stream_rig);
  ASSERT_EQ(r.exit_code, 0);
  EXPECT_NEAR(YamlReader(ekf_stream_rig).getDouble("range_scale_c2"), -0.461, 0.08);
  // The particle filter does not.
  r = test::runCli("localize " + out + " --method pf --calibrate range --out " + tmp_.file("pf.csv"));
  EXPECT_EQ(r.exit_code, 2) << r.output;
}

}  // namespace
}  // namespace stereoloc
