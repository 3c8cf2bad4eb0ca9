#include "frontend/gradient.h"

#include <algorithm>
#include <cmath>
#include <climits>
#include <cstring>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <opencv2/imgproc.hpp>

#include "src/core/error.h"

namespace stereoloc::frontend {

double Segment::length() const { return std::hypot(x2 - x1, y2 - y1); }
double LineFeature::x(double t) const { return rho * std::cos(theta) - t * std::sin(theta); }
double LineFeature::y(double t) const { return rho * std::sin(theta) + t * std::cos(theta); }

std::pair<double, double> lineBoxInterval(double rho, double theta, double xmin, double ymin, double xmax,
                                          double ymax) {
  const double c = std::cos(theta), s = std::sin(theta);
  return pathBoxInterval(rho * c, -s, rho * s, c, xmin, ymin, xmax, ymax);
}

void bgrToLuma(const cv::Mat& bgr, cv::Mat& luma) {
  if (bgr.type() != CV_8UC3) throw Error("bgrToLuma: expected an 8-bit 3-channel BGR image");
  // OpenCV's SIMD conversion, BT.601 weights (the Y channel of the thesis).
  cv::cvtColor(bgr, luma, cv::COLOR_BGR2GRAY);
}

namespace {

// 8 bytes of a bit mask (column x at bit x % 8 of byte x / 8) as a word whose lowest byte is
// the first.
inline uint64_t loadMaskWord(const uint8_t* p) {
  uint64_t word;
  std::memcpy(&word, p, sizeof word);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
  word = __builtin_bswap64(word);
#endif
  return word;
}


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

// The suppression's kept pixels, one array per field (see GradientStage::compute).
// kXY: x | y << 16; kG: gx in the low, gy in the high 16 bits; kD: dy * 65536 + dx.
enum KeptField { kXY, kC, kMm, kMp, kG, kD, kKeptFields };
struct KeptPixels {
  int32_t* field[kKeptFields];
};

// 1 deg bins of [0, 2 pi).
constexpr float kBinsPerRad = 360.0f / 6.28318548f;

// The edge pixel of kept pixel i: sub-pixel offset along (dx, dy) from the parabola through
// the magnitudes sqrt(mm), sqrt(c), sqrt(mp) (its vertex, clamped to half a pixel; none when
// the three are not concave), direction and magnitude.
inline void edgePixelOf(const KeptPixels& k, size_t i, EdgePixel& e) {
  const float fm = std::sqrt(static_cast<float>(k.field[kMm][i])), f0 = std::sqrt(static_cast<float>(k.field[kC][i])),
              fp = std::sqrt(static_cast<float>(k.field[kMp][i]));
  const float den = fm - 2.0f * f0 + fp;
  const float q = 0.5f * (fm - fp) / (den < 0.0f ? den : -1.0f);
  const float s = std::clamp(den < 0.0f ? q : 0.0f, -0.5f, 0.5f);
  const int32_t xy = k.field[kXY][i], d = k.field[kD][i], g = k.field[kG][i];
  const int x = xy & 0xffff, y = xy >> 16;
  const int dx = d & 1, dy = (d - dx) / 65536;
  e.ix = static_cast<int16_t>(x);
  e.iy = static_cast<int16_t>(y);
  e.x = static_cast<float>(x) + s * static_cast<float>(dx);
  e.y = static_cast<float>(y) + s * static_cast<float>(dy);
  // c > 0 (it exceeds a neighbour's): gx, gy are not both 0.
  e.angle = angleOf(static_cast<float>(static_cast<int16_t>(g >> 16)), static_cast<float>(static_cast<int16_t>(g & 0xffff)));
  e.mag = f0;
  const int bin = static_cast<int>(e.angle * kBinsPerRad + 0.5f);
  e.dir_bin = static_cast<uint16_t>(bin >= 360 ? bin - 360 : bin);
}

// edgePixelOf for kept pixels 0 .. n - 1 into out. With SSE2, four at a time: the same single
// precision operations in the same order (no contraction into fused multiply-adds, which
// baseline x86-64 lacks), so the same bits; the quadrant and clamp selections are masks, as
// the scalar code's selections compiled to branches that texture mispredicts.
void edgePixels(const KeptPixels& k, size_t n, EdgePixel* out) {
  size_t i = 0;
#if defined(__SSE2__)
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 zero = _mm_setzero_ps();
  const __m128 half = _mm_set1_ps(0.5f), neg_half = _mm_set1_ps(-0.5f), two = _mm_set1_ps(2.0f);
  const __m128 half_pi = _mm_set1_ps(1.57079637f), pi = _mm_set1_ps(3.14159274f), two_pi = _mm_set1_ps(6.28318548f);
  const __m128i i360 = _mm_set1_epi32(360), i359 = _mm_set1_epi32(359), low16 = _mm_set1_epi32(0xffff);
  auto load = [&](int f) { return _mm_loadu_si128(reinterpret_cast<const __m128i*>(k.field[f] + i)); };
  auto select = [](__m128 mask, __m128 a, __m128 b) { return _mm_or_ps(_mm_and_ps(mask, a), _mm_andnot_ps(mask, b)); };
  alignas(16) float ex[4], ey[4], ang[4], mag[4];
  alignas(16) int32_t bins[4];
  for (; i + 4 <= n; i += 4) {
    const __m128 fm = _mm_sqrt_ps(_mm_cvtepi32_ps(load(kMm)));
    const __m128 f0 = _mm_sqrt_ps(_mm_cvtepi32_ps(load(kC)));
    const __m128 fp = _mm_sqrt_ps(_mm_cvtepi32_ps(load(kMp)));
    const __m128 den = _mm_add_ps(_mm_sub_ps(fm, _mm_mul_ps(two, f0)), fp);
    const __m128 concave = _mm_cmplt_ps(den, zero);
    const __m128 q = _mm_div_ps(_mm_mul_ps(half, _mm_sub_ps(fm, fp)), select(concave, den, _mm_set1_ps(-1.0f)));
    const __m128 s = _mm_max_ps(neg_half, _mm_min_ps(_mm_and_ps(concave, q), half));
    const __m128i xy = load(kXY), d = load(kD), g = load(kG);
    const __m128 xf = _mm_cvtepi32_ps(_mm_and_si128(xy, low16)), yf = _mm_cvtepi32_ps(_mm_srai_epi32(xy, 16));
    const __m128i dx = _mm_and_si128(d, _mm_set1_epi32(1));
    const __m128i dy = _mm_srai_epi32(_mm_sub_epi32(d, dx), 16);
    _mm_store_ps(ex, _mm_add_ps(xf, _mm_mul_ps(s, _mm_cvtepi32_ps(dx))));
    _mm_store_ps(ey, _mm_add_ps(yf, _mm_mul_ps(s, _mm_cvtepi32_ps(dy))));
    _mm_store_ps(mag, f0);
    // angleOf, lane by lane.
    const __m128 gx = _mm_cvtepi32_ps(_mm_srai_epi32(_mm_slli_epi32(g, 16), 16)), gy = _mm_cvtepi32_ps(_mm_srai_epi32(g, 16));
    const __m128 ax = _mm_and_ps(gx, abs_mask), ay = _mm_and_ps(gy, abs_mask);
    const __m128 a = _mm_div_ps(_mm_min_ps(ax, ay), _mm_max_ps(ax, ay)), a2 = _mm_mul_ps(a, a);
    __m128 r = _mm_sub_ps(_mm_mul_ps(_mm_set1_ps(0.0208351f), a2), _mm_set1_ps(0.0851330f));
    r = _mm_add_ps(_mm_mul_ps(r, a2), _mm_set1_ps(0.1801410f));
    r = _mm_sub_ps(_mm_mul_ps(r, a2), _mm_set1_ps(0.3302995f));
    r = _mm_mul_ps(_mm_add_ps(_mm_mul_ps(r, a2), _mm_set1_ps(0.9998660f)), a);
    r = select(_mm_cmpgt_ps(ay, ax), _mm_sub_ps(half_pi, r), r);
    r = select(_mm_cmplt_ps(gx, zero), _mm_sub_ps(pi, r), r);
    r = select(_mm_cmplt_ps(gy, zero), _mm_sub_ps(two_pi, r), r);
    r = select(_mm_cmpge_ps(r, two_pi), _mm_sub_ps(r, two_pi), r);
    _mm_store_ps(ang, r);
    __m128i bin = _mm_cvttps_epi32(_mm_add_ps(_mm_mul_ps(r, _mm_set1_ps(kBinsPerRad)), half));
    bin = _mm_sub_epi32(bin, _mm_and_si128(_mm_cmpgt_epi32(bin, i359), i360));
    _mm_store_si128(reinterpret_cast<__m128i*>(bins), bin);
    for (int j = 0; j < 4; ++j) {
      EdgePixel& e = out[i + static_cast<size_t>(j)];
      e.x = ex[j];
      e.y = ey[j];
      const int32_t xyj = k.field[kXY][i + static_cast<size_t>(j)];
      e.ix = static_cast<int16_t>(xyj & 0xffff);
      e.iy = static_cast<int16_t>(xyj >> 16);
      e.angle = ang[j];
      e.mag = mag[j];
      e.dir_bin = static_cast<uint16_t>(bins[j]);
    }
  }
#endif
  for (; i < n; ++i) edgePixelOf(k, i, out[i]);
}

}  // namespace

float fastAngle(float y, float x) {
  if (std::fabs(x) == 0.0f && std::fabs(y) == 0.0f) return 0.0f;
  return angleOf(y, x);
}

void GradientStage::compute(const cv::Mat& luma, const GradientParams& params, const int16_t* top) {
  if (luma.type() != CV_8UC1) throw Error("GradientStage: expected an 8-bit one-channel image");
  prepare(luma.cols, luma.rows);
  edges_.clear();
  if (w_ < 5 || h_ < 5) return;
  sobel(luma, top);
  // With the automatic threshold, the samples of its median (below): squared magnitudes from
  // gx_, gy_ or, above the computed Sobel, from the luma directly.
  const size_t count = sampleMagnitudes(luma, params.auto_factor > 0);
  setThreshold(params, count);
  columnThresholds(top);
  // The kept pixels' data, one array per field (the vector pass loads four of a field at once);
  // + 4: it reads whole groups of four.
  const size_t stride = static_cast<size_t>(w_) * h_ + 4;
  if (kept_.size() < kKeptFields * stride) kept_.resize(kKeptFields * stride);
  KeptPixels kp;
  for (int f = 0; f < kKeptFields; ++f) kp.field[f] = kept_.data() + static_cast<size_t>(f) * stride;
  const size_t nk = suppress(top, kp.field);
  edges_.resize(nk);
  edgePixels(kp, nk, edges_.data());
}

void GradientStage::prepare(int w, int h) {
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
}

void GradientStage::sobel(const cv::Mat& luma, const int16_t* top) {
  const int w = w_, h = h_;
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
  y_exact_ = y_sobel > 0 ? y_sobel + 1 : 0;
  y_nms_ = std::max(2, y_first + 1);
}

size_t GradientStage::sampleMagnitudes(const cv::Mat& luma, bool automatic) {
  const int w = w_, h = h_, y_exact = y_exact_;
  // Sized once for the image (never shrunk: a growing resize would clear it on every call).
  const size_t max_samples = static_cast<size_t>(std::max(0, (w - 3) / kSampleStep + 1)) *
                             static_cast<size_t>(std::max(0, (h - 3) / kSampleStep + 1));
  if (samples_all_.size() < max_samples) samples_all_.resize(max_samples);
  int32_t* sample = samples_all_.data();
  row_mag2_.resize(static_cast<size_t>(w));
  if (automatic) {
    for (int y = 2; y < h - 2; y += kSampleStep) {
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
  return static_cast<size_t>(sample - samples_all_.data());
}

int64_t GradientStage::medianSquared(size_t count) {
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
  if (b < static_cast<size_t>(kFine)) return static_cast<int64_t>(b);
  samples_.clear();
  for (size_t i = 0; i < count; ++i)
    if (m[i] >= kFine) samples_.push_back(m[i]);
  auto mid = samples_.begin() + static_cast<std::ptrdiff_t>(k - below);
  std::nth_element(samples_.begin(), mid, samples_.end());
  return *mid;
}

void GradientStage::setThreshold(const GradientParams& params, size_t count) {
  int64_t thr2 = int64_t{params.magnitude_threshold} * params.magnitude_threshold;
  if (params.auto_factor > 0 && count > 0) {
    // The median magnitude measures the image's texture and noise (most pixels are floor);
    // every kSampleStep-th pixel of every kSampleStep-th row of the whole image is plenty for
    // a median (see gradient.h).
    const int64_t median2 = medianSquared(count);
    const double auto_thr2 = params.auto_factor * params.auto_factor * static_cast<double>(median2);
    thr2 = std::max(thr2, static_cast<int64_t>(std::ceil(auto_thr2)));
  }
  threshold_ = std::sqrt(static_cast<double>(thr2));
  // A 32-bit threshold keeps the comparisons below in 32-bit lanes; squared Sobel magnitudes
  // of 8-bit images stay below 2^22.
  thr2_32_ = static_cast<int32_t>(std::min<int64_t>(thr2, INT32_MAX));
}

void GradientStage::columnThresholds(const int16_t* top) {
  const int w = w_, h = h_, y_nms = y_nms_;
  const int32_t thr2_32 = thr2_32_;
  // Each column's squared threshold: out of reach in columns 0, 1, w - 2, w - 1 (their
  // neighbours have no gradient), past the image's end (padding to a multiple of 64 columns)
  // and, with a region, above the column's top row; thr2_32 elsewhere. The mask of a row is
  // then one comparison of two 32-bit rows (the test of the 16-bit top in the same loop
  // vectorised badly: a tenth of the stage). With a region, the columns are listed by top row
  // (counting sort) and enabled when the mask reaches it.
  w64_ = static_cast<size_t>((w + 63) / 64 * 64);
  col_thr_.assign(w64_, INT32_MAX);
  auto inner = [&](int x) { return x >= 2 && x < w - 2; };
  if (top) {
    top_start_.assign(static_cast<size_t>(h) + 2, 0);
    for (int x = 0; x < w; ++x) {
      if (!inner(x)) continue;
      col_thr_[x] = top[x] <= y_nms ? thr2_32 : INT32_MAX;
      if (top[x] > y_nms && top[x] < h) ++top_start_[top[x] + 1];
    }
    for (int y = 0; y <= h; ++y) top_start_[y + 1] += top_start_[y];
    top_cols_.resize(static_cast<size_t>(top_start_[h + 1]));
    top_fill_.assign(top_start_.begin(), top_start_.end() - 1);
    for (int x = 0; x < w; ++x)
      if (inner(x) && top[x] > y_nms && top[x] < h) top_cols_[top_fill_[top[x]]++] = x;
  } else {
    for (int x = 2; x < w - 2; ++x) col_thr_[x] = thr2_32;
  }
}

// Squared magnitudes and the mask of row y, right before the suppression first reads the row
// (one row ahead): the three rows it reads stay in the first-level cache (computed in one
// pass over the image, they came from the second level). Most pixels are below the
// threshold, and a branch per pixel in the suppression was half the stage's time.
void GradientStage::rowMagnitudes(int y, uint8_t* bits) {
  const int w = w_;
  const size_t w64 = w64_;
  const int32_t* ct = col_thr_.data();
  const int16_t* gxr = gx_.ptr<int16_t>(y);
  const int16_t* gyr = gy_.ptr<int16_t>(y);
  int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
  int x = 0;
#if defined(__SSE2__)
  // gx^2 + gy^2 is one multiply-add of the interleaved pairs; 8 columns give a byte.
  for (; x + 8 <= w; x += 8) {
    const __m128i gx8 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(gxr + x));
    const __m128i gy8 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(gyr + x));
    const __m128i lo = _mm_unpacklo_epi16(gx8, gy8), hi = _mm_unpackhi_epi16(gx8, gy8);
    const __m128i m_lo = _mm_madd_epi16(lo, lo), m_hi = _mm_madd_epi16(hi, hi);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(m2 + x), m_lo);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(m2 + x + 4), m_hi);
    const __m128i below_lo = _mm_cmpgt_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(ct + x)), m_lo);
    const __m128i below_hi = _mm_cmpgt_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(ct + x + 4)), m_hi);
    const __m128i below16 = _mm_packs_epi32(below_lo, below_hi);
    bits[x / 8] = static_cast<uint8_t>(~_mm_movemask_epi8(_mm_packs_epi16(below16, below16)));
  }
#endif
  std::memset(bits + x / 8, 0, w64 / 8 - static_cast<size_t>(x / 8));
  for (; x < w; ++x) {
    m2[x] = int32_t{gxr[x]} * gxr[x] + int32_t{gyr[x]} * gyr[x];
    bits[x / 8] = static_cast<uint8_t>(bits[x / 8] | (m2[x] >= ct[x]) << (x % 8));
  }
}

// Non-maximum suppression across the edge (4 sectors), sub-pixel offset by a parabola
// through the three magnitudes. Pixels next to the border are skipped (their neighbours
// have no gradient). The mask is read as 64-bit words of one bit per column and only its set
// bits are visited, lowest first, so the kept pixels are in row-major order (a word per 8
// columns ended a loop, mispredicted, at most candidates).
size_t GradientStage::suppress(const int16_t* top, int32_t* const* kept) {
  const int h = h_, y_nms = y_nms_;
  const int32_t thr2_32 = thr2_32_;
  // Two rows' masks of the pixels at the threshold (and in the region), one bit per column:
  // the row the suppression tests and the next.
  above_.assign(2 * w64_ / 8, 0);
  uint8_t* mask_rows[2] = {above_.data(), above_.data() + w64_ / 8};
  size_t nk = 0;
  if (y_nms < h - 2) {
    rowMagnitudes(y_nms - 1, mask_rows[1]);  // its mask is not used
    rowMagnitudes(y_nms, mask_rows[0]);
  }
  for (int y = y_nms; y < h - 2; ++y) {
    if (top)
      for (int j = top_start_[y + 1]; j < top_start_[y + 2]; ++j) col_thr_[top_cols_[j]] = thr2_32;
    const uint8_t* bits = mask_rows[(y - y_nms) & 1];
    rowMagnitudes(y + 1, mask_rows[(y + 1 - y_nms) & 1]);
    nk = suppressRow(y, bits, kept, nk);
  }
  return nk;
}

// The test is integer work without branches: each candidate is written to the kept list, whose
// end advances only when it is a maximum (on carpet half the candidates are not, at random, and
// a branch on it was mispredicted as often). Its index is written the same way (-1 when not
// kept).
size_t GradientStage::suppressRow(int y, const uint8_t* bits, int32_t* const* kept, size_t nk) {
  const int w = w_;
  const int32_t* m2 = mag2_.data() + static_cast<size_t>(y) * w;
  const int16_t* gxr = gx_.ptr<int16_t>(y);
  const int16_t* gyr = gy_.ptr<int16_t>(y);
  int32_t* index_row = index_.data() + static_cast<size_t>(y) * w;
  int32_t* const k_xy = kept[kXY];
  int32_t* const k_c = kept[kC];
  int32_t* const k_mm = kept[kMm];
  int32_t* const k_mp = kept[kMp];
  int32_t* const k_g = kept[kG];
  int32_t* const k_d = kept[kD];
  for (int x0 = 0; x0 < w - 2; x0 += 64) {
    uint64_t word = loadMaskWord(bits + x0 / 8);
    while (word != 0) {
      const int x = x0 + __builtin_ctzll(word);
      word &= word - 1;
      const int32_t c = m2[x];
      const int gxv = gxr[x], gyv = gyr[x];
      const int ax = std::abs(gxv), ay = std::abs(gyv);
      // Sector of the gradient direction, tan(22.5 deg) ~ 106/256: (1, 0), (0, 1) or a diagonal
      // ((1, 1) when gx and gy have the same sign, else (1, -1)).
      const int horizontal = ay * 256 <= ax * 106;
      const int vertical = (1 - horizontal) & (ax * 256 <= ay * 106);
      const int diagonal = 1 - horizontal - vertical;
      const int same = (gxv > 0) == (gyv > 0);
      const int dx = 1 - vertical;
      const int dy = vertical + diagonal * (2 * same - 1);
      const int off = dy * w + dx;
      const int32_t mp = m2[x + off], mm = m2[x - off];
      const int keep = (c > mm) & (c >= mp);
      k_xy[nk] = x | y << 16;
      k_c[nk] = c;
      k_mm[nk] = mm;
      k_mp[nk] = mp;
      k_g[nk] = static_cast<int32_t>(static_cast<uint32_t>(gyv) << 16 | static_cast<uint16_t>(gxv));
      k_d[nk] = dy * 65536 + dx;
      index_row[x] = static_cast<int32_t>(nk) | (keep - 1);  // -1 when not kept
      nk += static_cast<size_t>(keep);
    }
  }
  return nk;
}

}  // namespace stereoloc::frontend
