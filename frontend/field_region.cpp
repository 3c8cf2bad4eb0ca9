#include "frontend/field_region.h"

#include <algorithm>
#include <cmath>

namespace stereoloc::frontend {
namespace {

float medianOf(std::vector<float>& v) {
  if (v.empty()) return 0.0f;
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

}  // namespace

void FieldRegion::compute(const cv::Mat& bgr, const FieldRegionParams& p) {
  const int w = bgr.cols, h = bgr.rows;
  top_.assign(static_cast<size_t>(std::max(w, 0)), 0);
  restricted_ = false;
  if (!p.enabled || w < p.step_px || h < 3 * p.step_px) return;
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
  if (luma_.empty()) return;
  const float ref_c[3] = {medianOf(chroma_[0]), medianOf(chroma_[1]), medianOf(chroma_[2])};
  const float ref_l = medianOf(luma_);
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
  if (hull_.empty()) return;
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
}

}  // namespace stereoloc::frontend
