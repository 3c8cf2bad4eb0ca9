// The rectified side-by-side view `calibrate --overlay` writes: the images where rectification
// puts them, the marks where it puts the points, the row lines, and its errors.
#include "src/calib/rectified_view.h"

#include <gtest/gtest.h>

#include "test_util.h"

namespace stereoloc {
namespace {

// An ideal head rectifies by the identity: the view is the raw pair side by side.
TEST(RectifiedView, AnIdealHeadShowsTheRawPairWithItsPointsAndRowLines) {
  const StereoCalibration c = idealCalibration(80, 60, 70.0, 40.0, 30.0, 60.0);
  cv::Mat left(60, 80, CV_8UC1, cv::Scalar(40)), right(60, 80, CV_8UC1, cv::Scalar(90));
  const RectifiedView view(c);
  const cv::Mat out = view.draw(left, right, {cv::Point2f(20.0f, 31.0f)}, {cv::Point2f(50.0f, 31.0f)}, 10);
  ASSERT_EQ(out.size(), cv::Size(160, 60));
  ASSERT_EQ(out.type(), CV_8UC3);
  EXPECT_EQ(out.at<cv::Vec3b>(30, 70), cv::Vec3b(40, 40, 40));    // left image, between lines
  EXPECT_EQ(out.at<cv::Vec3b>(30, 150), cv::Vec3b(90, 90, 90));   // right image
  EXPECT_EQ(out.at<cv::Vec3b>(5, 10), cv::Vec3b(0, 200, 0));      // a row line every 10 rows from row 5
  EXPECT_EQ(out.at<cv::Vec3b>(15, 120), cv::Vec3b(0, 200, 0));
  // The marks: red circles of radius 3 px around (20, 31) and (80 + 50, 31).
  for (const cv::Point centre : {cv::Point(20, 31), cv::Point(130, 31)}) {
    const cv::Vec3b on = out.at<cv::Vec3b>(centre.y, centre.x + 3);
    EXPECT_GT(on[2], 150) << centre;
    EXPECT_LT(on[1], 100) << centre;
    EXPECT_EQ(out.at<cv::Vec3b>(centre.y, centre.x), out.at<cv::Vec3b>(centre.y, centre.x - 8)) << "hollow " << centre;
  }
}

TEST(RectifiedView, ImagesOfAnotherSizeOrNoRowsBetweenLinesAreErrors) {
  const StereoCalibration c = idealCalibration(80, 60, 70.0, 40.0, 30.0, 60.0);
  const RectifiedView view(c);
  const cv::Mat good(60, 80, CV_8UC1, cv::Scalar(0)), small(50, 80, CV_8UC1, cv::Scalar(0));
  EXPECT_EQ(test::errorOf([&] { view.draw(good, small, {}, {}); }),
            "rectified view: image size 80x50 differs from the calibration's image_size 80x60");
  EXPECT_EQ(test::errorOf([&] { view.draw(good, good, {}, {}, 0); }),
            "rectified view: line spacing must be positive, got 0");
  StereoCalibration raw = c;
  raw.R1 = cv::Mat();
  EXPECT_NE(test::errorOf([&] { RectifiedView{raw}; }).find("R1, P1, R2, P2: not rectified"), std::string::npos);
}

}  // namespace
}  // namespace stereoloc
