#include "frontend/rectify.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "frontend/frontend.h"
#include "src/core/error.h"
#include "src/core/stereo_rig.h"

namespace stereoloc::frontend {
namespace {

StereoCalibration rawCalibration() {
  return StereoCalibration::load(std::string(STEREOLOC_DATA_DIR) + "/stereo_calibration_example.yml");
}

// Intensity-weighted centroid of a bright blob in a grey image.
cv::Point2d centroid(const cv::Mat& grey) {
  const cv::Moments m = cv::moments(grey, false);
  return {m.m10 / m.m00, m.m01 / m.m00};
}

// A bright spot drawn where cv::projectPoints puts a 3-D point in each raw (distorted) image
// appears, after rectification, where the rectified pinhole rig projects it.
TEST(Rectifier, SpotLandsOnRectifiedProjection) {
  const StereoCalibration c = rawCalibration();
  Rectifier rect(c);
  StereoRigParams p;
  p.camera_height_mm = 0.0;
  const StereoRig rig(p, c);
  cv::Mat rvec;
  cv::Rodrigues(c.R, rvec);
  for (const cv::Point3d X : {cv::Point3d(80, 30, 500), cv::Point3d(-120, -50, 700)}) {
    std::vector<cv::Point2d> raw_l, raw_r;
    cv::projectPoints(std::vector<cv::Point3d>{X}, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), c.K1, c.D1, raw_l);
    cv::projectPoints(std::vector<cv::Point3d>{X}, rvec, c.T, c.K2, c.D2, raw_r);
    auto spot = [](const cv::Point2d& at) {
      cv::Mat img(240, 320, CV_32FC1);
      for (int v = 0; v < img.rows; ++v)
        for (int u = 0; u < img.cols; ++u) {
          const double r2 = (u - at.x) * (u - at.x) + (v - at.y) * (v - at.y);
          img.at<float>(v, u) = static_cast<float>(250.0 * std::exp(-r2 / (2 * 1.5 * 1.5)));
        }
      cv::Mat out;
      img.convertTo(out, CV_8UC1);
      return out;
    };
    rect.rectify(spot(raw_l[0]), spot(raw_r[0]));
    const cv::Mat Xr = c.R1 * cv::Mat(X);
    const double b = rig.params().baseline_mm;
    const auto px = rig.project(Eigen::Vector3d(Xr.at<double>(2), 0.5 * b - Xr.at<double>(0), -Xr.at<double>(1)), 0.0);
    ASSERT_TRUE(px);
    const cv::Point2d l = centroid(rect.left()), r = centroid(rect.right());
    EXPECT_NEAR(l.x, px->u_left, 0.1);
    EXPECT_NEAR(l.y, px->v_left, 0.1);
    EXPECT_NEAR(r.x, px->u_right, 0.1);
    EXPECT_NEAR(r.y, px->v_right, 0.1);
    const cv::Point2d back = rect.rawFromRectified(0, px->u_left, px->v_left);
    EXPECT_NEAR(back.x, raw_l[0].x, 0.02);
    EXPECT_NEAR(back.y, raw_l[0].y, 0.02);
  }
}

TEST(Rectifier, SigmaAccountsForStretchAndMapGrid) {
  const StereoCalibration c = rawCalibration();
  Rectifier rect(c);
  // Near the principal point the lens is undistorted and the map scales by the ratio of the
  // rectified to the raw focal length; towards the corners barrel distortion stretches more.
  const double ratio = c.P1.at<double>(0, 0) / c.K1.at<double>(0, 0);
  const double centre = rect.effectiveSigma(0, c.P1.at<double>(0, 2), c.P1.at<double>(1, 2), 0.5);
  EXPECT_NEAR(centre, 0.5 * ratio, 0.005);
  EXPECT_GT(rect.effectiveSigma(0, 5, 5, 0.5), 1.02 * centre);
  // A tiny raw sigma leaves the 1/32 px map grid.
  EXPECT_NEAR(rect.effectiveSigma(1, 160, 120, 0.0), 1.0 / 32 / std::sqrt(12.0), 1e-9);
}

// The two cameras run as two tasks of OpenCV's pool: the pair is the same whatever the thread
// count, and each image is the bilinear fixed-point remap of its own raw image.
TEST(Rectifier, SameImagesWhateverTheThreadCount) {
  const StereoCalibration c = rawCalibration();
  cv::Mat left(c.image_size, CV_8UC3), right(c.image_size, CV_8UC3);
  cv::RNG rng(3);
  rng.fill(left, cv::RNG::UNIFORM, 0, 256);
  rng.fill(right, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(left, left, cv::Size(5, 5), 1.2);
  cv::GaussianBlur(right, right, cv::Size(5, 5), 1.2);
  const int saved = cv::getNumThreads();
  cv::Mat out[2][2];
  for (int t = 0; t < 2; ++t) {
    cv::setNumThreads(t + 1);
    Rectifier rect(c);
    rect.rectify(left, right);
    out[t][0] = rect.left().clone();
    out[t][1] = rect.right().clone();
  }
  cv::setNumThreads(saved);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(cv::norm(out[0][i], out[1][i], cv::NORM_INF), 0.0) << "camera " << i;
    cv::Mat mx, my, ref;
    cv::initUndistortRectifyMap(i == 0 ? c.K1 : c.K2, i == 0 ? c.D1 : c.D2, i == 0 ? c.R1 : c.R2, i == 0 ? c.P1 : c.P2,
                                c.image_size, CV_32FC1, mx, my);
    cv::remap(i == 0 ? left : right, ref, mx, my, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    // Float maps against the 1/32 px fixed-point ones: at most one grey level apart.
    EXPECT_LE(cv::norm(out[0][i], ref, cv::NORM_INF), 1.0) << "camera " << i;
  }
}

TEST(Rectifier, FrontendRectifiesAndRejectsWrongSize) {
  const StereoRig rig(StereoRigParams(), rawCalibration());
  Frontend fe(rig, FieldMap::miroSot());
  ASSERT_NE(fe.rectifier(), nullptr);
  const cv::Mat small(200, 300, CV_8UC3, cv::Scalar(90, 140, 60));
  try {
    fe.process(small, small);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("image_size"), std::string::npos) << e.what();
  }
  EXPECT_EQ(Frontend(StereoRig(), FieldMap::miroSot()).rectifier(), nullptr);
}

}  // namespace
}  // namespace stereoloc::frontend
