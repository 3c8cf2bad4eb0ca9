// `stereoloc calibrate`: a simulated robot's checkerboard pairs (`simulate --calibration-views`)
// calibrated into a rig that the estimators then run on, and the command's errors.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>
#include <filesystem>
#include <fstream>
#include <cstdlib>

#include "cli_util.h"
#include "src/core/stereo_calibration.h"
#include "src/io/image_file.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// localize's "position RMSE X mm"; -1 when absent.
double positionRmse(const std::string& output) {
  const std::string key = "position RMSE ";
  const size_t at = output.find(key);
  if (at == std::string::npos) return -1.0;
  return std::strtod(output.c_str() + at + key.size(), nullptr);
}

// A realistic robot's given calibration is off by its principal points, focal lengths and
// baseline; its own cameras' checkerboard pairs give the rig that removes most of that error.
TEST(CliCalibrate, ARigFromTheRobotsOwnPairsBeatsTheGivenCalibration) {
  test::TempDir dir;
  const std::string d = dir.file("run");
  ASSERT_EQ(test::runCli("simulate --scenario circle --profile realistic --seed 5 --images --calibration-views 12 --out '" +
                         d + "'")
                .exit_code,
            0);
  const test::CliRun cal = test::runCli("calibrate '" + d + "/calibration' --out '" + dir.file("stereo.yml") +
                                        "' --rig-out '" + dir.file("rig.yaml") + "' --mounting '" + d + "/rig.yaml'");
  ASSERT_EQ(cal.exit_code, 0) << cal.output;
  EXPECT_NE(cal.output.find("pairs: 12 of 12 used, 54 corners per image"), std::string::npos) << cal.output;
  const StereoCalibration written = StereoCalibration::load(dir.file("stereo.yml"));
  const StereoCalibration truth = StereoCalibration::load(d + "/calibration/true_calibration.yml");
  EXPECT_NEAR(cv::norm(written.T), cv::norm(truth.T), 0.2);
  const test::CliRun given =
      test::runCli("localize '" + d + "' --method ekf --frontend images --out '" + dir.file("given.csv") + "'");
  const test::CliRun calibrated = test::runCli("localize '" + d + "' --method ekf --frontend images --rig '" +
                                               dir.file("rig.yaml") + "' --out '" + dir.file("calibrated.csv") + "'");
  ASSERT_EQ(given.exit_code, 0) << given.output;
  ASSERT_EQ(calibrated.exit_code, 0) << calibrated.output;
  const double before = positionRmse(given.output), after = positionRmse(calibrated.output);
  ASSERT_GT(before, 0.0) << given.output;
  ASSERT_GT(after, 0.0) << calibrated.output;
  EXPECT_LT(after, 0.1 * before) << "given " << before << " mm, calibrated " << after << " mm";
}

TEST(CliCalibrate, BadInputNamesTheProblem) {
  test::TempDir dir;
  const std::string d = dir.file("run");
  ASSERT_EQ(test::runCli("simulate --scenario spin --steps 2 --calibration-views 4 --out '" + d + "'").exit_code, 0);
  const std::string pairs = d + "/calibration";
  const std::string out = " --out '" + dir.file("s.yml") + "'";
  test::CliRun r = test::runCli("calibrate '" + pairs + "'" + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("4 of 4 pairs show the whole board in both images, 6 needed"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("s.yml")));
  r = test::runCli("calibrate '" + pairs + "' --min-pairs 4 --board 9x" + out);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--board: expected COLUMNSxROWS"), std::string::npos) << r.output;
  r = test::runCli("calibrate '" + pairs + "' --min-pairs 4 --board 6x6" + out);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("equal sides"), std::string::npos) << r.output;
  r = test::runCli("calibrate '" + pairs + "' --min-pairs 4 --mounting '" + d + "/rig.yaml'" + out);
  EXPECT_EQ(r.exit_code, 2) << r.output;
  std::filesystem::remove(pairs + "/right_002.png");
  r = test::runCli("calibrate '" + pairs + "' --min-pairs 3" + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("left_002.png: no right image with the key '002.png' beside it"), std::string::npos) << r.output;
  std::filesystem::remove(pairs + "/left_002.png");
  r = test::runCli("calibrate '" + pairs + "' --min-pairs 3" + out);
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("pairs: 3 of 3 used"), std::string::npos) << r.output;
}

// The overlays show every pair, the ones left out under their own name, to see why.
TEST(CliCalibrate, OverlaysShowThePairsLeftOutToo) {
  test::TempDir dir;
  const std::string d = dir.file("run");
  ASSERT_EQ(test::runCli("simulate --scenario spin --steps 2 --calibration-views 7 --out '" + d + "'").exit_code, 0);
  const std::string pairs = d + "/calibration";
  ASSERT_NO_THROW(writePngFile(pairs + "/right_003.png", cv::Mat(240, 320, CV_8UC1, cv::Scalar(110))));
  const test::CliRun r = test::runCli("calibrate '" + pairs + "' --out '" + dir.file("s.yml") + "' --overlay '" +
                                      dir.file("overlay") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("pairs: 6 of 7 used"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("wrote 7 rectified pairs (1 of them left out) to"), std::string::npos) << r.output;
  EXPECT_EQ(readImageFile(dir.file("overlay/left_out_left_003.png"), ImageColour::Bgr).image.size(), cv::Size(640, 240));
  EXPECT_EQ(readImageFile(dir.file("overlay/rectified_left_000.png"), ImageColour::Bgr).image.size(), cv::Size(640, 240));
  EXPECT_FALSE(std::filesystem::exists(dir.file("overlay/rectified_left_003.png")));
}

// Real photographs through OpenCV's image list: every pair used, the spread of the pairs
// reported, the lens warning where no view reached the image's corners, and a list that
// cannot be paired named.
TEST(CliCalibrate, OpenCvsSamplePhotographsThroughItsImageList) {
  test::TempDir dir;
  const std::string list = std::string(STEREOLOC_DATA_DIR) + "/real/checkerboard/stereo_calib.xml";
  test::CliRun r = test::runCli("calibrate '" + list + "' --square-mm 1 --out '" + dir.file("s.yml") + "' --overlay '" +
                                dir.file("overlay") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("pairs: 13 of 13 used, 54 corners per image"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("each the larger of the fit's and the pairs' spread"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("warning: the lens model is uncertain"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("a corner's two images 0.14"), std::string::npos) << r.output;
  const StereoCalibration c = StereoCalibration::load(dir.file("s.yml"));
  EXPECT_NEAR(c.K1.at<double>(0, 0), 533.7, 3.0);
  EXPECT_NEAR(cv::norm(c.T), 3.33, 0.03);
  EXPECT_NE(r.output.find("wrote 13 rectified pairs (0 of them left out) to"), std::string::npos) << r.output;
  const cv::Mat overlay = readImageFile(dir.file("overlay/rectified_left11.png"), ImageColour::Bgr).image;
  EXPECT_EQ(overlay.size(), cv::Size(1280, 480));

  const std::string odd = dir.file("odd.yml");
  {
    std::ofstream f(odd);
    f << "%YAML:1.0\n---\nimagelist:\n  - a.png\n  - b.png\n  - c.png\n";
  }
  r = test::runCli("calibrate '" + odd + "' --out '" + dir.file("t.yml") + "'");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find(odd + ": the imagelist has an odd number of names (3)"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("t.yml")));
}

}  // namespace
}  // namespace stereoloc
