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

namespace {

// 8 bytes of a 0/1 byte mask as a word whose lowest byte is the first.
inline uint64_t loadMaskWord(const uint8_t* p) {
  uint64_t word;
  std::memcpy(&word, p, sizeof word);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
  word = __builtin_bswap64(word);
#endif
  return word;
}

// Index of the lowest nonzero byte of such a word (nonzero).
inline int setByteIndex(uint64_t word) { return __builtin_ctzll(word) >> 3; }

// fastAngle without branches on the quadrant (the same operations, selected): edge pixels of
// texture have random directions, and a mispredicted branch per pixel cost more than the
// polynomial. x, y must not both be 0.
inline float angleOf(float y, float x) {
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float mn = std::min(ax, ay), mx = std::max(ax, ay);
  const float a = mn / mx, s = a * a;
  // Minimax polynomial for atan on [0, 1].
  float r = ((((0.0208351f * s - 0.0851330f) * s + 0.1801410f) * s - 0.3302995f) * s + 0.9998660f) * a;
  r = ay > ax ? 1.57079637f - r : r;
  r = x < 0 ? 3.14159274f - r : r;
  r = y < 0 ? 6.28318548f - r : r;
  return r >= 6.28318548f ? r - 6.28318548f : r;
}

}  // namespace

float fastAngle(float y, float x) {
  if (std::fabs(x) == 0.0f && std::fabs(y) == 0.0f) return 0.0f;
  return angleOf(y, x);
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
    gx_.create(h, w, CV_16S);
    gy_.create(h, w, CV_16S);
  } else {
    for (const EdgePixel& e : edges_) index_[static_cast<size_t>(e.iy) * w + e.ix] = -1;
  }
  edges_.clear();
  if (w < 5 || h < 5) return;

  // With a region of interest, rows above its highest column top give no edge pixels; the
  // suppression below reads one row above the first it tests (y_first), whose Sobel reads one
  // more. The Sobel is computed from one row above that (its own first row sees a reflected
  // border and is never read), in one SIMD pass into the full-size gx_, gy_.
  int y_first = 0, y_sobel = 0;
  if (top) {
    y_first = h;
    for (int x = 0; x < w; ++x) y_first = std::min<int>(y_first, top[x]);
    y_first = std::max(0, y_first - 1);
    y_sobel = std::max(0, y_first - 2);
  }
  if (h - y_sobel >= 3) {
    cv::Mat gxr = gx_.rowRange(y_sobel, h), gyr = gy_.rowRange(y_sobel, h);
    cv::spatialGradient(luma.rowRange(y_sobel, h), gxr, gyr, 3);
  }
  // Rows of gx_, gy_ equal to the whole image's Sobel: y_sobel + 1 on (all with no region).
  const int y_exact = y_sobel > 0 ? y_sobel + 1 : 0;

  // Squared magnitudes of the rows the suppression reads, in a loop the compiler vectorises.
  // With the automatic threshold, the samples of its median (below) are copied out of them
  // on the fly; samples above these rows come from gx_, gy_ or, above the computed Sobel,
  // from the luma directly.
  const bool automatic = params.auto_factor > 0;
  // Sized once for the image (never shrunk: a growing resize would clear it on every call).
  const size_t max_samples = static_cast<size_t>(std::max(0, (w - 3) / kSampleStep + 1)) *
                             static_cast<size_t>(std::max(0, (h - 3) / kSampleStep + 1));
  if (samples_all_.size() < max_samples) samples_all_.resize(max_samples);
  int32_t* sample = samples_all_.data();
  row_mag2_.resize(static_cast<size_t>(w));
  if (automatic) {
    for (int y = 2; y < std::min(y_first, h - 2); y += kSampleStep) {
      if (y >= y_exact) {
        const int16_t* gxr = gx_.ptr<int16_t>(y);
        const int16_t* gyr = gy_.ptr<int16_t>(y);
        for (int x = 2; x < w - 2; x += kSampleStep) *sample++ = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
      } else {
        // The whole row's Sobel in a loop the compiler vectorises, then the samples.
        int32_t* m = row_mag2_.data();
        const uint8_t* a = luma.ptr<uint8_t>(y - 1);
        const uint8_t* b = luma.ptr<uint8_t>(y);
        const uint8_t* c = luma.ptr<uint8_t>(y + 1);
        for (int x = 1; x < w - 1; ++x) {
          const int32_t sx = (a[x + 1] - a[x - 1]) + 2 * (b[x + 1] - b[x - 1]) + (c[x + 1] - c[x - 1]);
          const int32_t sy = (c[x - 1] + 2 * c[x] + c[x + 1]) - (a[x - 1] + 2 * a[x] + a[x + 1]);
          m[x] = sx * sx + sy * sy;
        }
        for (int x = 2; x < w - 2; x += kSampleStep) *sample++ = m[x];
      }
    }
  }
  for (int y = y_first; y < h; ++y) {
    const int16_t* gxr = gx_.ptr<int16_t>(y);
    const int16_t* gyr = gy_.ptr<int16_t>(y);
    int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) m2[x] = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
    if (automatic && y >= 2 && y < h - 2 && y % kSampleStep == 2)
      for (int x = 2; x < w - 2; x += kSampleStep) *sample++ = m2[x];
  }
  const size_t count = static_cast<size_t>(sample - samples_all_.data());

  int64_t thr2 = int64_t{params.magnitude_threshold} * params.magnitude_threshold;
  if (automatic && count > 0) {
    // The median magnitude measures the image's texture and noise (most pixels are floor);
    // every kSampleStep-th pixel of every kSampleStep-th row of the whole image is plenty for
    // a median (see gradient.h).
    // Exact median by a histogram select: squared magnitudes below kFine have a bin each (a
    // carpet's median lies there), the larger ones share one bin, whose samples are selected
    // from only when the median lies among them. The bin index is a minimum (no branch per
    // sample: edge samples above kFine are scattered at random). Consecutive samples go to
    // four interleaved 16-bit tables: a carpet's samples fall into few bins, and increments
    // of one counter in a row wait for each other (one table takes twice the time).
    // nth_element over all samples cost more than the rest of the threshold.
    const int32_t* m = samples_all_.data();
    const size_t k = count / 2;  // the element nth_element would place at size / 2
    size_t below = 0, b = 0;
    constexpr size_t kBins = static_cast<size_t>(kFine) + 1;
    if (count / 4 + 4 <= 65535) {
      hist16_.assign(4 * kBins, 0);
      uint16_t* h0 = hist16_.data();
      uint16_t* h1 = h0 + kBins;
      uint16_t* h2 = h1 + kBins;
      uint16_t* h3 = h2 + kBins;
      size_t j = 0;
      for (; j + 4 <= count; j += 4) {
        ++h0[std::min(m[j], kFine)];
        ++h1[std::min(m[j + 1], kFine)];
        ++h2[std::min(m[j + 2], kFine)];
        ++h3[std::min(m[j + 3], kFine)];
      }
      for (; j < count; ++j) ++h0[std::min(m[j], kFine)];
      for (;; ++b) {
        const size_t c = size_t{h0[b]} + h1[b] + h2[b] + h3[b];
        if (below + c > k) break;
        below += c;
      }
    } else {
      hist_.assign(kBins, 0);
      uint32_t* hist = hist_.data();
      for (size_t j = 0; j < count; ++j) ++hist[std::min(m[j], kFine)];
      while (below + hist[b] <= k) below += hist[b++];
    }
    int64_t median2;
    if (b < static_cast<size_t>(kFine)) {
      median2 = static_cast<int64_t>(b);
    } else {
      samples_.clear();
      for (size_t i = 0; i < count; ++i)
        if (m[i] >= kFine) samples_.push_back(m[i]);
      auto mid = samples_.begin() + static_cast<std::ptrdiff_t>(k - below);
      std::nth_element(samples_.begin(), mid, samples_.end());
      median2 = *mid;
    }
    const double auto_thr2 = params.auto_factor * params.auto_factor * static_cast<double>(median2);
    thr2 = std::max(thr2, static_cast<int64_t>(std::ceil(auto_thr2)));
  }
  threshold_ = std::sqrt(static_cast<double>(thr2));
  // A 32-bit threshold keeps the comparisons below in 32-bit lanes; squared Sobel magnitudes
  // of 8-bit images stay below 2^22.
  const int32_t thr2_32 = static_cast<int32_t>(std::min<int64_t>(thr2, INT32_MAX));
  // One row's byte mask of the pixels at the threshold (and in the region), built in a loop
  // the compiler vectorises right before the row is suppressed: most pixels are below it, and
  // a branch per pixel in the suppression loop was half the stage's time. 8 zero bytes of
  // padding at its end; its columns 0, 1, w - 2, w - 1 stay 0.
  above_.assign(static_cast<size_t>(w) + 8, 0);
  uint8_t* ab = above_.data();
  // With a region, each column's threshold is out of reach above its top row and thr2_32 from
  // it on, so the mask is one comparison of two 32-bit rows as without a region (the test of
  // the 16-bit top in the same loop vectorised badly: a tenth of the stage). The columns are
  // listed by top row (counting sort) and enabled when the suppression reaches it.
  const int y_nms = std::max(2, y_first + 1);
  if (top) {
    col_thr_.resize(static_cast<size_t>(w));
    top_start_.assign(static_cast<size_t>(h) + 2, 0);
    for (int x = 0; x < w; ++x) {
      col_thr_[x] = top[x] <= y_nms ? thr2_32 : INT32_MAX;
      if (top[x] > y_nms && top[x] < h) ++top_start_[top[x] + 1];
    }
    for (int y = 0; y <= h; ++y) top_start_[y + 1] += top_start_[y];
    top_cols_.resize(static_cast<size_t>(top_start_[h + 1]));
    top_fill_.assign(top_start_.begin(), top_start_.end() - 1);
    for (int x = 0; x < w; ++x)
      if (top[x] > y_nms && top[x] < h) top_cols_[top_fill_[top[x]]++] = x;
  }
  const int32_t* ct = col_thr_.data();

  // Non-maximum suppression across the edge (4 sectors), sub-pixel offset by a parabola
  // through the three magnitudes. Pixels next to the border are skipped (their neighbours
  // have no gradient). The mask is read 8 bytes at a time and only its set bytes are visited,
  // lowest first, so the order of edges_ is row-major.
  for (int y = y_nms; y < h - 2; ++y) {
    const int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
    const int16_t* gxr = gx_.ptr<int16_t>(y);
    const int16_t* gyr = gy_.ptr<int16_t>(y);
    if (top) {
      for (int j = top_start_[y]; j < top_start_[y + 1]; ++j) col_thr_[top_cols_[j]] = thr2_32;
      for (int x = 2; x < w - 2; ++x) ab[x] = static_cast<uint8_t>(m2[x] >= ct[x]);
    } else {
      for (int x = 2; x < w - 2; ++x) ab[x] = static_cast<uint8_t>(m2[x] >= thr2_32);
    }
    for (int x0 = 0; x0 < w - 2; x0 += 8) {
      uint64_t word = loadMaskWord(ab + x0);
      while (word != 0) {
        const int x = x0 + setByteIndex(word);
        word &= word - 1;  // each set byte holds the single bit 1
        const int32_t c = m2[x];
        const int gxv = gxr[x], gyv = gyr[x];
        const int ax = std::abs(gxv), ay = std::abs(gyv);
        // Sector of the gradient direction, tan(22.5 deg) ~ 106/256: (1, 0), (0, 1) or a diagonal.
        const bool horizontal = ay * 256 <= ax * 106;
        const bool vertical = !horizontal && ax * 256 <= ay * 106;
        const int dx = vertical ? 0 : 1;
        const int dy = horizontal ? 0 : vertical ? 1 : ((gxv > 0) == (gyv > 0)) ? 1 : -1;
        const int off = dy * w + dx;
        const int32_t mp = m2[x + off], mm = m2[x - off];
        if (!(c > mm && c >= mp)) continue;
        const float fm = std::sqrt(static_cast<float>(mm)), f0 = std::sqrt(static_cast<float>(c)),
                    fp = std::sqrt(static_cast<float>(mp));
        const float den = fm - 2.0f * f0 + fp;
        const float q = 0.5f * (fm - fp) / (den < 0.0f ? den : -1.0f);
        const float s = std::clamp(den < 0.0f ? q : 0.0f, -0.5f, 0.5f);
        EdgePixel e;
        e.ix = static_cast<int16_t>(x);
        e.iy = static_cast<int16_t>(y);
        e.x = static_cast<float>(x) + s * static_cast<float>(dx);
        e.y = static_cast<float>(y) + s * static_cast<float>(dy);
        e.angle = angleOf(static_cast<float>(gyv), static_cast<float>(gxv));  // c > 0: not both 0
        e.mag = f0;
        const int bin = static_cast<int>(e.angle * (360.0f / 6.28318548f) + 0.5f);
        e.dir_bin = static_cast<uint16_t>(bin >= 360 ? bin - 360 : bin);
        index_[static_cast<size_t>(y) * w + x] = static_cast<int32_t>(edges_.size());
        edges_.push_back(e);
      }
    }
  }
}

}  // namespace stereoloc::frontend
