// A calibration handed from one run to the next through the rig file saveAsRig writes
// (CalibrationHandover): what it reads back, the priors it sets, how a run's estimate is carried
// on, and the files it refuses.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "solvers/self_calibration.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {
namespace {

CalibrationEstimate sampleEstimate() {
  CalibrationEstimate e;
  e.odometry = e.stereo = e.row = true;
  e.wheels << 1.004, 0.995, 76.5;
  e.wheels_covariance = Eigen::Vector3d(0.002 * 0.002, 0.003 * 0.003, 1.5 * 1.5).asDiagonal();
  e.wheels_covariance(0, 1) = e.wheels_covariance(1, 0) = 0.5 * 0.002 * 0.003;
  e.head << 0.003, 0.99, -1.2, 0.4, 0.001, 0.002;
  e.head_covariance = (CalibrationEstimate::StereoVector() << 0.004, 0.006, 0.1, 0.5, 0.0009, 0.003)
                          .finished()
                          .cwiseAbs2()
                          .asDiagonal();
  e.row_offset_px = 0.8;
  e.row_offset_variance = 0.2 * 0.2;
  e.odometry_delay_s = 0.24;
  e.odometry_delay_sigma_s = 0.01;
  return e;
}

void writeText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// Removes the line of `key` from a YAML text.
std::string without(std::string text, const std::string& key) {
  const size_t at = text.find("\n" + key + ":");
  EXPECT_NE(at, std::string::npos) << key;
  if (at != std::string::npos) text.erase(at, text.find('\n', at + 1) - at);
  return text;
}

std::string replaced(std::string text, const std::string& key, const std::string& value) {
  const size_t at = text.find("\n" + key + ":");
  EXPECT_NE(at, std::string::npos) << key;
  if (at == std::string::npos) return text;
  const size_t end = text.find('\n', at + 1);
  text.replace(at, end - at, "\n" + key + ": " + value);
  return text;
}

TEST(CalibrationHandover, ReadsBackWhatSaveAsRigWrote) {
  test::TempDir dir;
  const CalibrationEstimate e = sampleEstimate();
  e.saveAsRig(dir.file("rig.yaml"), StereoRig(), 0.0);
  const CalibrationHandover h = CalibrationHandover::load(dir.file("rig.yaml"));
  ASSERT_TRUE(h.wheels && h.wheel_sigmas && h.head_sigmas && h.row_offset_sigma_px);
  EXPECT_NEAR(((*h.wheels) - e.wheels).norm(), 0.0, 1e-12);
  EXPECT_NEAR(((*h.wheel_sigmas) - e.wheels_covariance.diagonal().cwiseSqrt()).norm(), 0.0, 1e-12);
  EXPECT_NEAR(((*h.head_sigmas) - e.head_covariance.diagonal().cwiseSqrt()).norm(), 0.0, 1e-12);
  // The drive's part of the disparity offset, which the next drive does not share, is added to
  // its sigma alone.
  e.saveAsRig(dir.file("drive.yaml"), StereoRig(), 0.3);
  const CalibrationHandover d = CalibrationHandover::load(dir.file("drive.yaml"));
  CalibrationEstimate::StereoVector expected = e.head_covariance.diagonal().cwiseSqrt();
  expected[2] = std::hypot(expected[2], 0.3);
  EXPECT_NEAR(((*d.head_sigmas) - expected).norm(), 0.0, 1e-12);
  EXPECT_NE(test::errorOf([&] { e.saveAsRig(dir.file("bad.yaml"), StereoRig(), -0.1); }).find("the drive's part must be >= 0"),
            std::string::npos);
  EXPECT_NEAR(*h.row_offset_sigma_px, 0.2, 1e-12);
  ASSERT_TRUE(h.odometry_delay_s);
  EXPECT_DOUBLE_EQ(*h.odometry_delay_s, 0.24);
  EXPECT_DOUBLE_EQ(h.odometry_delay_sigma_s, 0.01);
  // A given delay (sigma 0) is written without a sigma and read back as given.
  CalibrationEstimate given;
  given.odometry_delay_s = -0.05;
  given.saveAsRig(dir.file("given.yaml"), StereoRig(), 0.3);
  const CalibrationHandover g = CalibrationHandover::load(dir.file("given.yaml"));
  EXPECT_FALSE(g.empty());
  EXPECT_DOUBLE_EQ(*g.odometry_delay_s, -0.05);
  EXPECT_EQ(g.odometry_delay_sigma_s, 0.0);

  // A rig without the keys (the default rig) hands nothing over.
  StereoRig().save(dir.file("plain.yaml"));
  EXPECT_TRUE(CalibrationHandover::load(dir.file("plain.yaml")).empty());
}

TEST(CalibrationHandover, ItsSigmasBecomeThePriors) {
  CalibrationHandover h;
  h.wheels = Eigen::Vector3d(1.01, 0.99, 80.0);
  h.wheel_sigmas = Eigen::Vector3d(0.002, 0.003, 1.6);
  h.head_sigmas = (CalibrationEstimate::StereoVector() << 0.004, 0.006, 0.1, 0.5, 0.0009, 0.003).finished();
  h.row_offset_sigma_px = 0.2;
  SelfCalibrationConfig c;
  UnmodelledNoise noise;
  h.applyPriors(c, noise);
  EXPECT_DOUBLE_EQ(c.wheel_scale_sigma, 0.003);  // the larger of the two wheels'
  EXPECT_DOUBLE_EQ(c.wheel_base_rel_sigma, 1.6 / 80.0);
  EXPECT_DOUBLE_EQ(c.tilt_sigma_rad, 0.004);
  EXPECT_DOUBLE_EQ(c.baseline_scale_sigma, 0.006);
  EXPECT_DOUBLE_EQ(c.disparity_offset_sigma_px, 0.1);
  EXPECT_DOUBLE_EQ(c.column_offset_sigma_px, 0.5);
  EXPECT_DOUBLE_EQ(c.focal_ratio_sigma, 0.0009);
  EXPECT_DOUBLE_EQ(c.focal_scale_sigma, 0.003);
  c.validate();
  // The row offset's prior only where the noise model states a misalignment (the row block).
  EXPECT_EQ(noise.row_offset_sigma_px, 0.0);
  noise.row_offset_sigma_px = 1.5;
  h.applyPriors(c, noise);
  EXPECT_DOUBLE_EQ(noise.row_offset_sigma_px, 0.2);

  // What the file does not hand over keeps its prior.
  CalibrationHandover wheels_only;
  wheels_only.wheels = h.wheels;
  wheels_only.wheel_sigmas = h.wheel_sigmas;
  SelfCalibrationConfig d;
  wheels_only.applyPriors(d, noise);
  EXPECT_EQ(d.baseline_scale_sigma, SelfCalibrationConfig().baseline_scale_sigma);
}

TEST(CalibrationHandover, CarriesARunsWheelEstimateOnInRawIncrements) {
  CalibrationHandover h;
  h.wheels = Eigen::Vector3d(1.02, 0.97, 80.0);
  h.wheel_sigmas = Eigen::Vector3d(0.002, 0.003, 1.6);
  const CalibrationEstimate run = sampleEstimate();  // relative to increments scaled by h
  const CalibrationEstimate on = h.carriedOn(run);
  // A reading r travelled 1.02 r after the handed-over scale and 1.004 * 1.02 r with the run's.
  EXPECT_DOUBLE_EQ(on.wheels[0], 1.004 * 1.02);
  EXPECT_DOUBLE_EQ(on.wheels[1], 0.995 * 0.97);
  EXPECT_DOUBLE_EQ(on.wheels[2], 76.5);  // the wheel base is absolute
  EXPECT_DOUBLE_EQ(on.wheels_covariance(0, 0), run.wheels_covariance(0, 0) * 1.02 * 1.02);
  EXPECT_DOUBLE_EQ(on.wheels_covariance(0, 1), run.wheels_covariance(0, 1) * 1.02 * 0.97);
  EXPECT_DOUBLE_EQ(on.wheels_covariance(2, 2), run.wheels_covariance(2, 2));
  EXPECT_EQ(on.head, run.head);
  // A run that did not estimate the wheels passes the handed-over estimate on.
  CalibrationEstimate stereo_only = run;
  stereo_only.odometry = false;
  const CalibrationEstimate passed = h.carriedOn(stereo_only);
  EXPECT_TRUE(passed.odometry);
  EXPECT_EQ(passed.wheels, *h.wheels);
  EXPECT_DOUBLE_EQ(passed.wheels_covariance(1, 1), 0.003 * 0.003);
  // Nothing handed over: the run's own.
  EXPECT_EQ(CalibrationHandover().carriedOn(run).wheels, run.wheels);
  // The odometry delay: the run's own, or, without one, the handed-over one with its sigma.
  h.odometry_delay_s = 0.3;
  h.odometry_delay_sigma_s = 0.02;
  EXPECT_DOUBLE_EQ(*h.carriedOn(run).odometry_delay_s, 0.24);
  CalibrationEstimate undelayed = run;
  undelayed.odometry_delay_s.reset();
  const CalibrationEstimate delayed = h.carriedOn(undelayed);
  EXPECT_DOUBLE_EQ(*delayed.odometry_delay_s, 0.3);
  EXPECT_DOUBLE_EQ(delayed.odometry_delay_sigma_s, 0.02);
}

TEST(CalibrationHandover, BadFilesNameTheFileAndTheKey) {
  test::TempDir dir;
  sampleEstimate().saveAsRig(dir.file("rig.yaml"), StereoRig(), 0.0);
  const std::string good = test::readFile(dir.file("rig.yaml"));
  auto expectError = [&](const std::string& text, const std::string& key, const std::string& what) {
    writeText(dir.file("bad.yaml"), text);
    try {
      CalibrationHandover::load(dir.file("bad.yaml"));
      ADD_FAILURE() << "accepted a file without a valid " << key;
    } catch (const Error& e) {
      const std::string m = e.what();
      EXPECT_NE(m.find("bad.yaml"), std::string::npos) << m;
      EXPECT_NE(m.find(key), std::string::npos) << m;
      EXPECT_NE(m.find(what), std::string::npos) << m;
    }
  };
  expectError(without(good, "wheel_scale_right_sigma"), "wheel_scale_right_sigma", "");
  expectError(replaced(good, "wheel_base_mm", "-75"), "wheel_base_mm", "positive");
  expectError(replaced(good, "baseline_scale_sigma", "0"), "baseline_scale_sigma", "positive");
  expectError(replaced(good, "focal_scale_sigma", ".nan"), "focal_scale_sigma", "");
  expectError(without(good, "disparity_offset_sigma_px"), "disparity_offset_sigma_px", "");
  expectError(replaced(good, "row_offset_sigma_px", "wide"), "row_offset_sigma_px", "");
  expectError(replaced(good, "odometry_delay_s", "3.5"), "odometry_delay_s", "within +-2 s");
  expectError(replaced(good, "odometry_delay_s", ".nan"), "odometry_delay_s", "");
  expectError(replaced(good, "odometry_delay_sigma_s", "-0.01"), "odometry_delay_sigma_s", "positive");
}

TEST(CalibrationHandover, WheelCalibrationScalesTheIncrements) {
  Dataset d;
  Step s;
  s.d_left = 10.0;
  s.d_right = 20.0;
  d.steps = {s, s};
  applyWheelCalibration(d, Eigen::Vector3d(1.1, 0.9, 80.0));
  for (const Step& t : d.steps) {
    EXPECT_DOUBLE_EQ(t.d_left, 11.0);
    EXPECT_DOUBLE_EQ(t.d_right, 18.0);
  }
  EXPECT_DOUBLE_EQ(d.odometry.wheel_base_mm, 80.0);
  EXPECT_THROW(applyWheelCalibration(d, Eigen::Vector3d(1.0, 0.0, 80.0)), Error);
  EXPECT_THROW(applyWheelCalibration(d, Eigen::Vector3d(1.0, 1.0, std::nan(""))), Error);
}

}  // namespace
}  // namespace stereoloc
