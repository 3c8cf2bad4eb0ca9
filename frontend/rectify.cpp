#include "frontend/rectify.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "src/core/error.h"

#if defined(__x86_64__) || defined(__i386__)
#include <tmmintrin.h>
#define STEREOLOC_RECTIFY_SSSE3 1
#endif

namespace stereoloc::frontend {
namespace {

// OpenCV's fixed-point maps hold positions in 1/2^INTER_BITS px.
constexpr double kMapStep = 1.0 / (1 << cv::INTER_BITS);

// cv::remap's INTER_LINEAR arithmetic on 8-bit data with 1/32 px maps: weights (32 - fx)(32 - fy)
// ... summing to 1024, rounded to nearest (OpenCV scales the same weights by 32 into 15 bits,
// which gives the same result).
inline uint8_t blend(int p00, int p01, int p10, int p11, int frac) {
  const int fx = frac & (cv::INTER_TAB_SIZE - 1), fy = frac >> cv::INTER_BITS;
  const int top = p00 * (32 - fx) + p01 * fx, bottom = p10 * (32 - fx) + p11 * fx;
  return static_cast<uint8_t>((top * (32 - fy) + bottom * fy + 512) >> 10);
}

// Marks a luma_frac_ entry whose 2x2 neighbourhood leaves the raw image (the fraction index
// uses the low 10 bits).
constexpr uint16_t kBorderFlag = 0x8000;
// Bytes past the raw luma that the vector kernel's 16-byte loads may touch.
constexpr size_t kLumaPadding = 16;

#ifdef STEREOLOC_RECTIFY_SSSE3
// 8 rectified pixels from two 16-byte loads (the top-left neighbours' raw row and the next):
// pshufb gathers the (left, right) neighbour pairs, pmaddubsw weighs them by (32 - fx, fx),
// pmaddwd the two rows by (32 - fy, fy); the rounding and shift are blend()'s.
// A block whose top-left neighbours lie on two raw rows (`crossing`) takes its pairs from the
// next row where `next_row` is set.
template <bool crossing>
__attribute__((target("ssse3"), always_inline)) inline void blendBlock(const uint8_t* top_row, int w, const uint8_t* shuffle,
                                                        const uint8_t* next_row, const int8_t* wx, const int16_t* fy,
                                                        uint8_t* dst) {
  const __m128i s = _mm_load_si128(reinterpret_cast<const __m128i*>(shuffle));
  const __m128i x = _mm_load_si128(reinterpret_cast<const __m128i*>(wx));
  __m128i t = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(top_row)), s);
  __m128i b = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(top_row + w)), s);
  if (crossing) {
    const __m128i n = _mm_load_si128(reinterpret_cast<const __m128i*>(next_row));
    const __m128i b2 = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(top_row + 2 * w)), s);
    t = _mm_or_si128(_mm_and_si128(n, b), _mm_andnot_si128(n, t));
    b = _mm_or_si128(_mm_and_si128(n, b2), _mm_andnot_si128(n, b));
  }
  const __m128i top = _mm_maddubs_epi16(t, x), bottom = _mm_maddubs_epi16(b, x);
  const __m128i y1 = _mm_load_si128(reinterpret_cast<const __m128i*>(fy));
  const __m128i y0 = _mm_sub_epi16(_mm_set1_epi16(32), y1);
  const __m128i half = _mm_set1_epi32(512);
  const __m128i lo = _mm_srai_epi32(
      _mm_add_epi32(_mm_madd_epi16(_mm_unpacklo_epi16(top, bottom), _mm_unpacklo_epi16(y0, y1)), half), 10);
  const __m128i hi = _mm_srai_epi32(
      _mm_add_epi32(_mm_madd_epi16(_mm_unpackhi_epi16(top, bottom), _mm_unpackhi_epi16(y0, y1)), half), 10);
  const __m128i packed = _mm_packs_epi32(lo, hi);
  _mm_storel_epi64(reinterpret_cast<__m128i*>(dst), _mm_packus_epi16(packed, packed));
}

// The vector blocks of rows [row0, row1); the scalar ones are left to the caller.
template <typename Block>
__attribute__((target("ssse3"))) void blendRows(const Block* blocks, int blocks_per_row, int row0, int row1,
                                                const uint8_t* raw, int w, uint8_t* out, size_t out_step) {
  for (int v = row0; v < row1; ++v) {
    const Block* b = blocks + static_cast<size_t>(v) * blocks_per_row;
    uint8_t* dst = out + static_cast<size_t>(v) * out_step;
    for (int j = 0; j < blocks_per_row; ++j) {
      if (b[j].base < 0) continue;
      if (b[j].crossing)
        blendBlock<true>(raw + b[j].base, w, b[j].shuffle, b[j].next_row, b[j].wx, b[j].fy, dst + 8 * j);
      else
        blendBlock<false>(raw + b[j].base, w, b[j].shuffle, b[j].next_row, b[j].wx, b[j].fy, dst + 8 * j);
    }
  }
}
#endif

double bilinearOfMap(const cv::Mat& m, double u, double v) {
  const double uc = std::clamp(u, 0.0, m.cols - 1.0), vc = std::clamp(v, 0.0, m.rows - 1.0);
  const int u0 = std::min(static_cast<int>(uc), m.cols - 2), v0 = std::min(static_cast<int>(vc), m.rows - 2);
  const double a = uc - u0, b = vc - v0;
  const float* r0 = m.ptr<float>(v0);
  const float* r1 = m.ptr<float>(v0 + 1);
  return (1 - b) * ((1 - a) * r0[u0] + a * r0[u0 + 1]) + b * ((1 - a) * r1[u0] + a * r1[u0 + 1]);
}

// s of rectify.h: the RMS singular value of (d raw / d rect)^-1, from central differences of
// the float maps (one-sided at the border).
cv::Mat scaleMap(const cv::Mat& mx, const cv::Mat& my) {
  cv::Mat s(mx.size(), CV_32FC1);
  for (int v = 0; v < mx.rows; ++v) {
    const int v0 = std::max(v - 1, 0), v1 = std::min(v + 1, mx.rows - 1);
    for (int u = 0; u < mx.cols; ++u) {
      const int u0 = std::max(u - 1, 0), u1 = std::min(u + 1, mx.cols - 1);
      const double du = u1 - u0, dv = v1 - v0;
      const double a = (mx.at<float>(v, u1) - mx.at<float>(v, u0)) / du;  // d x_raw / d u
      const double b = (mx.at<float>(v1, u) - mx.at<float>(v0, u)) / dv;  // d x_raw / d v
      const double c = (my.at<float>(v, u1) - my.at<float>(v, u0)) / du;  // d y_raw / d u
      const double d = (my.at<float>(v1, u) - my.at<float>(v0, u)) / dv;  // d y_raw / d v
      const double det = a * d - b * c;
      // The inverse's Frobenius norm is the forward one's divided by |det| (2x2).
      const double frob2 = (a * a + b * b + c * c + d * d) / (det * det);
      s.at<float>(v, u) = std::isfinite(frob2) && det != 0 ? static_cast<float>(std::sqrt(0.5 * frob2)) : 1.0f;
    }
  }
  return s;
}

}  // namespace

Rectifier::Rectifier(const StereoCalibration& c) : size_(c.image_size), source_(c.source) {
  c.validate(c.source.empty() ? "calibration" : c.source);
  const cv::Mat* K[2] = {&c.K1, &c.K2};
  const cv::Mat* D[2] = {&c.D1, &c.D2};
  const cv::Mat* Rr[2] = {&c.R1, &c.R2};
  const cv::Mat* P[2] = {&c.P1, &c.P2};
  for (int i = 0; i < 2; ++i) {
    cv::initUndistortRectifyMap(*K[i], *D[i], *Rr[i], *P[i], size_, CV_32FC1, map_x_[i], map_y_[i]);
    cv::convertMaps(map_x_[i], map_y_[i], map_fixed_[i], map_frac_[i], CV_16SC2, false);
    scale_[i] = scaleMap(map_x_[i], map_y_[i]);
    const int w = size_.width, h = size_.height;
    luma_offset_[i].resize(static_cast<size_t>(w) * h);
    luma_frac_[i].resize(static_cast<size_t>(w) * h);
    for (int v = 0; v < h; ++v) {
      const cv::Vec2s* m = map_fixed_[i].ptr<cv::Vec2s>(v);
      const uint16_t* f = map_frac_[i].ptr<uint16_t>(v);
      for (int u = 0; u < w; ++u) {
        const int k = v * w + u, sx = m[u][0], sy = m[u][1];
        const bool border = sx < 0 || sy < 0 || sx > w - 2 || sy > h - 2;
        luma_offset_[i][k] = std::clamp(sy, 0, h - 2) * w + std::clamp(sx, 0, w - 2);
        luma_frac_[i][k] = static_cast<uint16_t>(f[u] | (border ? kBorderFlag : 0));
      }
    }
    const int blocks_per_row = w / 8;
    blocks_[i].assign(static_cast<size_t>(blocks_per_row) * h, Block());
    for (int v = 0; v < h; ++v) {
      const cv::Vec2s* m = map_fixed_[i].ptr<cv::Vec2s>(v);
      const uint16_t* f = map_frac_[i].ptr<uint16_t>(v);
      for (int j = 0; j < blocks_per_row; ++j) {
        Block& b = blocks_[i][static_cast<size_t>(v) * blocks_per_row + j];
        const int u0 = 8 * j;
        int x_min = w, x_max = -1, y_min = h, y_max = -1;
        bool inside = true;
        for (int q = 0; q < 8; ++q) {
          const int sx = m[u0 + q][0], sy = m[u0 + q][1];
          inside = inside && sx >= 0 && sy >= 0 && sx <= w - 2 && sy <= h - 2;
          x_min = std::min(x_min, sx);
          x_max = std::max(x_max, sx);
          y_min = std::min(y_min, sy);
          y_max = std::max(y_max, sy);
        }
        if (!inside || x_max + 1 - x_min > 15 || y_max - y_min > 1) continue;
        b.base = y_min * w + x_min;
        for (int q = 0; q < 8; ++q) {
          const int fx = f[u0 + q] & (cv::INTER_TAB_SIZE - 1), fy = f[u0 + q] >> cv::INTER_BITS;
          b.shuffle[2 * q] = static_cast<uint8_t>(m[u0 + q][0] - x_min);
          b.shuffle[2 * q + 1] = static_cast<uint8_t>(m[u0 + q][0] - x_min + 1);
          b.next_row[2 * q] = b.next_row[2 * q + 1] = m[u0 + q][1] > y_min ? 0xFF : 0;
          b.wx[2 * q] = static_cast<int8_t>(32 - fx);
          b.wx[2 * q + 1] = static_cast<int8_t>(fx);
          b.fy[q] = static_cast<int16_t>(fy);
        }
        b.crossing = y_max > y_min;
      }
    }
    scalar_blocks_[i].clear();
    for (size_t k = 0; k < blocks_[i].size(); ++k)
      if (blocks_[i][k].base < 0) scalar_blocks_[i].push_back(static_cast<int32_t>(k));
    raw_luma_[i].assign(static_cast<size_t>(w) * h + kLumaPadding, 0);
    // The rows bilinear interpolation reads, clamped as BORDER_REPLICATE clamps them.
    raw_row_min_[i].assign(static_cast<size_t>(size_.height), size_.height - 1);
    raw_row_max_[i].assign(static_cast<size_t>(size_.height), 0);
    for (int v = 0; v < size_.height; ++v) {
      const cv::Vec2s* m = map_fixed_[i].ptr<cv::Vec2s>(v);
      for (int u = 0; u < size_.width; ++u) {
        raw_row_min_[i][v] = std::min(raw_row_min_[i][v], std::clamp<int>(m[u][1], 0, size_.height - 1));
        raw_row_max_[i][v] = std::max(raw_row_max_[i][v], std::clamp<int>(m[u][1] + 1, 0, size_.height - 1));
      }
    }
  }
  setKernel(Kernel::Auto);
}

void Rectifier::setKernel(Kernel kernel) {
#ifdef STEREOLOC_RECTIFY_SSSE3
  vector_kernel_ = kernel == Kernel::Auto && __builtin_cpu_supports("ssse3");
#else
  (void)kernel;
  vector_kernel_ = false;
#endif
}

cv::Mat Rectifier::rawLuma(int camera) { return cv::Mat(size_, CV_8UC1, raw_luma_[camera != 0].data()); }

void Rectifier::checkSize(const cv::Mat& left_raw, const cv::Mat& right_raw) const {
  for (const cv::Mat* m : {&left_raw, &right_raw})
    if (m->size() != size_)
      throw Error((m == &left_raw ? "left" : "right") + std::string(" image: size ") + std::to_string(m->cols) + "x" +
                  std::to_string(m->rows) + " differs from the calibration's image_size " + std::to_string(size_.width) +
                  "x" + std::to_string(size_.height) + (source_.empty() ? "" : " (" + source_ + ")"));
}

void Rectifier::rectify(const cv::Mat& left_raw, const cv::Mat& right_raw) {
  checkSize(left_raw, right_raw);
  raw_[0].m = cv::Mat();
  raw_[1].m = cv::Mat();
  // The two cameras are independent tasks of OpenCV's thread pool (OpenCV runs a nested
  // parallel_for_, the remap's own, serially), so with two threads the pair costs one remap of
  // wall time; each output depends only on its input, whatever the thread count. (One remap of a
  // 320x240 image is a single stripe of OpenCV's own splitting, so without this the pair runs
  // serially.) Replicated borders: a constant border would draw a strong straight edge for the
  // line stages.
  const cv::Mat* in[2] = {&left_raw, &right_raw};
  cv::Mat* out[2] = {&left_.m, &right_.m};
  for (int i = 0; i < 2; ++i) out[i]->create(size_, in[i]->type());  // allocation stays on the caller's thread
  cv::parallel_for_(
      cv::Range(0, 2),
      [&](const cv::Range& r) {
        for (int i = r.start; i < r.end; ++i)
          cv::remap(*in[i], *out[i], map_fixed_[i], map_frac_[i], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      },
      2);
}

void Rectifier::beginPair(const cv::Mat& left_raw_bgr, const cv::Mat& right_raw_bgr, cv::Mat& left_luma) {
  checkSize(left_raw_bgr, right_raw_bgr);
  for (const cv::Mat* m : {&left_raw_bgr, &right_raw_bgr})
    if (m->type() != CV_8UC3) throw Error("Rectifier::beginPair: expected 8-bit BGR images");
  raw_[0].m = left_raw_bgr;
  raw_[1].m = right_raw_bgr;
  left_.m.create(size_, CV_8UC3);
  right_.m.create(size_, CV_8UC3);
  // One channel instead of three: the bilinear remap costs per channel, the conversion is one
  // cheap pass, and bilinear weights and the BT.601 weights commute up to rounding.
  const cv::Mat raw_luma = rawLuma(0);
  cv::cvtColor(left_raw_bgr, raw_luma, cv::COLOR_BGR2GRAY);
  left_luma.create(size_, CV_8UC1);
  // Two row halves as two tasks of OpenCV's pool; every pixel depends only on the input,
  // whatever the thread count.
  const int half = size_.height / 2;
  cv::parallel_for_(
      cv::Range(0, 2),
      [&](const cv::Range& r) {
        for (int k = r.start; k < r.end; ++k) {
          const cv::Range rows = k == 0 ? cv::Range(0, half) : cv::Range(half, size_.height);
          remapLumaRows(0, raw_luma, rows.start, rows.end, left_luma);
        }
      },
      2);
}

void Rectifier::rightLumaRows(int row0, int row1, cv::Mat& right_luma) {
  if (raw_[1].m.empty()) throw Error("Rectifier::rightLumaRows: no pair (call beginPair first)");
  row0 = std::max(row0, 0);
  row1 = std::min(row1, size_.height);
  right_luma.create(size_, CV_8UC1);
  if (row1 <= row0) return;
  int raw0 = size_.height, raw1 = -1;
  for (int v = row0; v < row1; ++v) {
    raw0 = std::min(raw0, raw_row_min_[1][v]);
    raw1 = std::max(raw1, raw_row_max_[1][v]);
  }
  const cv::Mat raw_luma = rawLuma(1);
  cv::Mat raw_rows = raw_luma.rowRange(raw0, raw1 + 1);
  cv::cvtColor(raw_[1].m.rowRange(raw0, raw1 + 1), raw_rows, cv::COLOR_BGR2GRAY);
  remapLumaRows(1, raw_luma, row0, row1, right_luma);
}

void Rectifier::colour(int camera, const cv::Rect& rect, int step) {
  const int i = camera != 0;
  if (raw_[i].m.empty()) throw Error("Rectifier::colour: no pair (call beginPair first)");
  if (step < 1) throw Error("Rectifier::colour: step must be at least 1");
  const cv::Rect r = rect & cv::Rect(cv::Point(0, 0), size_);
  cv::Mat& dst = i == 0 ? left_.m : right_.m;
  dst.create(size_, CV_8UC3);
  if (r.empty()) return;
  if (step == 1) {
    cv::Mat out = dst(r);
    cv::remap(raw_[i].m, out, map_fixed_[i](r), map_frac_[i](r), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    return;
  }
  // Sparse samples: the map entries of the sampled pixels, one small remap, scattered back.
  const int nx = (r.width + step - 1) / step, ny = (r.height + step - 1) / step;
  cv::Mat& gm = grid_map_.m;
  cv::Mat& gf = grid_frac_.m;
  cv::Mat& go = grid_out_.m;
  gm.create(ny, nx, CV_16SC2);
  gf.create(ny, nx, CV_16UC1);
  for (int j = 0; j < ny; ++j) {
    const cv::Vec2s* m = map_fixed_[i].ptr<cv::Vec2s>(r.y + j * step) + r.x;
    const uint16_t* f = map_frac_[i].ptr<uint16_t>(r.y + j * step) + r.x;
    cv::Vec2s* gmr = gm.ptr<cv::Vec2s>(j);
    uint16_t* gfr = gf.ptr<uint16_t>(j);
    for (int k = 0; k < nx; ++k) {
      gmr[k] = m[k * step];
      gfr[k] = f[k * step];
    }
  }
  cv::remap(raw_[i].m, go, gm, gf, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  for (int j = 0; j < ny; ++j) {
    const cv::Vec3b* g = go.ptr<cv::Vec3b>(j);
    cv::Vec3b* d = dst.ptr<cv::Vec3b>(r.y + j * step) + r.x;
    for (int k = 0; k < nx; ++k) d[k * step] = g[k];
  }
}

cv::Mat Rectifier::rectifiedCopy(int camera, const cv::Mat& raw) const {
  if (raw.size() != size_)
    throw Error("image: size " + std::to_string(raw.cols) + "x" + std::to_string(raw.rows) +
                " differs from the calibration's image_size " + std::to_string(size_.width) + "x" +
                std::to_string(size_.height) + (source_.empty() ? "" : " (" + source_ + ")"));
  const int i = camera != 0;
  cv::Mat out;
  cv::remap(raw, out, map_fixed_[i], map_frac_[i], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return out;
}

void Rectifier::remapLumaRows(int camera, const cv::Mat& raw, int row0, int row1, cv::Mat& out) const {
  // raw is this object's continuous, padded raw luma buffer: rows are w bytes apart.
  const int i = camera != 0, w = size_.width;
#ifdef STEREOLOC_RECTIFY_SSSE3
  if (vector_kernel_) {
    const int blocks_per_row = w / 8;
    blendRows(blocks_[i].data(), blocks_per_row, row0, row1, raw.data, w, out.data, out.step);
    const auto& scalar = scalar_blocks_[i];
    for (auto it = std::lower_bound(scalar.begin(), scalar.end(), row0 * blocks_per_row);
         it != scalar.end() && *it < row1 * blocks_per_row; ++it) {
      const int v = *it / blocks_per_row, u0 = 8 * (*it % blocks_per_row);
      remapLumaPixels(i, raw, v, u0, u0 + 8, out.ptr<uint8_t>(v));
    }
    if (w % 8)
      for (int v = row0; v < row1; ++v) remapLumaPixels(i, raw, v, 8 * blocks_per_row, w, out.ptr<uint8_t>(v));
    return;
  }
#endif
  for (int v = row0; v < row1; ++v) remapLumaPixels(i, raw, v, 0, w, out.ptr<uint8_t>(v));
}

void Rectifier::remapLumaPixels(int camera, const cv::Mat& raw, int v, int u0, int u1, uint8_t* dst) const {
  const int i = camera != 0, w = size_.width, h = size_.height;
  const uint8_t* src = raw.data;
  const int32_t* off = luma_offset_[i].data() + static_cast<size_t>(v) * w;
  const uint16_t* frac = luma_frac_[i].data() + static_cast<size_t>(v) * w;
  for (int u = u0; u < u1; ++u) {
    if (!(frac[u] & kBorderFlag)) {
      const uint8_t* p = src + off[u];
      dst[u] = blend(p[0], p[1], p[w], p[w + 1], frac[u]);
      continue;
    }
    // Replicated borders: each neighbour's column and row clamped on its own.
    const cv::Vec2s m = map_fixed_[i].at<cv::Vec2s>(v, u);
    const int x0 = std::clamp<int>(m[0], 0, w - 1), x1 = std::clamp<int>(m[0] + 1, 0, w - 1);
    const int y0 = std::clamp<int>(m[1], 0, h - 1), y1 = std::clamp<int>(m[1] + 1, 0, h - 1);
    const uint8_t* r0 = raw.ptr<uint8_t>(y0);
    const uint8_t* r1 = raw.ptr<uint8_t>(y1);
    dst[u] = blend(r0[x0], r0[x1], r1[x0], r1[x1], frac[u] & ~kBorderFlag);
  }
}

double Rectifier::effectiveSigma(int camera, double u, double v, double sigma_px) const {
  const double s = bilinearOfMap(scale_[camera != 0], u, v);
  return std::sqrt(s * s * sigma_px * sigma_px + kMapStep * kMapStep / 12.0);
}

cv::Point2d Rectifier::rawFromRectified(int camera, double u, double v) const {
  const int i = camera != 0;
  return {bilinearOfMap(map_x_[i], u, v), bilinearOfMap(map_y_[i], u, v)};
}

}  // namespace stereoloc::frontend
