#include "frontend/field_region.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace stereoloc::frontend {
namespace {

// The element std::nth_element would place at v.size() / 2, of floats in [0, vmax]. A counting
// pass over 1024 bins of equal width (the bin a monotone function of the value, so the bins
// order as the values do) finds the bin holding it, through sums over blocks of 32 bins, and
// only that bin's few values are selected from. nth_element's data-dependent branches over
// the few hundred floor samples cost more than the rest of the region.
float medianOf(const std::vector<float>& v, float vmax, std::vector<float>& pick, std::vector<uint16_t>& bins) {
  if (v.empty()) return 0.0f;
  constexpr int kBins = 1024, kBlock = 32;
  const float scale = static_cast<float>(kBins) / vmax;
  // Two interleaved tables: the floor's samples fall into few bins, and increments of one
  // counter in a row wait for each other. Each value's bin is kept for the selection below;
  // only the blocks between the lowest and highest bin are cleared and searched (a floor's
  // values span a few blocks of the 32).
  uint32_t c[2][kBins];
  bins.resize(v.size());
  int lo = kBins - 1, hi = 0;
  for (size_t i = 0; i < v.size(); ++i) {
    const int b = std::min(static_cast<int>(v[i] * scale), kBins - 1);
    bins[i] = static_cast<uint16_t>(b);
    lo = std::min(lo, b);
    hi = std::max(hi, b);
  }
  const int block_lo = lo / kBlock, block_hi = hi / kBlock;
  for (auto& t : c) std::fill(t + block_lo * kBlock, t + (block_hi + 1) * kBlock, 0u);
  for (size_t i = 0; i < v.size(); ++i) ++c[i & 1][bins[i]];
  auto count = [&](int b) { return c[0][b] + c[1][b]; };
  size_t k = v.size() / 2;
  int block = block_lo;
  for (;; ++block) {
    uint32_t sum = 0;
    for (int b = block * kBlock; b < (block + 1) * kBlock; ++b) sum += count(b);
    if (k < sum) break;
    k -= sum;
  }
  int bin = block * kBlock;
  while (k >= count(bin)) k -= count(bin++);
  pick.resize(v.size());
  size_t m = 0;
  for (size_t i = 0; i < v.size(); ++i) {
    pick[m] = v[i];
    m += bins[i] == bin;
  }
  pick.resize(m);
  std::nth_element(pick.begin(), pick.begin() + static_cast<std::ptrdiff_t>(k), pick.end());
  return pick[k];
}

}  // namespace

void FieldRegion::compute(const cv::Mat& bgr, const FieldRegionParams& p) {
  const int w = bgr.cols, h = bgr.rows;
  top_.assign(static_cast<size_t>(std::max(w, 0)), 0);
  restricted_ = false;
  if (!p.enabled || w < p.step_px || h < 3 * p.step_px) return;
  w_ = w;
  h_ = h;
  step_ = p.step_px;
  gw_ = (w + step_ - 1) / step_;
  gh_ = (h + step_ - 1) / step_;
  if (!sampleReference(bgr)) return;
  setFloorTest(p);
  const int gy = scanAllColumns(bgr, p.min_run);
  scanOpenColumns(bgr, gy, p.min_run);
  smoothTops(p.smooth_columns);
  lowerHull();
  if (hull_.empty()) return;
  setTop(p.margin_px);
}

uint8_t FieldRegion::FloorTest::operator()(uint32_t word) const {
  const float b = static_cast<float>(static_cast<int32_t>(word & 255u)),
              g = static_cast<float>(static_cast<int32_t>((word >> 8) & 255u)),
              r = static_cast<float>(static_cast<int32_t>((word >> 16) & 255u));
  const float sum = b + g + r;
  const float l = 0.114f * b + 0.587f * g + 0.299f * r;
  float d = 0.0f;
  d += std::fabs(b - ref_c[0] * sum);
  d += std::fabs(g - ref_c[1] * sum);
  d += std::fabs(r - ref_c[2] * sum);
  return static_cast<uint8_t>((sum >= 1.0f) & (l >= lo) & (l <= hi) & (d <= tol * sum));
}

bool FieldRegion::sampleReference(const cv::Mat& bgr) {
  const int step = step_, gw = gw_, gh = gh_;
  // Floor reference from the bottom third. Every other grid sample of the bottom third is
  // plenty for a median. A black sample (no chromaticity) is written and then overwritten, so
  // the loop has no branch and its divisions overlap.
  const int gy_ref = (2 * gh) / 3;
  const size_t max_ref = static_cast<size_t>((gh - gy_ref + 1) / 2) * static_cast<size_t>((gw + 1) / 2);
  for (auto& c : chroma_) c.resize(max_ref);
  luma_.resize(max_ref);
  size_t n_ref = 0;
  for (int gy = gy_ref; gy < gh; gy += 2) {
    const uint8_t* row = bgr.ptr<uint8_t>(gy * step);
    for (int gx = 0; gx < gw; gx += 2) {
      const uint8_t* px = row + 3 * static_cast<size_t>(gx) * step;
      const float b = px[0], g = px[1], r = px[2];
      const float sum = b + g + r;
      const float safe = sum < 1.0f ? 1.0f : sum;
      chroma_[0][n_ref] = b / safe;
      chroma_[1][n_ref] = g / safe;
      chroma_[2][n_ref] = r / safe;
      luma_[n_ref] = 0.114f * b + 0.587f * g + 0.299f * r;
      n_ref += static_cast<size_t>(sum >= 1.0f);
    }
  }
  for (auto& c : chroma_) c.resize(n_ref);
  luma_.resize(n_ref);
  return !luma_.empty();
}

void FieldRegion::setFloorTest(const FieldRegionParams& p) {
  floor_.ref_c[0] = medianOf(chroma_[0], 1.0f, pick_, bins_);
  floor_.ref_c[1] = medianOf(chroma_[1], 1.0f, pick_, bins_);
  floor_.ref_c[2] = medianOf(chroma_[2], 1.0f, pick_, bins_);
  const float ref_l = medianOf(luma_, 255.0f, pick_, bins_);
  floor_.lo = static_cast<float>(p.luma_low) * ref_l;
  floor_.hi = static_cast<float>(p.luma_high) * ref_l;
  floor_.tol = static_cast<float>(p.chroma_tolerance);
}

int FieldRegion::scanAllColumns(const cv::Mat& bgr, int min_run) {
  const int step = step_, gw = gw_, gh = gh_;
  // Per grid column: the topmost run of min_run floor samples (-1: none). Row by row, so the
  // image is read in memory order, until every column has its run. The floor test of a whole
  // grid row runs in loops without branches that the compiler vectorises (the same float
  // operations in the same order as one sample at a time: the chromaticity test multiplied
  // through by the sum, no division per sample); a branch per test of a row above the
  // boundary, where the colours vary, cost more than the arithmetic.
  grid_top_.assign(static_cast<size_t>(gw), -1);
  run_.assign(static_cast<size_t>(gw), 0);
  bgr_words_.resize(static_cast<size_t>(gw));
  is_floor_.resize(static_cast<size_t>(gw));
  int open = gw;
  int gy = 0;
  for (; gy < gh && 4 * open >= gw; ++gy) open -= scanGridRow(bgr.ptr<uint8_t>(gy * step), gy, min_run);
  return gy;
}

int FieldRegion::scanGridRow(const uint8_t* row, int gy, int min_run) {
  const int w = w_, step = step_, gw = gw_;
  const FloorTest floor_test = floor_;
  // Each sample's b, g, r in the low three bytes of one word: one load per sample where the
  // byte after the pixel lies in its row (all but a sample in the last column).
  uint32_t* pw = bgr_words_.data();
  const int gw_word = std::min(gw, (w - 2) / step + 1);  // columns with gx step + 1 < w
  uint8_t* fl = is_floor_.data();
  for (int gx = 0; gx < gw; ++gx) {
    const uint8_t* px = row + 3 * static_cast<size_t>(gx) * step;
    uint32_t word;
    if (gx < gw_word) {
      std::memcpy(&word, px, sizeof word);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
      word = __builtin_bswap32(word);
#endif
    } else {
      word = px[0] | (uint32_t{px[1]} << 8) | (uint32_t{px[2]} << 16);
    }
    pw[gx] = word;
  }
  for (int gx = 0; gx < gw; ++gx) fl[gx] = floor_test(pw[gx]);
  // Runs and boundaries without a branch per column either: a closed column's run goes on
  // counting but never reopens it.
  const int first = gy - min_run + 1;
  int* run = run_.data();
  int* gt = grid_top_.data();
  int closed = 0;
  for (int gx = 0; gx < gw; ++gx) {
    const int r = fl[gx] ? run[gx] + 1 : 0;
    run[gx] = r;
    const int hit = (gt[gx] < 0) & (r >= min_run);
    gt[gx] = hit ? first : gt[gx];
    closed += hit;
  }
  return closed;
}

void FieldRegion::scanOpenColumns(const cv::Mat& bgr, int gy, int min_run) {
  const int step = step_, gw = gw_, gh = gh_;
  const FloorTest floor_test = floor_;
  // Few columns left open (a robot or the lens border at the bottom): only those are read and
  // tested, from a list that drops each column as it closes.
  open_cols_.clear();
  for (int gx = 0; gx < gw; ++gx)
    if (grid_top_[gx] < 0) open_cols_.push_back(gx);
  for (; gy < gh && !open_cols_.empty(); ++gy) {
    const uint8_t* row = bgr.ptr<uint8_t>(gy * step);
    const int first = gy - min_run + 1;
    size_t kept = 0;
    for (size_t j = 0; j < open_cols_.size(); ++j) {
      const int gx = open_cols_[j];
      const uint8_t* px = row + 3 * static_cast<size_t>(gx) * step;
      const uint32_t word = px[0] | (uint32_t{px[1]} << 8) | (uint32_t{px[2]} << 16);
      const int r = floor_test(word) ? run_[gx] + 1 : 0;
      run_[gx] = r;
      if (r >= min_run) {
        grid_top_[gx] = first;
      } else {
        open_cols_[kept++] = gx;
      }
    }
    open_cols_.resize(kept);
  }
}

void FieldRegion::smoothTops(int smooth_columns) {
  const int gw = gw_;
  // Median over neighbouring columns that have a boundary; a column without floor keeps all.
  smoothed_.assign(static_cast<size_t>(gw), -1);
  for (int gx = 0; gx < gw; ++gx) {
    if (grid_top_[gx] < 0) continue;
    window_.clear();
    // Insertion sort of the few values (the median is the same as nth_element's).
    for (int k = std::max(0, gx - smooth_columns); k <= std::min(gw - 1, gx + smooth_columns); ++k) {
      const int v = grid_top_[k];
      if (v < 0) continue;
      window_.push_back(v);
      for (size_t j = window_.size() - 1; j > 0 && window_[j - 1] > v; --j) std::swap(window_[j - 1], window_[j]);
    }
    smoothed_[gx] = window_[window_.size() / 2];
  }
}

void FieldRegion::lowerHull() {
  const int step = step_, gw = gw_;
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
}

void FieldRegion::setTop(double margin_px) {
  const int w = w_, h = h_, step = step_;
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
    const double row = (1.0 - f) * a.second + f * b.second - step - margin_px;
    // floor(row) from the truncation (std::floor without SSE4.1 is a library call per column).
    const int trunc = static_cast<int>(row);
    const int row_floor = trunc - (row < static_cast<double>(trunc) ? 1 : 0);
    top_[xi] = static_cast<int16_t>(std::clamp(row_floor, 0, h));
    restricted_ = restricted_ || top_[xi] > 0;
  }
}

}  // namespace stereoloc::frontend
