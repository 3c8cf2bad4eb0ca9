// The region of interest below the field boundary (frontend/field_region.h): found from the
// floor's colour, bridged under objects standing on the boundary, off by default.
#include "frontend/field_region.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "frontend/gradient.h"

namespace stereoloc::frontend {
namespace {

// Green carpet below a sloping boundary (row 80 at the left, 100 at the right), a light wall
// with dark posters above it, a white marking on the carpet and a dark robot standing on the
// boundary (columns 150-190, rows 70-130).
cv::Mat fieldImage() {
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(200, 205, 210));
  for (int x = 0; x < 320; ++x) {
    const int b = 80 + (20 * x) / 319;
    cv::line(img, cv::Point(x, b), cv::Point(x, 239), cv::Scalar(60, 150, 40));
  }
  cv::rectangle(img, cv::Rect(30, 20, 60, 40), cv::Scalar(90, 60, 40), cv::FILLED);
  cv::line(img, cv::Point(0, 200), cv::Point(319, 140), cv::Scalar(235, 235, 235), 6);
  cv::rectangle(img, cv::Rect(150, 70, 41, 61), cv::Scalar(25, 25, 25), cv::FILLED);
  return img;
}

double boundaryRow(int x) { return 80.0 + (20.0 * x) / 319.0; }

TEST(FieldRegion, StartsJustAboveTheBoundaryAndBridgesObjectsOnIt) {
  FieldRegionParams p;
  p.enabled = true;
  FieldRegion region;
  region.compute(fieldImage(), p);
  ASSERT_TRUE(region.restricted());
  ASSERT_EQ(region.top().size(), 320u);
  for (int x = 0; x < 320; ++x) {
    // At most one grid step plus the margin above the boundary (the grid samples it), and
    // never below it, also behind the robot.
    EXPECT_LE(region.top()[x], boundaryRow(x) - p.margin_px + 1.0) << x;
    EXPECT_GE(region.top()[x], boundaryRow(x) - p.margin_px - 2.0 * p.step_px - 1.0) << x;
  }
}

TEST(FieldRegion, DisabledOrWithoutFloorKeepsTheWholeImage) {
  FieldRegion region;
  region.compute(fieldImage(), FieldRegionParams());
  EXPECT_FALSE(region.restricted());
  for (int16_t t : region.top()) EXPECT_EQ(t, 0);
  // A floor colour found nowhere in a column's run (here: noise everywhere) restricts nothing.
  cv::Mat noise(240, 320, CV_8UC3);
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
  FieldRegionParams p;
  p.enabled = true;
  p.min_run = 6;
  region.compute(noise, p);
  for (int16_t t : region.top()) EXPECT_EQ(t, 0);
}

TEST(FieldRegion, GradientStageFindsNoEdgePixelsAboveTheRegion) {
  const cv::Mat img = fieldImage();
  FieldRegionParams p;
  p.enabled = true;
  FieldRegion region;
  region.compute(img, p);
  cv::Mat luma;
  bgrToLuma(img, luma);
  GradientStage all, roi;
  all.compute(luma, GradientParams());
  roi.compute(luma, GradientParams(), region.top().data());
  size_t below = 0;
  for (const EdgePixel& e : all.edges())
    if (e.iy >= region.top()[e.ix]) ++below;
  EXPECT_GT(all.edges().size(), roi.edges().size());
  EXPECT_EQ(roi.edges().size(), below);  // the same pixels below the region's top
  for (const EdgePixel& e : roi.edges()) EXPECT_GE(e.iy, region.top()[e.ix]);
}

}  // namespace
}  // namespace stereoloc::frontend
