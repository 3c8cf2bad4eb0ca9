// The segment extractor's branch-free pool scans against the pixel-by-pixel reference: the
// same segments, bit for bit, and the same pixels, on the photographs of data/real (carpet
// texture fills the bins of every direction) and on a synthetic image with lines of many
// directions over noise.
#include <gtest/gtest.h>

#include <cstring>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>

#include "frontend/field_region.h"
#include "frontend/frontend.h"
#include "frontend/gbht.h"
#include "frontend/gradient.h"
#include "frontend/peaks.h"
#include "frontend/segments.h"
#include "src/io/image_file.h"
#include "test_util.h"

namespace stereoloc::frontend {
namespace {

using test::kRealImagesDir;

bool sameBits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// Runs the stages up to the segments on `bgr` and extracts them with both pool scans.
// Returns the number of segments; fails the test on any difference.
size_t compareOn(const cv::Mat& bgr, const FrontendParams& p, const std::string& what) {
  cv::Mat luma;
  bgrToLuma(bgr, luma);
  FieldRegion region;
  region.compute(bgr, p.field);
  GradientStage grad;
  grad.compute(luma, p.gradient, region.restricted() ? region.top().data() : nullptr);
  HoughAccumulator acc;
  acc.configure(luma.cols, luma.rows, p.hough);
  acc.vote(grad.edges(), {});
  std::vector<HoughPeak> peaks;
  detectPeaks(acc, p.peaks, peaks);
  SegmentExtractor fast, linear;
  linear.setReferencePools(true);
  std::vector<uint8_t> used_fast, used_linear;
  std::vector<Segment> seg_fast, seg_linear;
  fast.extract(grad.edges(), peaks, p.hough.rho_step_px, p.segments, used_fast, seg_fast, luma.cols, luma.rows);
  linear.extract(grad.edges(), peaks, p.hough.rho_step_px, p.segments, used_linear, seg_linear, luma.cols, luma.rows);
  EXPECT_EQ(used_fast, used_linear) << what;
  EXPECT_EQ(seg_fast.size(), seg_linear.size()) << what;
  if (seg_fast.size() != seg_linear.size()) return 0;
  for (size_t k = 0; k < seg_fast.size(); ++k) {
    const Segment &a = seg_fast[k], &b = seg_linear[k];
    EXPECT_TRUE(sameBits(a.theta, b.theta) && sameBits(a.rho, b.rho) && sameBits(a.x1, b.x1) && sameBits(a.y1, b.y1) &&
                sameBits(a.x2, b.x2) && sameBits(a.y2, b.y2) && sameBits(a.rms, b.rms))
        << what << ", segment " << k;
    EXPECT_EQ(std::vector<int>(fast.pixelsBegin(k), fast.pixelsEnd(k)),
              std::vector<int>(linear.pixelsBegin(k), linear.pixelsEnd(k)))
        << what << ", segment " << k;
  }
  return seg_fast.size();
}

TEST(SegmentPools, BranchFreeScanEqualsLinearScanOnPhotographs) {
  const FrontendParams p = FrontendParams::load(kRealImagesDir + "/frontend.yaml");
  std::vector<cv::String> files;
  cv::glob(kRealImagesDir + "/images/*.jpg", files);
  ASSERT_GE(files.size(), 64u);
  size_t total = 0;
  for (const cv::String& f : files) {
    const cv::Mat img = readImageFile(f, ImageColour::Bgr).image;
    ASSERT_FALSE(img.empty()) << f;
    total += compareOn(img, p, f);
  }
  EXPECT_GT(total, 5 * files.size());  // the comparison covers real segments
}

TEST(SegmentPools, BranchFreeScanEqualsLinearScanOnLinesOverNoise) {
  // Bright bars of 36 directions through the image over strong noise: pools of every bin, with
  // peaks whose direction lies at every offset from the bins' centres.
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(60, 110, 60));
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 14.0);
  for (int k = 0; k < 36; ++k) {
    const double a = k * 5.3 * CV_PI / 180.0, r = 20 + 7 * k;
    const cv::Point2d c(160 + 0.3 * r * std::cos(a), 120 + 0.25 * r * std::sin(a));
    const cv::Point2d d(std::cos(a + CV_PI / 2), std::sin(a + CV_PI / 2));
    cv::line(img, c - 70 * d, c + 70 * d, cv::Scalar(235, 235, 235), 2 + k % 3, cv::LINE_AA);
  }
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        uint8_t& v = img.at<cv::Vec3b>(y, x)[ch];
        v = cv::saturate_cast<uint8_t>(v + noise(rng));
      }
  FrontendParams p;
  p.gradient.auto_factor = 4.0;
  EXPECT_GT(compareOn(img, p, "synthetic"), 20u);
}

}  // namespace
}  // namespace stereoloc::frontend
