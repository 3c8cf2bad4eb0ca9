// Stage 2: the gradient-based Hough transform votes only near the gradient direction.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "frontend/gbht.h"
#include "frontend/gradient.h"
#include "frontend/peaks.h"
#include "src/core/error.h"

using namespace stereoloc::frontend;
using stereoloc::kTwoPi;

namespace {
constexpr double kDeg = kTwoPi / 360.0;

// Bright half-plane x cos(t) + y sin(t) > rho on a dark background, anti-aliased.
cv::Mat halfPlane(double theta, double rho, int w = 160, int h = 120) {
  cv::Mat img(h, w, CV_8UC1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      double s = 0;
      for (int k = 0; k < 16; ++k) {
        const double sx = x - 0.5 + (k % 4 + 0.5) / 4, sy = y - 0.5 + (k / 4 + 0.5) / 4;
        s += (sx * std::cos(theta) + sy * std::sin(theta) > rho) ? 1.0 : 0.0;
      }
      img.at<uint8_t>(y, x) = static_cast<uint8_t>(std::lround(40 + 160 * s / 16));
    }
  return img;
}
}  // namespace

TEST(Gbht, PeakAtTheLineAndNoVotesFarFromTheGradient) {
  for (double theta_deg : {0.0, 37.0, 90.0, 200.0, 300.0}) {
    const double theta = theta_deg * kDeg, rho = (theta_deg < 180 ? 70.0 : -60.0);
    GradientStage g;
    g.compute(halfPlane(theta, rho), GradientParams());
    HoughAccumulator acc;
    acc.configure(160, 120, HoughParams());
    acc.vote(g.edges(), {});
    std::vector<HoughPeak> peaks;
    detectPeaks(acc, PeakParams(), peaks);
    ASSERT_FALSE(peaks.empty()) << theta_deg;
    double dt = std::fabs(peaks[0].theta - theta);
    dt = std::min(dt, kTwoPi - dt);
    EXPECT_LE(dt, 1.5 * kDeg) << theta_deg;
    EXPECT_NEAR(peaks[0].rho, rho, 3.0) << theta_deg;
    // Gradient-based: nothing outside +-tolerance of the line's direction.
    for (int t = 0; t < acc.numTheta(); ++t) {
      double d = std::fabs(acc.theta(t) - theta);
      d = std::min(d, kTwoPi - d);
      if (d < 12 * kDeg) continue;  // tolerance 5 deg + anti-aliasing error of the gradient
      for (int r = 0; r < acc.numRho(); ++r) ASSERT_EQ(acc.at(t, r), 0) << theta_deg << " " << t;
    }
  }
}

TEST(Gbht, UsedPixelsDoNotVoteAndBadParamsAreRejected) {
  GradientStage g;
  g.compute(halfPlane(0.3, 50), GradientParams());
  HoughAccumulator acc;
  acc.configure(160, 120, HoughParams());
  std::vector<uint8_t> used(g.edges().size(), 1);
  acc.vote(g.edges(), used);
  for (int c : acc.cells()) ASSERT_EQ(c, 0);
  HoughParams bad;
  bad.theta_step_deg = 7.0;  // does not divide 360
  EXPECT_THROW(acc.configure(160, 120, bad), stereoloc::Error);
}

TEST(Peaks, TwoLinesTwoPeaksStrongestFirstAndThreshold) {
  // Two bright stripes of different lengths: four directed edges.
  cv::Mat img(120, 160, CV_8UC1, cv::Scalar(30));
  cv::rectangle(img, cv::Rect(40, 10, 8, 100), cv::Scalar(210), cv::FILLED);   // long vertical stripe
  cv::rectangle(img, cv::Rect(70, 60, 60, 8), cv::Scalar(210), cv::FILLED);    // shorter horizontal
  GradientStage g;
  g.compute(img, GradientParams());
  HoughAccumulator acc;
  acc.configure(160, 120, HoughParams());
  acc.vote(g.edges(), {});
  std::vector<HoughPeak> peaks;
  PeakParams pp;
  pp.min_votes = 40;
  detectPeaks(acc, pp, peaks);
  ASSERT_GE(peaks.size(), 4u);
  for (size_t i = 1; i < peaks.size(); ++i) EXPECT_GE(peaks[i - 1].votes, peaks[i].votes);
  // The two strongest are the long stripe's sides (theta 0 and 180 deg).
  for (int i = 0; i < 2; ++i) EXPECT_NEAR(std::fabs(std::sin(peaks[i].theta)), 0.0, 0.05);
  pp.min_votes = 1000;
  detectPeaks(acc, pp, peaks);
  EXPECT_TRUE(peaks.empty());
}

// detectPeaks skips 4 cells at a time when none has a bit at or above the largest power of
// two <= min_votes: a cell of exactly min_votes votes must still be a peak at every rho
// position (each phase of the 4-cell words), and one vote fewer must not.
TEST(Peaks, CellAtTheThresholdIsFoundAtEveryRhoPosition) {
  const int w = 160, h = 120;
  HoughAccumulator acc;
  acc.configure(w, h, HoughParams());
  for (int n : {16, 17, 18, 31, 32, 33}) {
    for (int x0 = 2; x0 < w - 2; ++x0) {
      // n edge pixels on the vertical line x = x0, gradient to the right (theta 0): all n vote
      // for one cell of theta bin 0 (and perhaps of bin +-1); no cell gets more.
      std::vector<EdgePixel> edges;
      for (int k = 0; k < n; ++k) {
        EdgePixel e;
        e.x = static_cast<float>(x0);
        e.y = static_cast<float>(5.0 + k * 110.0 / (n - 1));  // 110 px: > 3 px of rho spread from 2 deg on
        e.ix = static_cast<int16_t>(x0);
        e.iy = static_cast<int16_t>(std::lround(e.y));
        edges.push_back(e);
      }
      acc.vote(edges, {});
      std::vector<HoughPeak> peaks;
      PeakParams pp;
      pp.min_votes = n;
      detectPeaks(acc, pp, peaks);
      ASSERT_FALSE(peaks.empty()) << n << " " << x0;
      EXPECT_TRUE(peaks[0].theta_bin <= 1 || peaks[0].theta_bin >= acc.numTheta() - 1) << n << " " << x0;
      EXPECT_EQ(peaks[0].votes, n) << n << " " << x0;
      EXPECT_NEAR(peaks[0].rho, x0, 3.0) << n << " " << x0;
      pp.min_votes = n + 1;
      detectPeaks(acc, pp, peaks);
      EXPECT_TRUE(peaks.empty()) << n << " " << x0;
    }
  }
}
