// selfCalibratedRig: raw images of cameras that differ from the given calibration as the
// folded rig says, rectified with the GIVEN calibration, show the pixel offsets of the
// self-calibration model (factors/stereo_pixel_calibration_factor.h).
#include "solvers/self_calibrated_rig.h"

#include <gtest/gtest.h>

#include <memory>
#include <opencv2/calib3d.hpp>
#include <string>
#include <vector>

#include "factors/stereo_pixel_image_calibration_factor.h"

namespace stereoloc {
namespace {

StereoCalibration exampleCalibration() {
  return StereoCalibration::load(std::string(STEREOLOC_DATA_DIR) + "/stereo_calibration_example.yml");
}

// Where a point given in the rectified left camera frame (OpenCV axes, mm) appears after the raw
// camera `i` of `truth` images it and `given` rectifies that raw pixel.
cv::Point2d rectifiedWithGiven(const StereoCalibration& truth, const StereoCalibration& given, int i,
                               const cv::Point3d& p_rect_left) {
  // The rectified right camera sits at -P2(0,3) / f along x of the rectified left one.
  const double shift = i == 0 ? 0.0 : truth.rectifiedBaseline();
  const cv::Matx33d R = i == 0 ? cv::Matx33d(truth.R1) : cv::Matx33d(truth.R2);  // raw -> rectified
  const cv::Point3d p_raw = R.t() * cv::Point3d(p_rect_left.x - shift, p_rect_left.y, p_rect_left.z);
  std::vector<cv::Point3d> object = {p_raw};
  std::vector<cv::Point2d> raw, rect;
  cv::projectPoints(object, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), i == 0 ? truth.K1 : truth.K2,
                    i == 0 ? truth.D1 : truth.D2, raw);
  cv::undistortPoints(raw, rect, i == 0 ? given.K1 : given.K2, i == 0 ? given.D1 : given.D2,
                      i == 0 ? given.R1 : given.R2, i == 0 ? given.P1 : given.P2);
  return rect[0];
}

TEST(SelfCalibratedRig, FoldsTheEstimateIntoTheCamerasItRectifies) {
  const StereoCalibration given = exampleCalibration();
  StereoRigParams params;
  params.tilt_rad = deg2rad(2.0);
  const StereoRig given_rig(params, given);
  CalibrationEstimate e;
  e.stereo = true;
  const double dbeta = deg2rad(0.3), k = 1.012, dd = 1.3, du = -0.7, phi = 0.006, psi = -0.004;
  e.head << dbeta, k, dd, du, phi, psi;
  const StereoRig rig = selfCalibratedRig(given_rig, e);
  ASSERT_TRUE(rig.calibration());
  EXPECT_NEAR(rig.params().tilt_rad, params.tilt_rad + dbeta, 1e-12);
  EXPECT_NEAR(rig.params().baseline_mm, k * given_rig.params().baseline_mm, 1e-9);
  EXPECT_NEAR(rig.focal(), given_rig.focal(), 1e-12);
  EXPECT_NEAR(rig.principalU(), given_rig.principalU(), 1e-12);
  EXPECT_NEAR(rig.principalV(), given_rig.principalV(), 1e-12);

  // The folded rig's cameras as the truth: the given rectification sees the model's offsets,
  // u_l = o_u + du + dd/2 + F X/Z, u_r = o_u + du - dd/2 + F (1 + phi) (X - k b)/Z, F = f (1 + psi),
  // v = o_v + F Y/Z. Exact at the
  // image centre; within 0.1 px over the central +-70 px, where the lens distortion's local scale
  // stays within ~6 % of 1 (rectify.h).
  const StereoCalibration& truth = *rig.calibration();
  const double f = given.rectifiedFocal(), ou = given.rectifiedPrincipalU(), ov = given.rectifiedPrincipalV();
  const double kb = k * given.rectifiedBaseline(), F = f * (1 + psi);
  double worst = 0;
  for (double X : {-200.0, -80.0, 0.0, 80.0, 200.0})
    for (double Y : {-150.0, 0.0, 150.0}) {
      const cv::Point3d p(X, Y, 900.0);
      const cv::Point2d l = rectifiedWithGiven(truth, given, 0, p), r = rectifiedWithGiven(truth, given, 1, p);
      const double ul = ou + du + 0.5 * dd + F * X / p.z;
      const double ur = ou + du - 0.5 * dd + F * (1 + phi) * (X - kb) / p.z;
      const double v = ov + F * Y / p.z;
      worst = std::max({worst, std::fabs(l.x - ul), std::fabs(r.x - ur)});
      EXPECT_NEAR(l.x, ul, 0.1) << X << "," << Y;
      EXPECT_NEAR(r.x, ur, 0.1) << X << "," << Y;
      EXPECT_NEAR(l.y, v, 0.1) << X << "," << Y;
      EXPECT_NEAR(r.y, v, 0.1) << X << "," << Y;
      // The disparity, which sets the range (3.4): F k b / Z + dd - phi F (X - k b) / Z.
      EXPECT_NEAR(l.x - r.x, F * kb / p.z + dd - phi * F * (X - kb) / p.z, 0.1) << X << "," << Y;
    }
  // At the image centre the fold is exact to the linearisation's second order.
  const cv::Point3d centre(0.0, 0.0, 900.0);
  EXPECT_NEAR(rectifiedWithGiven(truth, given, 0, centre).x, ou + du + 0.5 * dd, 0.02);
  EXPECT_GT(worst, 0.0);
}

// With the image block the folded rig's cameras, rectified with the given calibration, show
// the pixels the image factor predicts from the same estimate, across the image: the raw
// offsets and focal lengths through the given rectification map, the lens errors and the right
// camera's rotation.
TEST(SelfCalibratedRig, FoldsTheImageBlockAsTheImageFactorSeesIt) {
  const StereoCalibration given = exampleCalibration();
  const StereoRig given_rig(StereoRigParams(), given);
  CalibrationEstimate e;
  e.stereo = true;
  e.head << 0.0, 1.008, 1.1, -0.6, 0.005, -0.004;
  e.image = true;
  e.image_errors << 0.01, -0.004, 0.0003, -0.0002, -0.008, 0.005, -0.0002, 0.0003, 0.0015, -0.0012, 0.0017, 0.002;
  const StereoRig rig = selfCalibratedRig(given_rig, e);
  const StereoCalibration& truth = *rig.calibration();
  // The exposure offset's error goes to the rig's offset (the given rig's is zero).
  EXPECT_DOUBLE_EQ(rig.params().exposure_offset_s, 0.002);
  EXPECT_NEAR(rig.focal(), given_rig.focal(), 1e-12);
  EXPECT_NEAR(rig.principalU(), given_rig.principalU(), 1e-12);
  stereo_pixel_calibration::ImageErrorVector sigma;
  sigma << 0.01, 0.005, 0.0003, 0.0003, 0.01, 0.005, 0.0003, 0.0003, 0.0017, 0.0017, 0.0017, 0.003;
  const stereo_pixel_calibration::ImageErrorVector whitened = e.image_errors.cwiseQuotient(sigma);
  const double hb = 0.5 * given_rig.params().baseline_mm;
  const double pose[3] = {0.0, 0.0, 0.0};
  double worst = 0;
  for (double X : {-300.0, -150.0, 0.0, 150.0, 300.0})
    for (double Y : {-200.0, 0.0, 200.0}) {
      const cv::Point3d p(X, Y, 800.0);
      const cv::Point2d l = rectifiedWithGiven(truth, given, 0, p), r = rectifiedWithGiven(truth, given, 1, p);
      // The rectified left camera (x right, y down, z forward) in the robot frame of an untilted
      // rig at the origin: forward Z, left b/2 - X, up -Y, plus the mounting.
      const Eigen::Vector3d landmark(p.z + given_rig.params().offset_x_mm, hb - p.x,
                                     -p.y + given_rig.params().camera_height_mm);
      const StereoPixels px{l.x, l.y, r.x, r.y};
      std::unique_ptr<ceres::CostFunction> f(StereoPixelImageCalibrationFactor::Create(
          given_rig, landmark, px, 0.0, Eigen::Matrix4d::Identity(), PixelResiduals::Columns, sigma, BodyRate()));
      const double* blocks[3] = {pose, e.head.data(), whitened.data()};
      Eigen::Vector2d res;
      ASSERT_TRUE(f->Evaluate(blocks, res.data(), nullptr));
      worst = std::max(worst, res.cwiseAbs().maxCoeff());
    }
  // px; each image error alone within 0.003 px, the rest the second order of the large q.
  EXPECT_LT(worst, 0.06);
}

// The row block: the folded rig's cameras, rectified with the given calibration, show the right
// rows dv below the left ones (the misalignment the estimate states), alone and with the image
// block's right-camera pitch, whose own row shift the fold takes from the principal point.
TEST(SelfCalibratedRig, FoldsTheRowOffsetIntoTheRightPrincipalRow) {
  const StereoCalibration given = exampleCalibration();
  const StereoRig given_rig(StereoRigParams(), given);
  for (bool image : {false, true}) {
    CalibrationEstimate e;
    e.stereo = true;
    e.row = true;
    e.row_offset_px = 1.4;
    if (image) {
      e.image = true;
      e.image_errors.setZero();
      e.image_errors[8] = 0.0015;  // rad: f pitch = 0.4 px of rows
    }
    const StereoRig rig = selfCalibratedRig(given_rig, e);
    EXPECT_NEAR(rig.principalV(), given_rig.principalV(), 1e-12);
    const StereoCalibration& truth = *rig.calibration();
    for (double X : {-80.0, 0.0, 80.0})
      for (double Y : {-80.0, 0.0, 80.0}) {
        const cv::Point3d p(X, Y, 900.0);
        const cv::Point2d l = rectifiedWithGiven(truth, given, 0, p), r = rectifiedWithGiven(truth, given, 1, p);
        EXPECT_NEAR(r.y - l.y, e.row_offset_px, X == 0 && Y == 0 ? 0.02 : 0.1) << image << " " << X << "," << Y;
      }
    // Without the row block nothing moves the rows apart.
    e.row = false;
    if (!image) {
      const StereoRig plain_rig = selfCalibratedRig(given_rig, e);
      const StereoCalibration& plain = *plain_rig.calibration();
      const cv::Point3d centre(0.0, 0.0, 900.0);
      EXPECT_NEAR(rectifiedWithGiven(plain, given, 1, centre).y - rectifiedWithGiven(plain, given, 0, centre).y, 0.0, 0.02);
    }
  }
}

TEST(SelfCalibratedRig, PinholeRigGetsACalibrationAndNoStereoPartChangesNothing) {
  StereoRigParams params;
  const StereoRig pinhole(params);
  CalibrationEstimate e;
  EXPECT_FALSE(selfCalibratedRig(pinhole, e).calibration());
  e.stereo = true;
  e.head << 0.0, 1.0, 0.8, 0.0, 0.0, 0.0;
  const StereoRig rig = selfCalibratedRig(pinhole, e);
  ASSERT_TRUE(rig.calibration());
  EXPECT_TRUE(rig.calibration()->needsRemap());  // the two raw principal points now differ
  EXPECT_NEAR(rig.calibration()->K1.at<double>(0, 2) - rig.calibration()->K2.at<double>(0, 2), 0.8, 1e-12);
  EXPECT_NEAR(rig.focal(), pinhole.focal(), 1e-12);
  EXPECT_NEAR(rig.params().baseline_mm, pinhole.params().baseline_mm, 1e-12);
}

}  // namespace
}  // namespace stereoloc
