#include <gtest/gtest.h>

#include <filesystem>

#include "src/eval/plot.h"
#include "src/io/image_file.h"
#include "test_util.h"

namespace stereoloc {

TEST(Plot, NiceTicksAreOneTwoFiveSteps) {
  const auto t = niceTicks(0, 1500, 6);
  ASSERT_GE(t.size(), 4u);
  EXPECT_DOUBLE_EQ(t[1] - t[0], 500);  // raw 250 rounds up to the next 1-2-5 step
  EXPECT_DOUBLE_EQ(t.front(), 0);
  const auto s = niceTicks(-0.013, 0.021, 5);
  EXPECT_NEAR(s[1] - s[0], 0.01, 1e-15);
  EXPECT_TRUE(niceTicks(1, 1).empty());
}

TEST(Plot, RendersSeriesFieldAndWritesPng) {
  Plot p("trajectory", "x [mm]", "y [mm]", 800, 600);
  p.setEqualAspect(true);
  drawField(p, FieldMap::miroSot());
  p.line({100, 1400}, {100, 1200}, "truth", cv::Scalar(0, 0, 255));
  p.ellipse({750, 650}, (Eigen::Matrix2d() << 900, 300, 300, 400).finished(), 3.0, cv::Scalar(255, 0, 0));
  const cv::Mat img = p.render();
  ASSERT_EQ(img.rows, 600);
  ASSERT_EQ(img.cols, 800);
  // The red diagonal was drawn: some strongly red pixels exist.
  int red = 0;
  for (int r = 0; r < img.rows; ++r)
    for (int c = 0; c < img.cols; ++c) {
      const cv::Vec3b px = img.at<cv::Vec3b>(r, c);
      red += (px[2] > 200 && px[0] < 60 && px[1] < 60) ? 1 : 0;
    }
  EXPECT_GT(red, 300);
  test::TempDir dir;
  p.savePng(dir.file("p.png"));
  EXPECT_FALSE(readImageFile(dir.file("p.png"), ImageColour::Bgr).image.empty());
  Plot bars("rmse", "method", "mm");
  bars.bars({"ekf", "batch"}, {30, 12}, plotColor(0));
  EXPECT_FALSE(bars.render().empty());
}

}  // namespace stereoloc
