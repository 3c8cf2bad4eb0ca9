#include "src/io/image_file.h"
#include "src/sim/calibration_target.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <filesystem>
#include <random>

#include "src/calib/stereo_target_calibration.h"
#include "src/core/stereo_rig.h"
#include "src/sim/error_profile.h"
#include "test_util.h"

namespace stereoloc {
namespace {

StereoCalibration realisticCameras(uint64_t seed, DrawnErrors* drawn = nullptr) {
  std::mt19937_64 rng(seed);
  const DrawnErrors e = drawErrors(ErrorProfile::realistic(), 1, rng);
  if (drawn) *drawn = e;
  return trueCameraCalibration(StereoRig(), e);
}

// Board corners through a camera, in the detector's order up to the board's half turn.
std::vector<cv::Point2d> projected(const CheckerBoard& board, const cv::Matx33d& R, const cv::Vec3d& t,
                                   const cv::Mat& K, const cv::Mat& D) {
  std::vector<cv::Point3d> X;
  for (const auto& p : board.corners()) X.emplace_back(p.x, p.y, p.z);
  cv::Mat rvec;
  cv::Rodrigues(cv::Mat(R), rvec);
  std::vector<cv::Point2d> out;
  cv::projectPoints(X, rvec, cv::Mat(t), K, D, out);
  return out;
}

double rmsAgainst(const std::vector<cv::Point2f>& found, std::vector<cv::Point2d> truth) {
  if (cv::norm(cv::Point2d(found.front()) - truth.front()) > cv::norm(cv::Point2d(found.front()) - truth.back()))
    std::reverse(truth.begin(), truth.end());
  double sum = 0.0;
  for (size_t i = 0; i < truth.size(); ++i) {
    const cv::Point2d d = cv::Point2d(found[i]) - truth[i];
    sum += d.dot(d);
  }
  return std::sqrt(sum / static_cast<double>(truth.size()));
}

TEST(CalibrationTarget, TheTrueCamerasAreTheDrawnOnes) {
  DrawnErrors e;
  const StereoCalibration c = realisticCameras(7, &e);
  const StereoRig nominal;
  EXPECT_NEAR(c.K1.at<double>(0, 0), nominal.focal() * (1 + e.focal_rel[0]), 1e-9);
  EXPECT_NEAR(c.K2.at<double>(0, 2), nominal.principalU() + e.principal_px[1][0], 1e-9);
  EXPECT_NEAR(c.D2.at<double>(0, 0), e.distortion[1][0], 1e-12);
  EXPECT_NEAR(cv::norm(c.T), nominal.params().baseline_mm * (1 + e.baseline_rel), 1e-9);
  cv::Mat rvec;
  cv::Rodrigues(c.R, rvec);
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(rvec.at<double>(k), e.relative_rotation_rad[k], 1e-12);
  // The right camera's centre, -R^T T, is the true baseline along x of the left camera.
  const cv::Mat centre = -c.R.t() * c.T;
  EXPECT_NEAR(centre.at<double>(0), cv::norm(c.T), 1e-9);
  EXPECT_NEAR(centre.at<double>(1), 0.0, 1e-9);
}

// The rendered corners lie where the true cameras project them: the detector finds them there
// to a tenth of a pixel, distortion and the right camera's rotation included.
TEST(CalibrationTarget, CornersAreWhereTheTrueCamerasProjectThem) {
  const CheckerBoard board;
  const StereoCalibration truth = realisticCameras(3);
  CalibrationViewOptions o;
  o.views = 6;
  const std::vector<CalibrationView> views = renderCalibrationViews(truth, board, o, 21);
  ASSERT_EQ(views.size(), 6u);
  for (const CalibrationView& v : views) {
    ASSERT_EQ(v.left.type(), CV_8UC1);
    ASSERT_EQ(v.left.size(), truth.image_size);
    const std::vector<cv::Point2f> l = detectBoardCorners(v.left, board), r = detectBoardCorners(v.right, board);
    ASSERT_EQ(l.size(), 54u);
    ASSERT_EQ(r.size(), 54u);
    EXPECT_LT(rmsAgainst(l, projected(board, v.R, v.t, truth.K1, truth.D1)), 0.15);
    const cv::Matx33d R_lr(truth.R);
    const cv::Vec3d T_lr(truth.T.at<double>(0), truth.T.at<double>(1), truth.T.at<double>(2));
    EXPECT_LT(rmsAgainst(r, projected(board, R_lr * v.R, R_lr * v.t + T_lr, truth.K2, truth.D2)), 0.15);
  }
}

TEST(CalibrationTarget, DeterministicForASeed) {
  const CheckerBoard board;
  const StereoCalibration truth = realisticCameras(1);
  CalibrationViewOptions o;
  o.views = 2;
  const auto a = renderCalibrationViews(truth, board, o, 4), b = renderCalibrationViews(truth, board, o, 4),
             c = renderCalibrationViews(truth, board, o, 5);
  EXPECT_EQ(cv::norm(a[1].right, b[1].right, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a[1].right, c[1].right, cv::NORM_INF), 0.0);
}

TEST(CalibrationTarget, WritesPairsAndTheirTruth) {
  test::TempDir dir;
  CalibrationViewOptions o;
  o.views = 3;
  const StereoCalibration truth = realisticCameras(2);
  writeCalibrationViews(dir.file("cal"), truth, CheckerBoard(), o, 8);
  for (const char* f : {"left_000.png", "right_000.png", "left_002.png", "right_002.png"})
    EXPECT_FALSE(readImageFile(dir.file(std::string("cal/") + f), ImageColour::AsStored).image.empty()) << f;
  EXPECT_FALSE(std::filesystem::exists(dir.file("cal/left_003.png")));
  const StereoCalibration back = StereoCalibration::load(dir.file("cal/true_calibration.yml"));
  EXPECT_NEAR(back.K1.at<double>(0, 2), truth.K1.at<double>(0, 2), 1e-9);
  EXPECT_NEAR(back.D1.at<double>(0, 0), truth.D1.at<double>(0, 0), 1e-12);
}

TEST(CalibrationTarget, BadOptionsAreErrors) {
  const StereoCalibration truth = realisticCameras(1);
  CalibrationViewOptions o;
  o.views = 0;
  EXPECT_NE(test::errorOf([&] { renderCalibrationViews(truth, CheckerBoard(), o, 1); }).find("views"), std::string::npos);
  o = CalibrationViewOptions();
  o.supersampling = 0;
  EXPECT_NE(test::errorOf([&] { renderCalibrationViews(truth, CheckerBoard(), o, 1); }).find("supersampling"),
            std::string::npos);
  o = CalibrationViewOptions();
  CheckerBoard huge;
  huge.square_mm = 200.0;
  const std::string e = test::errorOf([&] { renderCalibrationViews(truth, huge, o, 1); });
  EXPECT_NE(e.find("did not fit both images"), std::string::npos) << e;
}

}  // namespace
}  // namespace stereoloc
