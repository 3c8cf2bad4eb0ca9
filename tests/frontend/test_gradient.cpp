// Stage 1: luma, Sobel, non-maximum suppression and the sub-pixel edge position.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>
#include <opencv2/core.hpp>

#include "frontend/gradient.h"
#include "src/core/error.h"

using namespace stereoloc::frontend;

namespace {
// Vertical step edge at sub-pixel column `edge` (dark left, bright right), box-filtered.
cv::Mat stepImage(double edge, int dark = 30, int bright = 200) {
  cv::Mat img(40, 60, CV_8UC1);
  for (int x = 0; x < img.cols; ++x) {
    const double cover = std::clamp(x + 0.5 - edge, 0.0, 1.0);  // fraction of pixel x right of the edge
    const int v = static_cast<int>(std::lround(dark + cover * (bright - dark)));
    img.col(x).setTo(v);
  }
  return img;
}
}  // namespace

TEST(Gradient, FastAngleMatchesAtan2) {
  double worst = 0;
  for (int i = 0; i < 3600; ++i) {
    const double a = i * kTwoPi / 3600;
    const float x = static_cast<float>(100 * std::cos(a)), y = static_cast<float>(100 * std::sin(a));
    double ref = std::atan2(y, x);
    if (ref < 0) ref += kTwoPi;
    double d = std::fabs(fastAngle(y, x) - ref);
    d = std::min(d, kTwoPi - d);
    worst = std::max(worst, d);
  }
  EXPECT_LT(worst, 2e-4);
}

TEST(Gradient, LumaUsesBt601Weights) {
  cv::Mat bgr(2, 2, CV_8UC3, cv::Scalar(0, 0, 255)), y;  // pure red
  bgrToLuma(bgr, y);
  EXPECT_NEAR(y.at<uint8_t>(0, 0), 0.299 * 255, 1.0);
  EXPECT_THROW(bgrToLuma(cv::Mat(2, 2, CV_8UC1), y), stereoloc::Error);
}

TEST(Gradient, StepEdgeGivesOneThinSubPixelEdgePerRow) {
  for (double edge : {29.5, 29.8, 30.1, 30.35}) {
    GradientStage g;
    g.compute(stepImage(edge), GradientParams());
    ASSERT_EQ(g.edges().size(), static_cast<size_t>(40 - 4)) << edge;  // one per inner row
    for (const EdgePixel& e : g.edges()) {
      // Pixel centres at integers: the box-filtered step's Sobel maximum is at the step.
      EXPECT_NEAR(e.x, edge, 0.1) << edge;
      EXPECT_NEAR(std::min<double>(e.angle, kTwoPi - e.angle), 0.0, 1e-3);  // bright to the right
      EXPECT_EQ(g.edgeAt(e.ix, e.iy), &e - g.edges().data());
    }
  }
}

TEST(Gradient, ThresholdRejectsWeakEdgesAndBuffersAreReused) {
  GradientStage g;
  g.compute(stepImage(30.0, 100, 105), GradientParams());  // step of 5 grey levels: Sobel 20 < 48
  EXPECT_TRUE(g.edges().empty());
  g.compute(stepImage(30.0), GradientParams());
  EXPECT_FALSE(g.edges().empty());
  g.compute(stepImage(30.0, 100, 105), GradientParams());
  EXPECT_TRUE(g.edges().empty());
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) ASSERT_EQ(g.edgeAt(x, y), -1);
}

// The suppression loop skips 8 pixels at a time where the byte mask of the threshold is clear:
// an edge in any column (each phase of the 8-pixel words, and next to the right border) and
// an image width that is no multiple of 8 must still give one edge pixel per inner row.
TEST(Gradient, EdgesInEveryColumnSurviveTheWordSkip) {
  for (int cols : {60, 67}) {
    for (int col = 3; col <= cols - 4; ++col) {
      cv::Mat img(20, cols, CV_8UC1);
      for (int x = 0; x < cols; ++x) img.col(x).setTo(x < col ? 30 : 200);  // step between col - 1 and col
      GradientStage g;
      g.compute(img, GradientParams());
      ASSERT_EQ(g.edges().size(), static_cast<size_t>(20 - 4)) << cols << " " << col;
      for (const EdgePixel& e : g.edges()) ASSERT_NEAR(e.x, col - 0.5, 0.51) << cols << " " << col;
    }
  }
}

// The automatic threshold follows the image's texture: on a strong step over a textured floor
// (Gaussian noise, sigma 10 grey levels, fixed seed) the texture's edges go, the step stays;
// on a clean image the fixed threshold is the floor and nothing changes.
TEST(Gradient, AutomaticThresholdRisesWithTextureOnly) {
  cv::Mat img = stepImage(30.0, 60, 220);
  cv::Mat noise(img.size(), CV_16S), textured;
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::NORMAL, 0, 10);
  img.convertTo(textured, CV_16S);
  textured += noise;
  textured.convertTo(textured, CV_8U);
  GradientParams fixed, autop;
  autop.auto_factor = 6.0;
  GradientStage g;
  g.compute(textured, fixed);
  const size_t fixed_edges = g.edges().size();
  EXPECT_DOUBLE_EQ(g.threshold(), 48.0);
  g.compute(textured, autop);
  EXPECT_GT(g.threshold(), 48.0);
  EXPECT_LT(g.edges().size(), fixed_edges / 2);
  int on_step = 0;  // the step at x = 30 keeps one edge pixel per inner row
  for (const EdgePixel& e : g.edges()) on_step += std::fabs(e.x - 29.5) < 1.0 ? 1 : 0;
  EXPECT_GE(on_step, g.height() - 4);
  g.compute(img, autop);  // clean: median 0, the fixed threshold applies
  EXPECT_DOUBLE_EQ(g.threshold(), 48.0);
}

// The automatic threshold is auto_factor times the exact median of the squared Sobel magnitude
// on every 3rd pixel of every 3rd row, whether the median is small (carpet) or large (strong
// texture: the coarse histogram bins).
TEST(Gradient, AutomaticThresholdIsTheExactSampleMedian) {
  for (const double sigma : {3.0, 12.0, 60.0}) {
    cv::Mat noise(97, 131, CV_16S), img;
    cv::RNG rng(11);
    rng.fill(noise, cv::RNG::NORMAL, 128, sigma);
    noise.convertTo(img, CV_8U);
    GradientParams p;
    p.magnitude_threshold = 1;
    p.auto_factor = 2.5;
    GradientStage g;
    g.compute(img, p);
    std::vector<int64_t> s;
    for (int y = 2; y < img.rows - 2; y += 3)
      for (int x = 2; x < img.cols - 2; x += 3) {
        const int64_t gx = g.gx().at<int16_t>(y, x), gy = g.gy().at<int16_t>(y, x);
        s.push_back(gx * gx + gy * gy);
      }
    std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(s.size() / 2), s.end());
    const double expected = std::sqrt(std::ceil(p.auto_factor * p.auto_factor * static_cast<double>(s[s.size() / 2])));
    EXPECT_DOUBLE_EQ(g.threshold(), expected) << "sigma " << sigma;
    EXPECT_GT(s[s.size() / 2], sigma > 50 ? 4096 : 0) << "sigma " << sigma;
  }
}
