#include "frontend/rectify.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

#include "frontend/frontend.h"
#include "src/core/angles.h"
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

// A blurred random BGR image of the calibration's size.
cv::Mat randomImage(const cv::Size& size, uint64_t seed) {
  cv::Mat img(size, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(img, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(img, img, cv::Size(5, 5), 1.2);
  return img;
}

// The example calibration with the rectified focal length scaled: below 1 the rectified image
// sees beyond the raw one, so the maps leave the raw image (replicated borders).
StereoCalibration zoomed(double scale) {
  StereoCalibration c = rawCalibration();
  c.P1 = c.P1.clone();
  c.P2 = c.P2.clone();
  for (cv::Mat* P : {&c.P1, &c.P2}) {
    P->at<double>(0, 0) *= scale;
    P->at<double>(1, 1) *= scale;
    P->at<double>(0, 3) *= scale;
  }
  return c;
}

cv::Mat referenceRemap(const StereoCalibration& c, int i, const cv::Mat& src) {
  cv::Mat mx, my, fixed, frac, out;
  cv::initUndistortRectifyMap(i == 0 ? c.K1 : c.K2, i == 0 ? c.D1 : c.D2, i == 0 ? c.R1 : c.R2, i == 0 ? c.P1 : c.P2,
                              c.image_size, CV_32FC1, mx, my);
  cv::convertMaps(mx, my, fixed, frac, CV_16SC2, false);
  cv::remap(src, out, fixed, frac, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return out;
}

// The luma path gives exactly cv::remap(cvtColor(raw)) on the rows it rectifies, borders
// included, whatever the thread count and with either kernel; the colour samples are exactly the
// whole-image remap's.
TEST(Rectifier, LumaPathAndColourSamplesEqualWholeImageRemap) {
  const int saved = cv::getNumThreads();
  // The third calibration's rows end in pixels outside the 8-pixel blocks of the vector kernel.
  for (const double scale : {1.0, 0.7, 0.9}) {
    StereoCalibration c = zoomed(scale);
    if (scale == 0.9) c.image_size = cv::Size(317, 237);
    const cv::Mat left = randomImage(c.image_size, 5), right = randomImage(c.image_size, 6);
    cv::Mat grey[2];
    cv::cvtColor(left, grey[0], cv::COLOR_BGR2GRAY);
    cv::cvtColor(right, grey[1], cv::COLOR_BGR2GRAY);
    const cv::Mat ref_l = referenceRemap(c, 0, grey[0]), ref_r = referenceRemap(c, 1, grey[1]);
    if (scale < 1) {
      cv::Mat mx, my, constant;
      cv::initUndistortRectifyMap(c.K1, c.D1, c.R1, c.P1, c.image_size, CV_32FC1, mx, my);
      cv::remap(grey[0], constant, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
      ASSERT_GT(cv::countNonZero(constant == 0), 100) << "the zoomed maps must leave the raw image";
    }
    for (int run = 0; run < 3; ++run) {
      const int threads = run == 1 ? 2 : 1;
      cv::setNumThreads(threads);
      Rectifier rect(c);
      if (run == 2) {
        rect.setKernel(Rectifier::Kernel::Scalar);
        EXPECT_FALSE(rect.vectorKernel());
      } else {
#if defined(__x86_64__) || defined(__i386__)
        EXPECT_EQ(rect.vectorKernel(), static_cast<bool>(__builtin_cpu_supports("ssse3")));
#endif
      }
      cv::Mat luma_l, luma_r;
      rect.beginPair(left, right, luma_l);
      EXPECT_EQ(cv::norm(luma_l, ref_l, cv::NORM_INF), 0.0) << "scale " << scale << " run " << run;
      rect.rightLumaRows(0, 7, luma_r);
      rect.rightLumaRows(100, 131, luma_r);
      rect.rightLumaRows(230, 300, luma_r);
      for (const cv::Range rows : {cv::Range(0, 7), cv::Range(100, 131), cv::Range(230, c.image_size.height)})
        EXPECT_EQ(cv::norm(luma_r.rowRange(rows), ref_r.rowRange(rows), cv::NORM_INF), 0.0) << "rows " << rows.start;
      const cv::Mat full_l = referenceRemap(c, 0, left), full_r = referenceRemap(c, 1, right);
      rect.colour(0, cv::Rect(2, 2, 318, 238), 4);
      rect.colour(1, cv::Rect(40, 60, 100, 20));
      for (int v = 2; v < c.image_size.height; v += 4)
        for (int u = 2; u < c.image_size.width; u += 4)
          ASSERT_EQ(rect.colourImage(0).at<cv::Vec3b>(v, u), full_l.at<cv::Vec3b>(v, u)) << u << "," << v;
      EXPECT_EQ(cv::norm(rect.colourImage(1)(cv::Rect(40, 60, 100, 20)), full_r(cv::Rect(40, 60, 100, 20)), cv::NORM_INF),
                0.0);
      EXPECT_EQ(cv::norm(rect.rectifiedCopy(1, right), full_r, cv::NORM_INF), 0.0);
    }
  }
  cv::setNumThreads(saved);
}

// A raw pair of the example calibration: white markings and a yellow goal area bordered by
// white on a green floor, drawn straight into the raw (distorted) images.
std::pair<cv::Mat, cv::Mat> drawnRawPair(const cv::Size& size) {
  cv::Mat img[2];
  for (int i = 0; i < 2; ++i) {
    const int shift = i == 0 ? 0 : -14;  // a disparity
    img[i] = cv::Mat(size, CV_8UC3, cv::Scalar(40, 90, 40));
    cv::rectangle(img[i], cv::Point(90 + shift, 40), cv::Point(230 + shift, 110), cv::Scalar(235, 235, 235), cv::FILLED);
    cv::rectangle(img[i], cv::Point(130 + shift, 50), cv::Point(190 + shift, 100), cv::Scalar(20, 210, 220), cv::FILLED);
    cv::line(img[i], cv::Point(10, 230), cv::Point(300 + shift, 150), cv::Scalar(235, 235, 235), 5, cv::LINE_AA);
    cv::line(img[i], cv::Point(60 + shift, 130), cv::Point(200 + shift, 235), cv::Scalar(235, 235, 235), 5, cv::LINE_AA);
    cv::GaussianBlur(img[i], img[i], cv::Size(3, 3), 0.8);
  }
  return {img[0], img[1]};
}

// The frontend's luma path on a raw pair finds what the frontend finds on the pair rectified
// whole in colour: the goal corners exactly (the colour it reads is the same), the line
// features within the luma rounding (remapped luma against luma of the remapped colour: each
// rounds twice, so they differ by a grey level or two, which moves the sub-pixel edges of the
// 45-level yellow/white border by up to ~0.12 px).
TEST(Rectifier, FrontendLumaPathMatchesColourRectifiedPair) {
  const StereoCalibration c = rawCalibration();
  const StereoRig raw_rig(StereoRigParams(), c);
  const auto [left, right] = drawnRawPair(c.image_size);
  Frontend fe(raw_rig, FieldMap::miroSot());
  const FrontendResult got = fe.process(left, right);
  Rectifier rect(c);
  rect.rectify(left, right);
  Frontend ref_fe(StereoRig(raw_rig.params()), FieldMap::miroSot());
  const FrontendResult want = ref_fe.process(rect.left(), rect.right());
  int goals = 0;
  for (const PointFeature& w : want.features) {
    if (w.type != LandmarkType::GoalCorner) continue;
    ++goals;
    bool found = false;
    for (const PointFeature& g : got.features)
      found |= g.type == LandmarkType::GoalCorner && g.color == w.color && g.side == w.side && g.u == w.u && g.v == w.v;
    EXPECT_TRUE(found) << "goal corner side " << w.side;
  }
  EXPECT_EQ(goals, 2);
  int goal_matches = 0;
  for (const StereoFeature& w : want.matched) {
    if (w.feature.type != LandmarkType::GoalCorner) continue;
    for (const StereoFeature& g : got.matched)
      if (g.feature.type == LandmarkType::GoalCorner && g.feature.side == w.feature.side) {
        EXPECT_EQ(g.pixels.u_right, w.pixels.u_right);
        ++goal_matches;
      }
  }
  EXPECT_EQ(goal_matches, 2);
  // Equal vote counts may come out of the Hough stage in another order: pair lines by value.
  ASSERT_EQ(got.lines.size(), want.lines.size());
  ASSERT_GE(want.lines.size(), 4u);
  for (const LineFeature& w : want.lines) {
    bool found = false;
    for (const LineFeature& g : got.lines)
      found |= std::fabs(g.rho - w.rho) < 0.2 && std::fabs(wrapAngle(g.theta - w.theta)) < 0.003;
    EXPECT_TRUE(found) << "line rho " << w.rho << " theta " << w.theta;
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
