// A calibration handed from one run to the next (`--calibration-out`, then `--rig`): one robot
// of the realistic world (the same seed draws the same calibration errors in every scenario)
// self-calibrates on one drive, and the next drive runs on the calibrated rig and wheels, in
// localize and in the real-time stream.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <map>
#include <sstream>
#include <string>
#include <utility>

#include "cli_util.h"
#include "src/core/yaml_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// Every JSON line of a stream's output without its compute time (the only field that may differ).
std::string withoutTimes(const std::string& output) {
  std::stringstream in(output), out;
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("{\"step\":", 0) != 0) continue;
    const size_t t = line.find(",\"compute_ms\":");
    if (t != std::string::npos) line.erase(t, line.find_first_of(",}", t + 1) - t);
    out << line << "\n";
  }
  return out.str();
}

class RigHandover : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::TempDir("rig_handover");
    for (const char* scenario : {"line", "circle"}) {
      const test::CliRun r = test::runCli(std::string("simulate --scenario ") + scenario +
                                          " --seed 5 --profile realistic --images --out " + dir_->file(scenario));
      ASSERT_EQ(r.exit_code, 0) << r.output;
    }
    const test::CliRun r = test::runCli("refine " + dir_->file("line") +
                                        " --frontend images --calibrate odometry,stereo --noise-model " + noise() +
                                        " --calibration-out " + rig() + " --out " + dir_->file("line.csv"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::string noise() { return std::string(STEREOLOC_DATA_DIR) + "/noise_realistic.yaml"; }
  static std::string rig() { return dir_->file("calibrated.yaml"); }
  static std::string circle() { return dir_->file("circle"); }
  static std::string out() { return dir_->file("est.csv"); }
  static test::TempDir* dir_;
};
test::TempDir* RigHandover::dir_ = nullptr;

// The thesis's EKF, which does not self-calibrate, runs on the given calibration's range bias
// without the handed-over rig.
TEST_F(RigHandover, TheNextDriveRunsOnTheCalibratedRig) {
  for (const char* method : {"ekf", "window"}) {
    const test::CliRun given = test::runCli("localize " + circle() + " --method " + method +
                                            " --frontend images --out " + out());
    const test::CliRun handed = test::runCli("localize " + circle() + " --method " + method +
                                             " --frontend images --rig " + rig() + " --out " + out());
    ASSERT_EQ(given.exit_code, 0) << given.output;
    ASSERT_EQ(handed.exit_code, 0) << handed.output;
    EXPECT_LT(test::printedPositionRmse(handed.output), 0.2 * test::printedPositionRmse(given.output))
        << method << "\n" << given.output << handed.output;
  }
  // The dataset's stored pixels were rectified with its own rig, not the calibrated one.
  const test::CliRun pixels = test::runCli("localize " + circle() + " --method ekf --rig " + rig() + " --out " + out());
  EXPECT_EQ(pixels.exit_code, 1) << pixels.output;
  EXPECT_NE(pixels.output.find("--frontend images"), std::string::npos) << pixels.output;
}

// selfcheck shows what a rig file hands over.
TEST_F(RigHandover, SelfcheckShowsWhatTheFileHandsOver) {
  const test::CliRun r = test::runCli("selfcheck --samples 10 --rig " + rig());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* line : {"hands over: wheel scales", "hands over: head priors", "hands over: row offset prior"})
    EXPECT_NE(r.output.find(line), std::string::npos) << line << "\n" << r.output;
  const test::CliRun plain = test::runCli("selfcheck --samples 10 --rig " + circle() + "/rig.yaml");
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  EXPECT_EQ(plain.output.find("hands over"), std::string::npos) << plain.output;
}

// The disparity offset a drive estimates holds for its own motion (cameras exposing apart on a
// turning robot shift it by f w dt): its handed-over sigma carries that drive's part in
// quadrature, 0.3 px by default, unless the exposure offset is modelled: stated by the rig (its
// pixels moved to one instant; the offset handed on) or estimated (its sigma handed on too).
TEST_F(RigHandover, TheDisparityOffsetIsHandedOverWithTheDrivesPart) {
  const std::string exact = dir_->file("exact.yaml");
  const test::CliRun r = test::runCli("refine " + dir_->file("line") + " --frontend images --calibrate odometry,stereo " +
                                      "--noise-model " + noise() + " --calibration-out " + exact +
                                      " --drive-disparity-sigma-px 0 --out " + out());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const double posterior = YamlReader(exact).getDouble("disparity_offset_sigma_px");
  const double handed = YamlReader(rig()).getDouble("disparity_offset_sigma_px");
  EXPECT_GT(posterior, 0.0);
  EXPECT_NEAR(handed, std::hypot(posterior, 0.3), 1e-9);
  EXPECT_NEAR(YamlReader(rig()).getDouble("disparity_offset_px"), YamlReader(exact).getDouble("disparity_offset_px"), 1e-12);
  EXPECT_FALSE(YamlReader(rig()).has("exposure_offset_s"));

  // The cameras' offset known (the drawn one, as a driver's timestamps give it) in the dataset's rig.
  const std::string known = dir_->file("line_known");
  std::filesystem::copy(dir_->file("line"), known, std::filesystem::copy_options::recursive);
  const double tau = YamlReader(known + "/errors.yaml").getDouble("exposure_offset_s");
  std::ofstream(known + "/rig.yaml", std::ios::app) << "exposure_offset_s: " << std::setprecision(17) << tau << "\n";
  const std::string synced = dir_->file("synced.yaml");
  const test::CliRun k = test::runCli("refine " + known + " --frontend images --calibrate odometry,stereo --noise-model " +
                                      noise() + " --calibration-out " + synced + " --drive-disparity-sigma-px 5 --out " +
                                      out());
  ASSERT_EQ(k.exit_code, 0) << k.output;
  EXPECT_NEAR(YamlReader(synced).getDouble("exposure_offset_s"), tau, 1e-12);
  EXPECT_LT(YamlReader(synced).getDouble("disparity_offset_sigma_px"), 0.3);  // no drive part, even a large one
  EXPECT_FALSE(YamlReader(synced).has("exposure_offset_sigma_s"));

  // Estimated, where a noise model states its uncertainty.
  std::ifstream in(noise());
  std::ostringstream with;
  with << in.rdbuf() << "exposure_offset_sigma_s: 0.0029\n";
  const std::string noise_exposure = dir_->file("noise_exposure.yaml");
  std::ofstream(noise_exposure) << with.str();
  const std::string estimated = dir_->file("estimated.yaml");
  const test::CliRun e = test::runCli("refine " + dir_->file("line") + " --frontend images --calibrate odometry,stereo " +
                                      "--noise-model " + noise_exposure + " --calibration-out " + estimated +
                                      " --out " + out());
  ASSERT_EQ(e.exit_code, 0) << e.output;
  const YamlReader est(estimated);
  EXPECT_GT(est.getDouble("exposure_offset_sigma_s"), 0.0);
  EXPECT_LE(est.getDouble("exposure_offset_sigma_s"), 0.0029);
  EXPECT_LT(est.getDouble("disparity_offset_sigma_px"), 0.3);
  const test::CliRun shown = test::runCli("selfcheck --samples 10 --rig " + estimated);
  EXPECT_NE(shown.output.find("hands over: exposure offset prior"), std::string::npos) << shown.output;

  const test::CliRun alone =
      test::runCli("refine " + dir_->file("line") + " --drive-disparity-sigma-px 0.5 --out " + out());
  EXPECT_EQ(alone.exit_code, 2) << alone.output;
  EXPECT_NE(alone.output.find("--calibration-out"), std::string::npos) << alone.output;
}

// A further self-calibration starts from the handed-over estimate and its sigmas; the rig it
// writes carries the wheels on in raw increments, within 3 sigma of the robot's true wheels.
TEST_F(RigHandover, AFurtherCalibrationCarriesTheWheelsOn) {
  const std::string next = dir_->file("next.yaml");
  const test::CliRun r = test::runCli("localize " + circle() + " --method batch --frontend images --calibrate "
                                      "odometry,stereo --noise-model " + noise() + " --rig " + rig() +
                                      " --calibration-out " + next + " --out " + out());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const YamlReader errors(circle() + "/errors.yaml"), handed(rig()), written(next);
  const cv::FileNode radius = errors.node()["wheel_radius_rel"];
  const char* keys[2] = {"wheel_scale_left", "wheel_scale_right"};
  for (int i = 0; i < 2; ++i) {
    // The encoders read with the nominal radius: true travel = (1 + e) x reading.
    const double truth = 1.0 + static_cast<double>(radius[i]);
    const double sigma = written.getDouble(std::string(keys[i]) + "_sigma");
    EXPECT_LT(std::fabs(written.getDouble(keys[i]) - truth), 3.0 * sigma) << keys[i];
    EXPECT_LT(sigma, handed.getDouble(std::string(keys[i]) + "_sigma") * 1.0001) << keys[i];
  }
  EXPECT_LT(std::fabs(written.getDouble("wheel_base_mm") - 75.0 * (1.0 + errors.getDouble("wheel_base_rel"))),
            3.0 * written.getDouble("wheel_base_sigma_mm"));
}

// The stream takes the raw increments a robot sends and scales them itself: the same estimates
// as the replayed dataset, whose steps the handed-over wheels scaled on loading.
TEST_F(RigHandover, TheStreamScalesTheRobotsIncrements) {
  const std::string lines = dir_->file("steps.jsonl");
  {
    std::map<long, std::string> compass;  // step -> heading, as written (round trip exact)
    std::ifstream compass_csv(circle() + "/compass.csv");
    std::string row;
    std::getline(compass_csv, row);  // header
    while (std::getline(compass_csv, row)) {
      const size_t a = row.find(','), b = row.find(',', a + 1);
      compass[std::stol(row.substr(0, a))] = row.substr(b + 1);
    }
    std::ifstream odometry(circle() + "/odometry.csv");
    std::ofstream out(lines);
    std::getline(odometry, row);  // header
    while (std::getline(odometry, row)) {
      long step;
      double t, dl, dr;
      ASSERT_EQ(std::sscanf(row.c_str(), "%ld,%lf,%lf,%lf", &step, &t, &dl, &dr), 4) << row;
      char buf[512];
      std::snprintf(buf, sizeof buf,
                    "{\"step\":%ld,\"t\":%.17g,\"d_left\":%.17g,\"d_right\":%.17g,\"left\":\"%s/images/left_%06ld.png\","
                    "\"right\":\"%s/images/right_%06ld.png\"",
                    step, t, dl, dr, circle().c_str(), step, circle().c_str(), step);
      out << buf;
      if (compass.count(step)) out << ",\"compass\":" << compass[step];
      out << "}\n";
    }
  }
  const std::string common = " --rig " + rig() + " --calibrate odometry,stereo --noise-model " + noise();
  const test::CliRun replayed = test::runCli("stream --from " + circle() + " --frontend images" + common);
  const test::CliRun live = test::runCli("stream --setup " + circle() + common, lines);
  ASSERT_EQ(replayed.exit_code, 0) << replayed.output;
  ASSERT_EQ(live.exit_code, 0) << live.output;
  EXPECT_FALSE(withoutTimes(live.output).empty());
  EXPECT_EQ(withoutTimes(replayed.output), withoutTimes(live.output));
  // A rig that cannot be read is an error naming it, with a dataset too.
  const test::CliRun bad = test::runCli("stream --setup " + circle() + " --rig " + circle() + "/odometry.csv", lines);
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("odometry.csv"), std::string::npos) << bad.output;
  // The rig's wheel estimate is the wheel base: another given beside it would be ignored.
  const test::CliRun wheels = test::runCli("stream --rig " + rig() + " --wheel-base 80", lines);
  EXPECT_EQ(wheels.exit_code, 2);
  EXPECT_NE(wheels.output.find("--wheel-base: the --rig hands over its wheel estimate"), std::string::npos)
      << wheels.output;
}

}  // namespace
}  // namespace stereoloc
