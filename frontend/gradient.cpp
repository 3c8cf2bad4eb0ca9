#include "frontend/gradient.h"

#include <algorithm>
#include <cmath>
#include <climits>
#include <cstring>

#include <opencv2/imgproc.hpp>

#include "src/core/error.h"

namespace stereoloc::frontend {

double Segment::length() const { return std::hypot(x2 - x1, y2 - y1); }
double LineFeature::x(double t) const { return rho * std::cos(theta) - t * std::sin(theta); }
double LineFeature::y(double t) const { return rho * std::sin(theta) + t * std::cos(theta); }

std::pair<double, double> lineBoxInterval(double rho, double theta, double xmin, double ymin, double xmax,
                                          double ymax) {
  const double c = std::cos(theta), s = std::sin(theta);
  double lo = -1e30, hi = 1e30;
  auto clip = [&](double p0, double dp, double pmin, double pmax) {  // pmin <= p0 + t dp <= pmax
    if (std::fabs(dp) < 1e-12) {
      if (p0 < pmin || p0 > pmax) hi = lo - 1;
      return;
    }
    double a = (pmin - p0) / dp, b = (pmax - p0) / dp;
    if (a > b) std::swap(a, b);
    lo = std::max(lo, a);
    hi = std::min(hi, b);
  };
  clip(rho * c, -s, xmin, xmax);
  clip(rho * s, c, ymin, ymax);
  return {lo, hi};
}

void bgrToLuma(const cv::Mat& bgr, cv::Mat& luma) {
  if (bgr.type() != CV_8UC3) throw Error("bgrToLuma: expected an 8-bit 3-channel BGR image");
  // OpenCV's SIMD conversion, BT.601 weights (the Y channel of the thesis).
  cv::cvtColor(bgr, luma, cv::COLOR_BGR2GRAY);
}

float fastAngle(float y, float x) {
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float mn = std::min(ax, ay), mx = std::max(ax, ay);
  if (mx == 0.0f) return 0.0f;
  const float a = mn / mx, s = a * a;
  // Minimax polynomial for atan on [0, 1].
  float r = ((((0.0208351f * s - 0.0851330f) * s + 0.1801410f) * s - 0.3302995f) * s + 0.9998660f) * a;
  if (ay > ax) r = 1.57079637f - r;
  if (x < 0) r = 3.14159274f - r;
  if (y < 0) r = 6.28318548f - r;
  if (r >= 6.28318548f) r -= 6.28318548f;
  return r;
}

void GradientStage::compute(const cv::Mat& luma, const GradientParams& params, const int16_t* top) {
  if (luma.type() != CV_8UC1) throw Error("GradientStage: expected an 8-bit one-channel image");
  const int w = luma.cols, h = luma.rows;
  const size_t n = static_cast<size_t>(w) * h;
  if (w != w_ || h != h_ || index_.size() != n) {
    w_ = w;
    h_ = h;
    mag2_.assign(n, 0);
    index_.assign(n, -1);
    edges_.reserve(n / 8);
  } else {
    for (const EdgePixel& e : edges_) index_[static_cast<size_t>(e.iy) * w + e.ix] = -1;
  }
  edges_.clear();
  if (w < 5 || h < 5) return;

  // 3x3 Sobel in one SIMD pass (the border rows and columns are never used below).
  cv::spatialGradient(luma, gx_, gy_, 3);
  // Squared magnitudes and a byte mask of the pixels at the threshold, both in loops the
  // compiler vectorises: most pixels are below it, and a branch per pixel in the suppression
  // loop below was half the stage's time. The mask has 8 zero bytes of padding per row end.
  // With a region of interest, rows above its highest column top give no edge pixels; the
  // suppression below reads one row above the first it tests.
  int y_first = 0;
  if (top) {
    y_first = h;
    for (int x = 0; x < w; ++x) y_first = std::min<int>(y_first, top[x]);
    y_first = std::max(0, y_first - 1);
  }
  for (int y = y_first; y < h; ++y) {
    const int16_t* gxr = gx_.ptr<int16_t>(y);
    const int16_t* gyr = gy_.ptr<int16_t>(y);
    int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) m2[x] = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
  }
  int64_t thr2 = int64_t{params.magnitude_threshold} * params.magnitude_threshold;
  if (params.auto_factor > 0) {
    // The median magnitude measures the image's texture and noise (most pixels are floor);
    // every 3rd pixel of every 3rd row of the whole image is plenty for a median.
    // Exact median by a two-level histogram select: squared magnitudes below kFine have a bin
    // each (a carpet's median lies there), larger ones share bins of 2^kShift values and only
    // the bin holding the median is sorted. nth_element over all samples cost more than the
    // rest of the threshold.
    hist_.assign(kFine + (kMaxMag2 >> kShift) + 1, 0);
    size_t count = 0;
    for (int y = 2; y < h - 2; y += 3) {
      const int16_t* gxr = gx_.ptr<int16_t>(y);
      const int16_t* gyr = gy_.ptr<int16_t>(y);
      for (int x = 2; x < w - 2; x += 3) {
        const int32_t m2 = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
        ++hist_[m2 < kFine ? m2 : kFine + (m2 >> kShift)];
        ++count;
      }
    }
    if (count > 0) {
      const size_t k = count / 2;  // the element nth_element would place at size / 2
      size_t below = 0, bin = 0;
      while (below + hist_[bin] <= k) below += hist_[bin++];
      int64_t median2;
      if (bin < static_cast<size_t>(kFine)) {
        median2 = static_cast<int64_t>(bin);
      } else {
        samples_.clear();
        const int32_t lo = static_cast<int32_t>(bin - kFine) << kShift;
        for (int y = 2; y < h - 2; y += 3) {
          const int16_t* gxr = gx_.ptr<int16_t>(y);
          const int16_t* gyr = gy_.ptr<int16_t>(y);
          for (int x = 2; x < w - 2; x += 3) {
            const int32_t m2 = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
            if (m2 >= kFine && (m2 >> kShift) == (lo >> kShift)) samples_.push_back(m2);
          }
        }
        auto mid = samples_.begin() + static_cast<std::ptrdiff_t>(k - below);
        std::nth_element(samples_.begin(), mid, samples_.end());
        median2 = *mid;
      }
      const double auto_thr2 = params.auto_factor * params.auto_factor * static_cast<double>(median2);
      thr2 = std::max(thr2, static_cast<int64_t>(std::ceil(auto_thr2)));
    }
  }
  threshold_ = std::sqrt(static_cast<double>(thr2));
  // A 32-bit threshold keeps the comparison below in 32-bit lanes (vectorised); squared Sobel
  // magnitudes of 8-bit images stay below 2^22.
  const int32_t thr2_32 = static_cast<int32_t>(std::min<int64_t>(thr2, INT32_MAX));
  const size_t stride = static_cast<size_t>(w) + 8;
  if (above_.size() != stride * h) above_.assign(stride * h, 0);  // only [2, w - 2) is written
  for (int y = 0; y < h; ++y) {
    const int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
    uint8_t* ab = above_.data() + static_cast<size_t>(y) * stride;
    if (y < y_first + 1) {
      std::fill(ab + 2, ab + std::max(2, w - 2), uint8_t{0});
      continue;
    }
    for (int x = 2; x < w - 2; ++x) ab[x] = static_cast<uint8_t>(m2[x] >= thr2_32);
    if (top)
      for (int x = 2; x < w - 2; ++x) ab[x] = static_cast<uint8_t>(ab[x] & (y >= top[x]));
  }

  // Non-maximum suppression across the edge (4 sectors), sub-pixel offset by a parabola
  // through the three magnitudes. Pixels next to the border are skipped (their neighbours
  // have no gradient).
  for (int y = std::max(2, y_first + 1); y < h - 2; ++y) {
    const int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
    const int16_t* gxr = gx_.ptr<int16_t>(y);
    const int16_t* gyr = gy_.ptr<int16_t>(y);
    const uint8_t* ab = above_.data() + static_cast<size_t>(y) * stride;
    for (int x = 2; x < w - 2; ++x) {
      // Skip 8 pixels below the threshold at once (left to right, so the order of edges_ is
      // unchanged).
      if ((x & 7) == 0) {
        uint64_t word;
        std::memcpy(&word, ab + x, sizeof word);
        if (word == 0) {
          x += 7;
          continue;
        }
      }
      if (!ab[x]) continue;
      const int32_t c = m2[x];
      const int gxv = gxr[x], gyv = gyr[x];
      const int ax = std::abs(gxv), ay = std::abs(gyv);
      int dx, dy;
      // tan(22.5 deg) ~ 106/256
      if (ay * 256 <= ax * 106) {
        dx = 1;
        dy = 0;
      } else if (ax * 256 <= ay * 106) {
        dx = 0;
        dy = 1;
      } else {
        dx = 1;
        dy = ((gxv > 0) == (gyv > 0)) ? 1 : -1;
      }
      const int off = dy * w + dx;
      const int32_t mp = m2[x + off], mm = m2[x - off];
      if (!(c > mm && c >= mp)) continue;
      const float fm = std::sqrt(static_cast<float>(mm)), f0 = std::sqrt(static_cast<float>(c)),
                  fp = std::sqrt(static_cast<float>(mp));
      const float den = fm - 2.0f * f0 + fp;
      float s = den < 0.0f ? 0.5f * (fm - fp) / den : 0.0f;
      s = std::clamp(s, -0.5f, 0.5f);
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
      index_[static_cast<size_t>(y) * w + x] = static_cast<int32_t>(edges_.size());
      edges_.push_back(e);
    }
  }
}

}  // namespace stereoloc::frontend
