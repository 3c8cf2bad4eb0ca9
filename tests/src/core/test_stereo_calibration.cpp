#include "src/core/stereo_calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "src/core/error.h"
#include "src/core/stereo_rig.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// A small CMOS pair as a calibration tool reports it (data/stereo_calibration_example.yml): lens
// distortion, slightly different cameras, a rotated right camera.
StereoCalibration rawCalibration() {
  return StereoCalibration::load(std::string(STEREOLOC_DATA_DIR) + "/stereo_calibration_example.yml");
}

using test::errorOf;

void writeText(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

TEST(StereoCalibration, RoundTripThroughFileStorage) {
  test::TempDir dir;
  const StereoCalibration c = rawCalibration();
  c.save(dir.file("calib.yml"));
  const StereoCalibration back = StereoCalibration::load(dir.file("calib.yml"));
  for (auto [a, b] : {std::pair{&c.K1, &back.K1}, {&c.K2, &back.K2}, {&c.D1, &back.D1}, {&c.D2, &back.D2},
                      {&c.R, &back.R}, {&c.T, &back.T}, {&c.R1, &back.R1}, {&c.R2, &back.R2}, {&c.P1, &back.P1},
                      {&c.P2, &back.P2}, {&c.Q, &back.Q}})
    EXPECT_LT(cv::norm(*a - *b, cv::NORM_INF), 1e-12);
  EXPECT_EQ(back.image_size, c.image_size);
  EXPECT_TRUE(back.needsRemap());
  EXPECT_FALSE(idealCalibration(320, 240, 277, 159.5, 119.5, 30).needsRemap());
}

TEST(StereoCalibration, ComputesRectificationWhenAbsentAndReadsTwoFileLayout) {
  test::TempDir dir;
  const StereoCalibration c = rawCalibration();
  // OpenCV's stereo_calib sample: intrinsics.yml (M1 D1 M2 D2) and extrinsics.yml (R T R1 ...).
  {
    cv::FileStorage fs(dir.file("intrinsics.yml"), cv::FileStorage::WRITE);
    fs << "M1" << c.K1 << "D1" << c.D1 << "M2" << c.K2 << "D2" << c.D2 << "image_width" << 320 << "image_height" << 240;
  }
  {
    cv::FileStorage fs(dir.file("extrinsics.yml"), cv::FileStorage::WRITE);
    fs << "R" << c.R << "T" << c.T;
  }
  const StereoCalibration back = StereoCalibration::load(dir.file("intrinsics.yml"), dir.file("extrinsics.yml"));
  EXPECT_LT(cv::norm(back.P2 - c.P2, cv::NORM_INF), 1e-9);
  EXPECT_NEAR(back.rectifiedBaseline(), cv::norm(c.T), 1e-9);
}

// The rectified pinhole rig and the rectification maps together reproduce cv::projectPoints of
// the raw calibration: a point projected by StereoRig lands, mapped back to the raw image,
// where OpenCV's distorted projection puts it.
TEST(StereoCalibration, RectifiedProjectionMatchesProjectPointsOfRawCalibration) {
  const StereoCalibration c = rawCalibration();
  StereoRigParams p;
  p.camera_height_mm = 0.0;
  const StereoRig rig(p, c);
  EXPECT_NEAR(rig.params().baseline_mm, cv::norm(c.T), 1e-9);
  const double b = rig.params().baseline_mm;
  cv::Mat rvec;
  cv::Rodrigues(c.R, rvec);
  for (const cv::Point3d X : {cv::Point3d(100, 20, 600), cv::Point3d(-250, -40, 900), cv::Point3d(5, 60, 350)}) {
    std::vector<cv::Point2d> raw_l, raw_r;
    cv::projectPoints(std::vector<cv::Point3d>{X}, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), c.K1, c.D1, raw_l);
    cv::projectPoints(std::vector<cv::Point3d>{X}, rvec, c.T, c.K2, c.D2, raw_r);
    // The point in C2: rectified left camera frame (R1), re-ordered, moved to the baseline centre.
    const cv::Mat Xr = c.R1 * cv::Mat(X);
    const Eigen::Vector3d p_c2(Xr.at<double>(2), 0.5 * b - Xr.at<double>(0), -Xr.at<double>(1));
    const auto px = rig.project(p_c2, 0.0);
    ASSERT_TRUE(px);
    // Undistort the raw projections into the rectified images and compare.
    std::vector<cv::Point2d> rect_l, rect_r;
    cv::undistortPoints(raw_l, rect_l, c.K1, c.D1, c.R1, c.P1,
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
    cv::undistortPoints(raw_r, rect_r, c.K2, c.D2, c.R2, c.P2,
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
    EXPECT_NEAR(px->u_left, rect_l[0].x, 1e-3);
    EXPECT_NEAR(px->v_left, rect_l[0].y, 1e-3);
    EXPECT_NEAR(px->u_right, rect_r[0].x, 1e-3);
    EXPECT_NEAR(px->v_right, rect_r[0].y, 1e-3);
  }
}

TEST(StereoCalibration, RigFilePointsToCalibrationAndSavesItBeside) {
  test::TempDir dir;
  rawCalibration().save(dir.file("cam.yml"));
  writeText(dir.file("rig.yaml"), "%YAML:1.0\n---\ncalibration_file: cam.yml\ncamera_height_mm: 72.5\ntilt_rad: 0.1\n");
  const StereoRig rig = StereoRig::load(dir.file("rig.yaml"));
  ASSERT_TRUE(rig.calibration());
  EXPECT_DOUBLE_EQ(rig.params().camera_height_mm, 72.5);
  EXPECT_DOUBLE_EQ(rig.focal(), rawCalibration().rectifiedFocal());
  test::TempDir out;
  rig.save(out.file("rig.yaml"));
  const StereoRig back = StereoRig::load(out.file("rig.yaml"));
  ASSERT_TRUE(back.calibration());
  EXPECT_DOUBLE_EQ(back.params().baseline_mm, rig.params().baseline_mm);
  EXPECT_DOUBLE_EQ(back.params().tilt_rad, 0.1);
}

TEST(StereoCalibration, BadFilesNameFileAndKey) {
  test::TempDir dir;
  const StereoCalibration c = rawCalibration();
  auto write = [&](const std::function<void(cv::FileStorage&)>& body) {
    const std::string path = dir.file("bad.yml");
    cv::FileStorage fs(path, cv::FileStorage::WRITE);
    body(fs);
    fs.release();
    return path;
  };
  auto all_but = [&](const std::string& skip) {
    return [&, skip](cv::FileStorage& fs) {
      if (skip != "image_size") fs << "image_size" << std::vector<int>{320, 240};
      if (skip != "M1") fs << "M1" << c.K1;
      if (skip != "D1") fs << "D1" << c.D1;
      if (skip != "M2") fs << "M2" << c.K2;
      if (skip != "D2") fs << "D2" << c.D2;
      if (skip != "R") fs << "R" << c.R;
      if (skip != "T") fs << "T" << c.T;
    };
  };
  auto expect = [&](const std::string& path, const std::string& key, const std::string& reason) {
    const std::string e = errorOf([&] { StereoCalibration::load(path); });
    EXPECT_NE(e.find(path + ": " + key + ":"), std::string::npos) << e;
    EXPECT_NE(e.find(reason), std::string::npos) << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
  };
  expect(write(all_but("T")), "T", "missing");
  expect(write(all_but("M2")), "M2", "missing");
  expect(write([&](cv::FileStorage& fs) {
           all_but("M1")(fs);
           fs << "M1" << (cv::Mat_<double>(3, 3) << -279.0, 0, 160, 0, 279, 120, 0, 0, 1);
         }),
         "M1", "focal length must be positive");
  expect(write([&](cv::FileStorage& fs) {
           all_but("R")(fs);
           fs << "R" << (cv::Mat_<double>(3, 3) << 1.01, 0, 0, 0, 1, 0, 0, 0, 1);
         }),
         "R", "not orthonormal");
  expect(write([&](cv::FileStorage& fs) {
           all_but("D1")(fs);
           fs << "D1" << (cv::Mat_<double>(1, 5) << -0.2, std::nan(""), 0, 0, 0);
         }),
         "D1", "not finite");
  expect(write([&](cv::FileStorage& fs) {
           all_but("D2")(fs);
           fs << "D2" << (cv::Mat_<double>(1, 3) << -0.2, 0.1, 0);
         }),
         "D2", "expected 4, 5, 8 or 12 coefficients");
  // Rectified projections must have cv::stereoRectify's form: a negative last-row entry (a
  // camera looking backwards) or a left camera off the origin is refused.
  auto with_projections = [&](cv::Mat P1, cv::Mat P2) {
    return write([&, P1, P2](cv::FileStorage& fs) {
      all_but("")(fs);
      fs << "R1" << c.R1 << "R2" << c.R2 << "P1" << P1 << "P2" << P2;
    });
  };
  cv::Mat flipped = c.P1.clone();
  flipped.at<double>(2, 2) = -1;
  expect(with_projections(flipped, c.P2), "P1", "not a rectified projection");
  cv::Mat skewed = c.P2.clone();
  skewed.at<double>(0, 1) = 2;
  expect(with_projections(c.P1, skewed), "P2", "not a rectified projection");
  cv::Mat moved = c.P1.clone();
  moved.at<double>(0, 3) = -100;
  expect(with_projections(moved, c.P2), "P1", "the left rectified camera must be at the origin");
  EXPECT_NO_THROW(StereoCalibration::load(with_projections(c.P1, c.P2)));
  // A rig whose own image size contradicts the calibration's.
  c.save(dir.file("good.yml"));
  writeText(dir.file("rig.yaml"), "%YAML:1.0\n---\ncalibration_file: good.yml\nimage_width: 640\n");
  const std::string e = errorOf([&] { StereoRig::load(dir.file("rig.yaml")); });
  EXPECT_NE(e.find(dir.file("rig.yaml") + ": image_width: 640 differs from the calibration's image_size"),
            std::string::npos)
      << e;
  writeText(dir.file("rig2.yaml"), "%YAML:1.0\n---\ncalibration_file: good.yml\nfocal_px: 300\n");
  EXPECT_NE(errorOf([&] { StereoRig::load(dir.file("rig2.yaml")); }).find("focal_px: given by calibration_file"),
            std::string::npos);
  // The calibration gives the cameras; the rig file must still give the head's mounting.
  writeText(dir.file("rig3.yaml"), "%YAML:1.0\n---\ncalibration_file: good.yml\ncamera_height_mm: 70\n");
  EXPECT_NE(errorOf([&] { StereoRig::load(dir.file("rig3.yaml")); }).find(dir.file("rig3.yaml") + ": tilt_rad: missing"),
            std::string::npos);
}

}  // namespace
}  // namespace stereoloc
