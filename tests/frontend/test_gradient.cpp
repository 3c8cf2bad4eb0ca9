// Stage 1: luma, Sobel, non-maximum suppression and the sub-pixel edge position.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>
#include <cstdint>
#include <string>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "frontend/gradient.h"
#include "src/core/error.h"

using namespace stereoloc::frontend;
using stereoloc::kTwoPi;

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
// on every kSampleStep-th pixel of every kSampleStep-th row, whether the median is small
// (carpet) or large (strong texture: the overflow bin), and on an image with so many samples
// that a bin of the four 16-bit tables could overflow (one 32-bit table then).
TEST(Gradient, AutomaticThresholdIsTheExactSampleMedian) {
  constexpr int step = GradientStage::kSampleStep;
  for (const double sigma : {3.0, 12.0, 60.0, 5.0}) {
    const bool large = sigma == 5.0;  // more than 4 x 65535 samples
    cv::Mat noise(large ? 520 * step : 97, large ? 520 * step : 131, CV_16S), img;
    cv::RNG rng(11);
    rng.fill(noise, cv::RNG::NORMAL, 128, sigma);
    noise.convertTo(img, CV_8U);
    GradientParams p;
    p.magnitude_threshold = 1;
    p.auto_factor = large ? 6.0 : 2.5;  // large: few edge pixels, a short test
    GradientStage g;
    g.compute(img, p);
    std::vector<int64_t> s;
    for (int y = 2; y < img.rows - 2; y += step)
      for (int x = 2; x < img.cols - 2; x += step) {
        const int64_t gx = g.gx().at<int16_t>(y, x), gy = g.gy().at<int16_t>(y, x);
        s.push_back(gx * gx + gy * gy);
      }
    std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(s.size() / 2), s.end());
    const double expected = std::sqrt(std::ceil(p.auto_factor * p.auto_factor * static_cast<double>(s[s.size() / 2])));
    EXPECT_DOUBLE_EQ(g.threshold(), expected) << "sigma " << sigma;
    EXPECT_GT(s[s.size() / 2], sigma > 50 ? 4096 : 0) << "sigma " << sigma;
    if (large) {
      EXPECT_GT(s.size(), size_t{4} * 65535);
    }
  }
}

namespace {

// The stage as specified, one pixel at a time: Sobel of the whole image, the exact median of
// every kSampleStep-th pixel of every kSampleStep-th row by nth_element, suppression of every pixel at the
// threshold and in the region. The stage's bit masks, partial Sobel, histogram select,
// branch-free suppression and four-at-a-time edge pixels must give exactly these edge pixels.
std::vector<EdgePixel> referenceEdges(const cv::Mat& luma, const GradientParams& p, const int16_t* top, double& threshold) {
  cv::Mat gx, gy;
  cv::spatialGradient(luma, gx, gy, 3);
  const int w = luma.cols, h = luma.rows;
  std::vector<int64_t> m2(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int64_t a = gx.at<int16_t>(y, x), b = gy.at<int16_t>(y, x);
      m2[static_cast<size_t>(y) * w + x] = a * a + b * b;
    }
  int64_t thr2 = int64_t{p.magnitude_threshold} * p.magnitude_threshold;
  if (p.auto_factor > 0) {
    std::vector<int64_t> s;
    for (int y = 2; y < h - 2; y += GradientStage::kSampleStep)
      for (int x = 2; x < w - 2; x += GradientStage::kSampleStep) s.push_back(m2[static_cast<size_t>(y) * w + x]);
    if (!s.empty()) {
      std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(s.size() / 2), s.end());
      thr2 = std::max(thr2, static_cast<int64_t>(std::ceil(p.auto_factor * p.auto_factor * static_cast<double>(s[s.size() / 2]))));
    }
  }
  threshold = std::sqrt(static_cast<double>(thr2));
  std::vector<EdgePixel> out;
  for (int y = 2; y < h - 2; ++y)
    for (int x = 2; x < w - 2; ++x) {
      const int64_t c = m2[static_cast<size_t>(y) * w + x];
      if (c < thr2 || (top && y < top[x])) continue;
      const int gxv = gx.at<int16_t>(y, x), gyv = gy.at<int16_t>(y, x);
      const int ax = std::abs(gxv), ay = std::abs(gyv);
      int dx = 1, dy = ((gxv > 0) == (gyv > 0)) ? 1 : -1;
      if (ay * 256 <= ax * 106) {
        dy = 0;
      } else if (ax * 256 <= ay * 106) {
        dx = 0;
        dy = 1;
      }
      const int64_t mp = m2[static_cast<size_t>(y + dy) * w + x + dx], mm = m2[static_cast<size_t>(y - dy) * w + x - dx];
      if (!(c > mm && c >= mp)) continue;
      const float fm = std::sqrt(static_cast<float>(mm)), f0 = std::sqrt(static_cast<float>(c)), fp = std::sqrt(static_cast<float>(mp));
      const float den = fm - 2.0f * f0 + fp;
      const float s = std::clamp(den < 0.0f ? 0.5f * (fm - fp) / den : 0.0f, -0.5f, 0.5f);
      EdgePixel e;
      e.ix = static_cast<int16_t>(x);
      e.iy = static_cast<int16_t>(y);
      e.x = static_cast<float>(x) + s * static_cast<float>(dx);
      e.y = static_cast<float>(y) + s * static_cast<float>(dy);
      e.angle = fastAngle(static_cast<float>(gyv), static_cast<float>(gxv));
      e.mag = f0;
      int bin = static_cast<int>(e.angle * (360.0f / 6.28318548f) + 0.5f);
      if (bin >= 360) bin -= 360;
      e.dir_bin = static_cast<uint16_t>(bin);
      out.push_back(e);
    }
  return out;
}

// Textured floor (Gaussian noise), a bright stripe at a slant, a disc and a dark block, so
// that every gradient direction and sector occurs.
cv::Mat texturedImage(int w, int h, double sigma, uint64_t seed) {
  cv::Mat noise(h, w, CV_16S), img;
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::NORMAL, 0, sigma);
  cv::Mat base(h, w, CV_16S, cv::Scalar(90));
  cv::line(base, cv::Point(0, h / 3), cv::Point(w - 1, 2 * h / 3), cv::Scalar(220), 5);
  cv::circle(base, cv::Point(w / 2, h / 2), h / 5, cv::Scalar(170), cv::FILLED);
  cv::rectangle(base, cv::Rect(w / 8, h / 8, w / 5, h / 6), cv::Scalar(20), cv::FILLED);
  base += noise;
  base.convertTo(img, CV_8U);
  return img;
}

void expectSameEdges(const GradientStage& g, const std::vector<EdgePixel>& ref, double ref_thr, const char* what) {
  EXPECT_DOUBLE_EQ(g.threshold(), ref_thr) << what;
  ASSERT_EQ(g.edges().size(), ref.size()) << what;
  for (size_t k = 0; k < ref.size(); ++k) {
    const EdgePixel& a = g.edges()[k];
    const EdgePixel& b = ref[k];
    ASSERT_TRUE(a.ix == b.ix && a.iy == b.iy && a.x == b.x && a.y == b.y && a.angle == b.angle && a.mag == b.mag &&
                a.dir_bin == b.dir_bin)
        << what << ": edge " << k << " at (" << b.ix << ", " << b.iy << ")";
    EXPECT_EQ(g.edgeAt(a.ix, a.iy), static_cast<int>(k)) << what;
  }
  int mapped = 0;
  for (int y = 0; y < g.height(); ++y)
    for (int x = 0; x < g.width(); ++x) mapped += g.edgeAt(x, y) >= 0 ? 1 : 0;
  EXPECT_EQ(mapped, static_cast<int>(ref.size())) << what;
}

}  // namespace

// Fixed and automatic thresholds (small medians: fine bins; strong texture: coarse bins),
// whole images and field regions whose highest top lies at rows 0-4, in the middle or below
// the image, on one reused stage (rows of earlier images must not leak in) and odd sizes (131:
// a partial group of 8 and of 64 columns; 6: narrower than one group of 8).
TEST(Gradient, EqualsThePixelByPixelReference) {
  GradientStage g;
  int cases = 0;
  for (const cv::Size size : {cv::Size(320, 240), cv::Size(131, 97), cv::Size(64, 7), cv::Size(6, 9)}) {
    for (const double sigma : {2.0, 9.0, 70.0}) {
      const cv::Mat img = texturedImage(size.width, size.height, sigma, 100 + cases);
      const cv::Mat other = texturedImage(size.width, size.height, 2 * sigma, 200 + cases);
      for (const double factor : {0.0, 3.0, 8.0}) {
        for (const int lowest : {-1, 0, 1, 2, 3, 4, size.height / 2, size.height}) {
          GradientParams p;
          p.auto_factor = factor;
          std::vector<int16_t> top;
          if (lowest >= 0) {
            top.resize(static_cast<size_t>(size.width));
            for (int x = 0; x < size.width; ++x)  // a convex boundary with its highest point at `lowest`
              top[x] = static_cast<int16_t>(std::min(size.height, lowest + (x - size.width / 2) * (x - size.width / 2) / (4 * size.width)));
          }
          const int16_t* t = top.empty() ? nullptr : top.data();
          double thr = 0;
          const std::vector<EdgePixel> ref = referenceEdges(img, p, t, thr);
          g.compute(other, GradientParams());  // leaves another image's Sobel in every row
          g.compute(img, p, t);
          const std::string what = std::to_string(size.width) + "x" + std::to_string(size.height) + " sigma " +
                                   std::to_string(sigma) + " factor " + std::to_string(factor) + " top " + std::to_string(lowest);
          expectSameEdges(g, ref, thr, what.c_str());
          ++cases;
        }
      }
    }
  }
  EXPECT_EQ(cases, 4 * 3 * 3 * 8);
}
