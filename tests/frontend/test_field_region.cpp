// The region of interest below the field boundary (frontend/field_region.h): found from the
// floor's colour, bridged under objects standing on the boundary, off by default.
#include "frontend/field_region.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>
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


// The region as specified, one grid sample at a time with nth_element medians (the stage's
// radix select and row-wise floor test must give exactly its column tops).
float referenceMedian(std::vector<float>& v) {
  if (v.empty()) return 0.0f;
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

std::vector<int16_t> referenceTop(const cv::Mat& bgr, const FieldRegionParams& p, bool& restricted_) {
  std::vector<int16_t> top_;
  std::vector<int> grid_top_, run_, smoothed_, window_;
  std::vector<std::pair<double, double>> hull_;
  std::vector<float> chroma_[3], luma_;
  const int w = bgr.cols, h = bgr.rows;
  top_.assign(static_cast<size_t>(std::max(w, 0)), 0);
  restricted_ = false;
  if (!p.enabled || w < p.step_px || h < 3 * p.step_px) return top_;
  const int step = p.step_px;
  const int gw = (w + step - 1) / step, gh = (h + step - 1) / step;
  // Floor reference from the bottom third.
  for (auto& c : chroma_) c.clear();
  luma_.clear();
  // Every other grid sample of the bottom third is plenty for a median.
  for (int gy = (2 * gh) / 3; gy < gh; gy += 2) {
    const cv::Vec3b* row = bgr.ptr<cv::Vec3b>(gy * step);
    for (int gx = 0; gx < gw; gx += 2) {
      const cv::Vec3b& px = row[gx * step];
      const float sum = static_cast<float>(px[0]) + px[1] + px[2];
      if (sum < 1.0f) continue;
      for (int c = 0; c < 3; ++c) chroma_[c].push_back(px[c] / sum);
      luma_.push_back(0.114f * px[0] + 0.587f * px[1] + 0.299f * px[2]);
    }
  }
  if (luma_.empty()) return top_;
  const float ref_c[3] = {referenceMedian(chroma_[0]), referenceMedian(chroma_[1]), referenceMedian(chroma_[2])};
  const float ref_l = referenceMedian(luma_);
  const float lo = static_cast<float>(p.luma_low) * ref_l, hi = static_cast<float>(p.luma_high) * ref_l;
  const float tol = static_cast<float>(p.chroma_tolerance);
  // The chromaticity test multiplied through by the sum (no division per sample).
  auto floor = [&](const cv::Vec3b& px) {
    const float sum = static_cast<float>(px[0]) + px[1] + px[2];
    if (sum < 1.0f) return false;
    const float l = 0.114f * px[0] + 0.587f * px[1] + 0.299f * px[2];
    if (l < lo || l > hi) return false;
    float d = 0.0f;
    for (int c = 0; c < 3; ++c) d += std::fabs(px[c] - ref_c[c] * sum);
    return d <= tol * sum;
  };
  // Per grid column: the topmost run of min_run floor samples (-1: none). Row by row, so the
  // image is read in memory order, until every column has its run.
  grid_top_.assign(static_cast<size_t>(gw), -1);
  run_.assign(static_cast<size_t>(gw), 0);
  int open = gw;
  for (int gy = 0; gy < gh && open > 0; ++gy) {
    const cv::Vec3b* row = bgr.ptr<cv::Vec3b>(gy * step);
    for (int gx = 0; gx < gw; ++gx) {
      if (grid_top_[gx] >= 0) continue;
      run_[gx] = floor(row[gx * step]) ? run_[gx] + 1 : 0;
      if (run_[gx] >= p.min_run) {
        grid_top_[gx] = gy - p.min_run + 1;
        --open;
      }
    }
  }
  // Median over neighbouring columns that have a boundary; a column without floor keeps all.
  smoothed_.assign(static_cast<size_t>(gw), -1);
  for (int gx = 0; gx < gw; ++gx) {
    if (grid_top_[gx] < 0) continue;
    window_.clear();
    for (int k = std::max(0, gx - p.smooth_columns); k <= std::min(gw - 1, gx + p.smooth_columns); ++k)
      if (grid_top_[k] >= 0) window_.push_back(grid_top_[k]);
    std::nth_element(window_.begin(), window_.begin() + static_cast<std::ptrdiff_t>(window_.size() / 2), window_.end());
    smoothed_[gx] = window_[window_.size() / 2];
  }
  // The floor is convex and so is its image under a pinhole: the region below the boundary is
  // convex, its boundary row a convex function of the column. Its greatest convex minorant (the
  // lower hull of the column tops, in row numbers) bridges the dips under robots, people and
  // darker patches of carpet that hide or mimic the boundary.
  hull_.clear();
  for (int gx = 0; gx < gw; ++gx) {
    if (smoothed_[gx] < 0) continue;
    const double x = static_cast<double>(gx) * step, y = static_cast<double>(smoothed_[gx]) * step;
    while (hull_.size() >= 2) {
      const auto& a = hull_[hull_.size() - 2];
      const auto& b = hull_.back();
      // Drop b when it lies on or above (in rows: at or below) the chord from a to (x, y).
      if ((b.first - a.first) * (y - a.second) - (b.second - a.second) * (x - a.first) <= 0.0) {
        hull_.pop_back();
      } else {
        break;
      }
    }
    hull_.emplace_back(x, y);
  }
  if (hull_.empty()) return top_;
  // Image columns: on the hull, raised by one grid step (the boundary lies between the last
  // non-floor sample and the first floor one) and by the margin. Columns within a grid step
  // beyond the hull's ends take its end value; the others keep the whole column.
  size_t k = 0;
  for (int xi = 0; xi < w; ++xi) {
    if (xi < hull_.front().first - step || xi > hull_.back().first + step) continue;
    const double x = std::clamp(static_cast<double>(xi), hull_.front().first, hull_.back().first);
    while (k + 1 < hull_.size() && hull_[k + 1].first < x) ++k;
    const auto& a = hull_[k];
    const auto& b = k + 1 < hull_.size() ? hull_[k + 1] : hull_[k];
    const double f = b.first > a.first ? (x - a.first) / (b.first - a.first) : 0.0;
    const double row = (1.0 - f) * a.second + f * b.second - step - p.margin_px;
    top_[xi] = static_cast<int16_t>(std::clamp(static_cast<int>(std::floor(row)), 0, h));
    restricted_ = restricted_ || top_[xi] > 0;
  }
  return top_;
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


// Scenes of the kind the real set shows and pure noise, with every grid step, tolerance and
// run length the parameters allow in practice: the column tops equal the reference's.
TEST(FieldRegion, EqualsTheSampleBySampleReference) {
  FieldRegion region;
  cv::RNG rng(17);
  int cases = 0;
  for (int i = 0; i < 12; ++i) {
    cv::Mat img = fieldImage();
    cv::Mat noise(img.size(), CV_8UC3);
    rng.fill(noise, cv::RNG::UNIFORM, 0, 10 + 20 * (i % 4));
    img += noise;
    if (i % 3 == 1) img(cv::Rect(0, 180, 60, 60)).setTo(cv::Scalar(0, 0, 0));  // a dark lens corner
    if (i % 3 == 2) rng.fill(img, cv::RNG::UNIFORM, 0, 256);
    for (const double tol : {0.03, 0.06, 0.15, 0.6}) {
      for (const int step : {1, 3, 4, 7}) {
        for (const int run : {1, 2, 4}) {
          FieldRegionParams p;
          p.enabled = true;
          p.chroma_tolerance = tol;
          p.step_px = step;
          p.min_run = run;
          bool restricted = false;
          const std::vector<int16_t> ref = referenceTop(img, p, restricted);
          region.compute(img, p);
          EXPECT_EQ(region.top(), ref) << "image " << i << " tolerance " << tol << " step " << step << " run " << run;
          EXPECT_EQ(region.restricted(), restricted);
          cases += restricted ? 1 : 0;
        }
      }
    }
  }
  EXPECT_GT(cases, 100);  // most cases find a boundary
}

}  // namespace
}  // namespace stereoloc::frontend
