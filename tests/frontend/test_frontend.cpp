// The pipeline object: parameters (YAML), input validation, goal-corner identities, and a
// full run on a synthetic pair.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <opencv2/imgproc.hpp>

#include "frontend/frontend.h"
#include "src/core/error.h"
#include "synthetic_scene.h"
#include "test_util.h"

using namespace stereoloc;
using namespace stereoloc::frontend;

namespace {
std::string tempFile(const std::string& name) {
  return (std::filesystem::temp_directory_path() / ("stereoloc_fe_" + std::to_string(::getpid()) + "_" + name)).string();
}
void writeText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }
using stereoloc::test::kWhite;
using stereoloc::test::kYellow;
using stereoloc::test::kBlue;

// A goal (colour between two white walls) on rows 100..129 with its edges at sub-pixel
// columns a, b (box-filtered), on a dark image.
cv::Mat goalImage(double a, double b, const cv::Vec3b& colour) {
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(20, 20, 20));
  for (int y = 100; y < 130; ++y)
    for (int x = 0; x < 320; ++x) {
      const double t = std::clamp(x + 0.5 - a, 0.0, 1.0) - std::clamp(x + 0.5 - b, 0.0, 1.0);
      cv::Vec3b p;
      for (int c = 0; c < 3; ++c) p[c] = static_cast<uint8_t>(std::lround((1 - t) * kWhite[c] + t * colour[c]));
      img.at<cv::Vec3b>(y, x) = p;
    }
  return img;
}
}  // namespace

TEST(FrontendParams, DefaultsAreTheThesisValues) {
  const FrontendParams p;
  EXPECT_EQ(p.hough.theta_step_deg, 1.0);   // 6.1
  EXPECT_EQ(p.hough.rho_step_px, 3.0);
  EXPECT_EQ(p.hough.tolerance_deg, 5.0);
  EXPECT_EQ(p.segments.gap_min_px, 3.0);
  EXPECT_EQ(p.segments.gap_max_px, 50.0);
  EXPECT_EQ(p.segments.min_length_px, 30.0);
  EXPECT_EQ(p.corners.delta_px, 8.0);
  EXPECT_EQ(p.goals.coarse_step, 4);        // 3.6
}

TEST(FrontendParams, YamlRoundTripAndShippedDefaultsFile) {
  FrontendParams p;
  p.hough.rho_step_px = 2.0;
  p.segments.gap_max_px = 40.0;
  p.hough.weight_by_magnitude = true;
  p.goals.min_rows = 6;
  const std::string path = tempFile("params.yaml");
  p.save(path);
  const FrontendParams q = FrontendParams::load(path);
  EXPECT_EQ(q.hough.rho_step_px, 2.0);
  EXPECT_EQ(q.segments.gap_max_px, 40.0);
  EXPECT_TRUE(q.hough.weight_by_magnitude);
  EXPECT_EQ(q.goals.min_rows, 6);
  std::filesystem::remove(path);
  // The shipped file holds the defaults: written back, it reads as the defaults written.
  const FrontendParams d = FrontendParams::load(std::string(STEREOLOC_DATA_DIR) + "/frontend_default.yaml");
  EXPECT_EQ(d.segments.min_length_px, FrontendParams().segments.min_length_px);
  EXPECT_EQ(d.gradient.magnitude_threshold, FrontendParams().gradient.magnitude_threshold);
  const std::string shipped = tempFile("shipped.yaml"), defaults = tempFile("defaults.yaml");
  d.save(shipped);
  FrontendParams().save(defaults);
  EXPECT_EQ(test::readFile(shipped), test::readFile(defaults));
  std::filesystem::remove(shipped);
  std::filesystem::remove(defaults);
}

TEST(FrontendParams, ErrorsNameFileAndKey) {
  const std::string path = tempFile("bad.yaml");
  auto message = [&](const std::string& text) {
    writeText(path, "%YAML:1.0\n---\n" + text);
    try {
      FrontendParams::load(path);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("hough:\n  rho_stepp_px: 3\n").find("rho_stepp_px"), std::string::npos);
  EXPECT_NE(message("houg:\n  rho_step_px: 3\n").find("houg"), std::string::npos);
  EXPECT_NE(message("hough:\n  rho_step_px: -1\n").find("hough.rho_step_px"), std::string::npos);
  EXPECT_NE(message("hough:\n  theta_step_deg: 7\n").find("theta_step_deg"), std::string::npos);
  EXPECT_NE(message("segments:\n  min_length_px: abc\n").find("min_length_px"), std::string::npos);
  EXPECT_NE(message("hough:\n  rho_step_px: -1\n").find(path), std::string::npos);
  EXPECT_NE(message("stereo:\n  uniqueness: -0.1\n").find("stereo.uniqueness: must be in [0, 2]"), std::string::npos);
  EXPECT_NE(message("stereo:\n  min_zncc: 1.5\n").find("stereo.min_zncc: must be in [-1, 1]"), std::string::npos);
  EXPECT_EQ(message("stereo:\n  floor_search_px: -1\n"), "no error");  // <= 0: the full disparity range
  for (const char* share : {"0", "1.5", "-0.25"})
    EXPECT_NE(message(std::string("stereo:\n  goal_single_view_share: ") + share + "\n")
                  .find("stereo.*_single_view_share: must be in (0, 1]"),
              std::string::npos)
        << share;
  EXPECT_EQ(message("stereo:\n  corner_single_view_share: 0.5\n"), "no error");
  std::filesystem::remove(path);
}

TEST(Frontend, RejectsBadImagesWithOneLineErrors) {
  Frontend fe(StereoRig(), FieldMap::miroSot());
  const cv::Mat ok(240, 320, CV_8UC3, cv::Scalar(20, 20, 20));
  const std::vector<std::pair<cv::Mat, cv::Mat>> bad = {
      {cv::Mat(), ok},
      {ok, cv::Mat(120, 160, CV_8UC3)},
      {cv::Mat(120, 160, CV_8UC3), cv::Mat(120, 160, CV_8UC3)},
      {ok, cv::Mat(240, 320, CV_16UC3, cv::Scalar(0))},
      {cv::Mat(240, 320, CV_8UC1, cv::Scalar(0)), ok},
  };
  for (const auto& [l, r] : bad) {
    try {
      fe.process(l, r);
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    }
  }
  EXPECT_NO_THROW(fe.process(ok, ok));
  EXPECT_TRUE(fe.result().observations.empty());
}

TEST(Frontend, GoalCornerIdentityFromColourAndSide) {
  const FieldMap map = FieldMap::miroSot();
  Frontend fe(StereoRig(), map);
  // Facing the blue goal (x = 0) from the field, the image's left is the world's -y side.
  const Landmark& bl = map.at(fe.goalCornerLandmark(GoalColor::Blue, -1));
  const Landmark& br = map.at(fe.goalCornerLandmark(GoalColor::Blue, +1));
  EXPECT_EQ(bl.color, GoalColor::Blue);
  EXPECT_LT(bl.position.y(), br.position.y());
  const Landmark& yl = map.at(fe.goalCornerLandmark(GoalColor::Yellow, -1));
  const Landmark& yr = map.at(fe.goalCornerLandmark(GoalColor::Yellow, +1));
  EXPECT_EQ(yl.color, GoalColor::Yellow);
  EXPECT_GT(yl.position.y(), yr.position.y());
  EXPECT_EQ(fe.goalCornerLandmark(GoalColor::None, -1), -1);
}

TEST(Frontend, GoalCornerObservationsFromASyntheticPair) {
  const StereoRig rig;
  const FieldMap map = FieldMap::miroSot();
  Frontend fe(rig, map);
  const double d = 9.25;  // disparity, px
  const FrontendResult& r = fe.process(goalImage(120.3, 200.7, kBlue), goalImage(120.3 - d, 200.7 - d, kBlue));
  ASSERT_EQ(r.observations.size(), 2u);
  for (const Observation& o : r.observations) {
    EXPECT_EQ(o.type, LandmarkType::GoalCorner);
    EXPECT_EQ(map.at(o.landmark_id).color, GoalColor::Blue);
    ASSERT_TRUE(o.pixels.has_value());
    EXPECT_NEAR(o.pixels->disparity(), d, 0.05);
    const RangeBearing rb = rig.rangeBearing(*o.pixels, 0.0);
    EXPECT_NEAR(o.range, rb.range, 1e-9);
    EXPECT_GT(o.covariance(0, 0), 0.0);
    // Stated for trackers at twice the white sigmas: one view is a quarter of the variance.
    EXPECT_EQ(o.single_view_share, 0.25);
  }
  EXPECT_NE(r.observations[0].landmark_id, r.observations[1].landmark_id);
  FrontendParams p;
  p.stereo.goal_noise.single_view_share = 0.5;
  Frontend half(rig, map, p);
  const FrontendResult& h = half.process(goalImage(120.3, 200.7, kBlue), goalImage(120.3 - d, 200.7 - d, kBlue));
  ASSERT_EQ(h.observations.size(), 2u);
  for (const Observation& o : h.observations) EXPECT_EQ(o.single_view_share, 0.5);
}

// Monocular use on a raw image of a calibrated rig: the image is rectified before detection,
// so the lines are those found on the rectified image, not on the distorted one.
TEST(Frontend, RawMonocularImageIsRectifiedFirst) {
  const StereoCalibration c =
      StereoCalibration::load(std::string(STEREOLOC_DATA_DIR) + "/stereo_calibration_example.yml");
  const StereoRig rig(StereoRigParams(), c);
  Frontend fe(rig, FieldMap::miroSot());
  ASSERT_NE(fe.rectifier(), nullptr);
  const int w = rig.params().image_width, h = rig.params().image_height;
  cv::Mat raw(h, w, CV_8UC3, cv::Scalar(30, 60, 30));
  cv::line(raw, cv::Point(20, h - 30), cv::Point(w - 60, h / 2 + 10), cv::Scalar(235, 235, 235), 5, cv::LINE_AA);
  cv::line(raw, cv::Point(40, h / 2 + 30), cv::Point(w / 2, h - 10), cv::Scalar(235, 235, 235), 5, cv::LINE_AA);
  const std::vector<LineFeature> from_raw = fe.detectFeaturesRaw(raw).lines;
  ASSERT_FALSE(from_raw.empty());
  const cv::Mat rectified = fe.rectifier()->left().clone();
  const std::vector<LineFeature> direct = fe.detectFeatures(rectified).lines;
  ASSERT_EQ(from_raw.size(), direct.size());
  for (size_t i = 0; i < direct.size(); ++i) {
    EXPECT_DOUBLE_EQ(from_raw[i].rho, direct[i].rho);
    EXPECT_DOUBLE_EQ(from_raw[i].theta, direct[i].theta);
  }
  // The distorted image itself gives other lines (the map is not the identity).
  const std::vector<LineFeature> unrectified = fe.detectFeatures(raw).lines;
  bool differs = unrectified.size() != direct.size();
  for (size_t i = 0; !differs && i < direct.size(); ++i) differs = std::fabs(unrectified[i].rho - direct[i].rho) > 0.5;
  EXPECT_TRUE(differs);
}
