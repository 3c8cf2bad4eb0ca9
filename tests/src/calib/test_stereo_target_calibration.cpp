#include "src/calib/stereo_target_calibration.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <cmath>
#include <cstdio>
#include <random>

#include "solvers/self_calibration.h"
#include "src/core/error.h"
#include "src/core/stereo_rig.h"
#include "src/sim/calibration_target.h"
#include "src/sim/error_profile.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// A realistic robot's true cameras (the realistic profile's draw for `seed`).
StereoCalibration trueCameras(uint64_t seed) {
  std::mt19937_64 rng(seed);
  const DrawnErrors e = drawErrors(ErrorProfile::realistic(), 1, rng);
  return trueCameraCalibration(StereoRig(), e);
}

std::vector<TargetPair> pairsOf(const std::vector<CalibrationView>& views) {
  std::vector<TargetPair> pairs;
  for (size_t i = 0; i < views.size(); ++i) pairs.push_back({"pair " + std::to_string(i), views[i].left, views[i].right});
  return pairs;
}

// The rectified disparity at infinity straight ahead of the left camera that rectifying with
// `estimate` leaves on pairs taken by `truth` (0 for an exact estimate: zero-disparity
// rectification): a far point's raw pixels through the true cameras, rectified with the estimate.
double disparityErrorAtInfinity(const StereoCalibration& truth, const StereoCalibration& estimate) {
  const std::vector<cv::Point3d> far = {cv::Point3d(0, 0, 1e9)};
  std::vector<cv::Point2d> raw_l, raw_r;
  cv::projectPoints(far, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), truth.K1, truth.D1, raw_l);
  cv::Mat rt;
  cv::Rodrigues(truth.R, rt);
  cv::projectPoints(far, rt, truth.T, truth.K2, truth.D2, raw_r);
  std::vector<cv::Point2d> rect_l, rect_r;
  cv::undistortPoints(raw_l, rect_l, estimate.K1, estimate.D1, estimate.R1, estimate.P1);
  cv::undistortPoints(raw_r, rect_r, estimate.K2, estimate.D2, estimate.R2, estimate.P2);
  return rect_l[0].x - rect_r[0].x;
}

TEST(StereoTargetCalibration, RecoversARealisticHeadBetterThanItsGivenCalibration) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 16;
  const StereoCalibration truth = trueCameras(3);
  const TargetCalibrationResult r =
      calibrateStereoFromTargets(pairsOf(renderCalibrationViews(truth, board, options, 11)), board);
  EXPECT_EQ(r.used_pairs, 16);
  EXPECT_EQ(r.corners_per_image, 54);
  EXPECT_LT(r.rms_px, 0.15);
  for (const TargetPairResult& p : r.pairs) {
    EXPECT_TRUE(p.used) << p.name << ": " << p.reason;
    EXPECT_GT(p.rms_px, 0.0);
    EXPECT_LT(p.rms_px, 0.3);
  }
  const StereoCalibration& c = r.calibration;
  for (int i = 0; i < 2; ++i) {
    const cv::Mat& K = i == 0 ? c.K1 : c.K2;
    const cv::Mat& Kt = i == 0 ? truth.K1 : truth.K2;
    EXPECT_NEAR(K.at<double>(0, 0), Kt.at<double>(0, 0), 4 * r.sigmas.focal_px[i][0]) << "camera " << i;
    EXPECT_NEAR(K.at<double>(0, 2), Kt.at<double>(0, 2), 4 * r.sigmas.principal_px[i][0]) << "camera " << i;
    EXPECT_NEAR(K.at<double>(1, 2), Kt.at<double>(1, 2), 4 * r.sigmas.principal_px[i][1]) << "camera " << i;
    const cv::Mat& D = i == 0 ? c.D1 : c.D2;
    const cv::Mat& Dt = i == 0 ? truth.D1 : truth.D2;
    EXPECT_NEAR(D.at<double>(0, 0), Dt.at<double>(0, 0), 4 * r.sigmas.distortion[i][0]) << "camera " << i;
  }
  EXPECT_NEAR(cv::norm(c.T), cv::norm(truth.T), 4 * r.sigmas.baseline_mm);
  // Far better than the realistic profile's given calibration (baseline 1 %, principal points
  // 1 px, focal lengths 0.5 %), which is what the self-calibration otherwise starts from.
  EXPECT_LT(r.sigmas.baseline_scale, 0.003);
  EXPECT_LT(r.sigmas.disparity_offset_px, 0.1);
  EXPECT_LT(r.sigmas.focal_scale, 0.003);
  EXPECT_LT(r.sigmas.focal_ratio, 0.003);
  EXPECT_LT(std::abs(disparityErrorAtInfinity(truth, c)), 4 * r.sigmas.disparity_offset_px);
}

// A wide head: the board's image moves by more than half its diagonal between the cameras, and
// the two corner lists still pair corner with corner.
TEST(StereoTargetCalibration, AWideBaselinePairsTheCornersRight) {
  StereoCalibration wide = trueCameras(2);
  wide.T = (cv::Mat_<double>(3, 1) << -90.0, 0.0, 0.0);
  wide.rectify();
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 10;
  options.min_distance_mm = 300.0;
  options.max_distance_mm = 450.0;
  options.max_attempts_per_view = 2000;
  const TargetCalibrationResult r =
      calibrateStereoFromTargets(pairsOf(renderCalibrationViews(wide, board, options, 4)), board);
  EXPECT_EQ(r.used_pairs, 10);
  EXPECT_LT(r.rms_px, 0.15);
  EXPECT_NEAR(cv::norm(r.calibration.T), 90.0, 4 * r.sigmas.baseline_mm);
}

// The standard deviations against the errors over independent robots and view sets. Rendered
// corners have independent errors, so the fit's covariance is honest: mean z^2 near 1 (over 12
// draws a mean z^2 of one parameter above 2.5 has probability ~0.003 for honest sigmas; below
// 0.2 one of ~0.002). The stated ones, never below the fit's, are not over-confident either.
TEST(StereoTargetCalibration, StatedSigmasMatchTheErrors) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 12;
  const int draws = 12;
  double z2[8] = {0, 0, 0, 0, 0, 0, 0, 0}, fit_z2[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  for (int s = 1; s <= draws; ++s) {
    const StereoCalibration truth = trueCameras(static_cast<uint64_t>(s));
    const TargetCalibrationResult r =
        calibrateStereoFromTargets(pairsOf(renderCalibrationViews(truth, board, options, 100 + s)), board);
    const StereoCalibration& c = r.calibration;
    // The rectified frames' forward axes, R1^T e_z: the estimate's turned against the truth's.
    const double yaw = c.R1.at<double>(0, 2) - truth.R1.at<double>(0, 2);
    const double pitch = c.R1.at<double>(1, 2) - truth.R1.at<double>(1, 2);
    const double error[8] = {c.K1.at<double>(0, 0) - truth.K1.at<double>(0, 0),
                             c.K1.at<double>(0, 2) - truth.K1.at<double>(0, 2),
                             c.K2.at<double>(0, 2) - truth.K2.at<double>(0, 2),
                             cv::norm(c.T) - cv::norm(truth.T),
                             disparityErrorAtInfinity(truth, c),
                             c.K2.at<double>(0, 0) / c.K1.at<double>(0, 0) - truth.K2.at<double>(0, 0) / truth.K1.at<double>(0, 0),
                             c.rectifiedFocal() * yaw,
                             pitch};
    auto sigmas = [](const TargetCalibrationSigmas& S) {
      return std::vector<double>{S.focal_px[0][0], S.principal_px[0][0], S.principal_px[1][0], S.baseline_mm,
                                 S.disparity_offset_px, S.focal_ratio, S.column_offset_px, S.tilt_rad};
    };
    const std::vector<double> stated = sigmas(r.sigmas), fit = sigmas(r.fit_sigmas);
    for (int k = 0; k < 8; ++k) {
      z2[k] += std::pow(error[k] / stated[static_cast<size_t>(k)], 2) / draws;
      fit_z2[k] += std::pow(error[k] / fit[static_cast<size_t>(k)], 2) / draws;
    }
  }
  const char* names[8] = {"fx1", "cx1", "cx2", "baseline", "disparity at infinity", "focal ratio", "column offset", "tilt"};
  for (int k = 0; k < 8; ++k) {
    std::printf("%-22s mean z^2 %.2f fit, %.2f stated\n", names[k], fit_z2[k], z2[k]);
    EXPECT_LT(fit_z2[k], 2.5) << names[k];
    EXPECT_GT(fit_z2[k], 0.2) << names[k];
    EXPECT_LT(z2[k], 2.5) << names[k];
  }
}

// Views spread over the image against views of a far, small board: the lens at the image's
// corners is known far worse from the second, and the calibration says so.
TEST(StereoTargetCalibration, TheLensAtTheImageCornersIsAsWellKnownAsTheViewsReachThem) {
  const CheckerBoard board;
  const StereoCalibration truth = trueCameras(6);
  CalibrationViewOptions spread;
  spread.views = 16;
  const TargetCalibrationResult wide =
      calibrateStereoFromTargets(pairsOf(renderCalibrationViews(truth, board, spread, 2)), board);
  CalibrationViewOptions far = spread;
  far.views = 8;
  far.min_distance_mm = 500.0;
  far.max_distance_mm = 550.0;
  const TargetCalibrationResult narrow =
      calibrateStereoFromTargets(pairsOf(renderCalibrationViews(truth, board, far, 2)), board);
  std::printf("the lens at the image's corners: 16 views spread %.2f / %.2f px, 8 far views %.2f / %.2f px\n",
              wide.sigmas.image_corner_px[0], wide.sigmas.image_corner_px[1], narrow.sigmas.image_corner_px[0],
              narrow.sigmas.image_corner_px[1]);
  for (int c = 0; c < 2; ++c) {
    EXPECT_LT(wide.sigmas.image_corner_px[c], TargetCalibrationSigmas::kEdgeWarningPx) << "camera " << c;
    EXPECT_GT(narrow.sigmas.image_corner_px[c], TargetCalibrationSigmas::kEdgeWarningPx) << "camera " << c;
  }
}

TEST(StereoTargetCalibration, PairsWithoutTheWholeBoardAreReportedAndLeftOut) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 8;
  std::vector<TargetPair> pairs = pairsOf(renderCalibrationViews(trueCameras(2), board, options, 5));
  pairs[2].right = cv::Mat(pairs[2].right.size(), CV_8UC1, cv::Scalar(110));  // the board out of view
  pairs[5].left = cv::Mat(pairs[5].left.size(), CV_8UC1, cv::Scalar(110));
  TargetCalibrationOptions o;
  o.min_views = 6;
  const TargetCalibrationResult r = calibrateStereoFromTargets(pairs, board, o);
  EXPECT_EQ(r.used_pairs, 6);
  EXPECT_FALSE(r.pairs[2].used);
  EXPECT_EQ(r.pairs[2].reason, "board not found in the right image");
  EXPECT_EQ(r.pairs[5].reason, "board not found in the left image");
  o.min_views = 7;
  const std::string e = test::errorOf([&] { calibrateStereoFromTargets(pairs, board, o); });
  EXPECT_NE(e.find("6 of 8 pairs show the whole board in both images, 7 needed"), std::string::npos) << e;
  EXPECT_NE(e.find("pair 2: board not found in the right image"), std::string::npos) << e;
}

// A pair whose right image belongs to another pair (two unsynchronised exposures of a moving
// board look alike) shows the whole board in both images but does not fit the others: it is
// left out, and the calibration is the one of the other pairs.
TEST(StereoTargetCalibration, APairThatDoesNotFitTheOthersIsLeftOut) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 9;
  std::vector<TargetPair> pairs = pairsOf(renderCalibrationViews(trueCameras(3), board, options, 7));
  std::vector<TargetPair> good = pairs;
  good.erase(good.begin() + 4);
  pairs[4].right = pairs[5].right.clone();
  TargetCalibrationOptions o;
  o.min_views = 6;
  const TargetCalibrationResult r = calibrateStereoFromTargets(pairs, board, o);
  const TargetCalibrationResult expected = calibrateStereoFromTargets(good, board, o);
  EXPECT_EQ(r.used_pairs, 8);
  EXPECT_FALSE(r.pairs[4].used);
  EXPECT_GT(r.pairs[4].rms_px, 3.0);
  EXPECT_EQ(r.pairs[4].reason.rfind("does not fit the others: its right corners lie ", 0), 0u) << r.pairs[4].reason;
  EXPECT_NE(r.pairs[4].reason.find("over 3.0 times the pairs' median"), std::string::npos) << r.pairs[4].reason;
  EXPECT_NEAR(r.calibration.K1.at<double>(0, 0), expected.calibration.K1.at<double>(0, 0), 1e-9);
  EXPECT_NEAR(cv::norm(r.calibration.T - expected.calibration.T), 0.0, 1e-9);
  EXPECT_NEAR(r.rms_px, expected.rms_px, 1e-12);
  // Kept, it spoils the calibration.
  o.outlier_factor = 0.0;
  const TargetCalibrationResult kept = calibrateStereoFromTargets(pairs, board, o);
  EXPECT_EQ(kept.used_pairs, 9);
  EXPECT_GT(kept.rms_px, 5.0 * r.rms_px);
  // Never below min_views.
  o.outlier_factor = 3.0;
  o.min_views = 9;
  EXPECT_EQ(calibrateStereoFromTargets(pairs, board, o).used_pairs, 9);
  // Two such pairs are found as well: each is judged against the pairs' median geometry, which
  // they do not move.
  std::vector<TargetPair> two = pairs;
  two[7].right = pairs[1].right.clone();
  o.min_views = 6;
  const TargetCalibrationResult r2 = calibrateStereoFromTargets(two, board, o);
  EXPECT_EQ(r2.used_pairs, 7);
  EXPECT_FALSE(r2.pairs[4].used);
  EXPECT_FALSE(r2.pairs[7].used);
  o.outlier_factor = -1.0;
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(pairs, board, o); }).find("outlier_factor"), std::string::npos);
}

TEST(StereoTargetCalibration, BadInputIsAnError) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 6;
  std::vector<TargetPair> pairs = pairsOf(renderCalibrationViews(trueCameras(1), board, options, 3));
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets({}, board); }).find("no image pairs"), std::string::npos);
  std::vector<TargetPair> resized = pairs;
  cv::resize(resized[3].right, resized[3].right, cv::Size(160, 120));
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(resized, board); })
                .find("pair 3: the left image is 320x240, the right 160x120"),
            std::string::npos);
  cv::resize(resized[3].left, resized[3].left, cv::Size(160, 120));
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(resized, board); })
                .find("pair 3: image size 160x120 differs from 320x240 of pair 0"),
            std::string::npos);
  std::vector<TargetPair> empty = pairs;
  empty[1].left = cv::Mat();
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(empty, board); }).find("pair 1: an image of the pair is empty"),
            std::string::npos);
  TargetCalibrationOptions o;
  o.distortion_coefficients = 6;
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(pairs, board, o); }).find("distortion_coefficients"),
            std::string::npos);
  CheckerBoard square = board;
  square.rows = square.columns;
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(pairs, square); }).find("equal sides"), std::string::npos);
  CheckerBoard no_size = board;
  no_size.square_mm = 0.0;
  EXPECT_NE(test::errorOf([&] { calibrateStereoFromTargets(pairs, no_size); }).find("square_mm"), std::string::npos);
}

// The rig `calibrate --rig-out` writes: the calibration as its cameras, the mounting kept, and
// the standard deviations a self-calibration handed the rig takes as its priors.
TEST(StereoTargetCalibration, TheRigHandsItsSigmasToASelfCalibration) {
  const CheckerBoard board;
  CalibrationViewOptions options;
  options.views = 10;
  const TargetCalibrationResult r =
      calibrateStereoFromTargets(pairsOf(renderCalibrationViews(trueCameras(4), board, options, 9)), board);
  test::TempDir dir;
  StereoRigParams mounting;
  mounting.camera_height_mm = 72.5;
  mounting.tilt_rad = 0.05;
  saveCalibratedRig(dir.file("rig.yaml"), mounting, r, 0.01, 1.5, 0.3);
  const StereoRig rig = StereoRig::load(dir.file("rig.yaml"));
  EXPECT_DOUBLE_EQ(rig.params().camera_height_mm, 72.5);
  EXPECT_DOUBLE_EQ(rig.params().tilt_rad, 0.05);
  ASSERT_TRUE(rig.calibration());
  EXPECT_NEAR(rig.calibration()->K1.at<double>(0, 0), r.calibration.K1.at<double>(0, 0), 1e-9);
  EXPECT_NEAR(rig.focal(), r.calibration.rectifiedFocal(), 1e-9);
  const CalibrationHandover h = CalibrationHandover::load(dir.file("rig.yaml"));
  ASSERT_TRUE(h.head_sigmas);
  // The mounting's and the calibration's own, in quadrature.
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[0], std::hypot(0.01, r.sigmas.tilt_rad));
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[1], r.sigmas.baseline_scale);
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[2], std::hypot(r.sigmas.disparity_offset_px, 0.3));
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[3], std::hypot(1.5, r.sigmas.column_offset_px));
  EXPECT_GT(r.sigmas.column_offset_px, 0.0);
  EXPECT_GT(r.sigmas.tilt_rad, 0.0);
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[4], r.sigmas.focal_ratio);
  EXPECT_DOUBLE_EQ((*h.head_sigmas)[5], r.sigmas.focal_scale);
  EXPECT_FALSE(h.wheels);
  // A mounting that states the cameras' exposure offset keeps it, and the disparity offset has
  // no drive's part: the pairs are moved to one instant.
  StereoRigParams unsynchronised = mounting;
  unsynchronised.exposure_offset_s = 0.0036;
  saveCalibratedRig(dir.file("timed.yaml"), unsynchronised, r, 0.01, 1.5, 0.3);
  EXPECT_DOUBLE_EQ(StereoRig::load(dir.file("timed.yaml")).params().exposure_offset_s, 0.0036);
  EXPECT_DOUBLE_EQ((*CalibrationHandover::load(dir.file("timed.yaml")).head_sigmas)[2], r.sigmas.disparity_offset_px);
  EXPECT_NE(test::errorOf([&] { saveCalibratedRig(dir.file("bad.yaml"), mounting, r, 0.0, 1.5, 0.3); })
                .find("tilt_correction_sigma_rad: must be a positive standard deviation"),
            std::string::npos);
}

}  // namespace
}  // namespace stereoloc
