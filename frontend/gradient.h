#pragma once
// Stage 1: luma, integer Sobel, non-maximum suppression with a sub-pixel edge position
// (thesis 3.3.1 and 3.4 use the Sobel operator on the Y channel).
#include <opencv2/core/mat.hpp>
#include <vector>

#include "frontend/features.h"

namespace stereoloc::frontend {

struct GradientParams {
  int magnitude_threshold = 48;  // Sobel magnitude (luma step x 4) an edge pixel must reach
  // Automatic threshold from the image: an edge pixel must also reach auto_factor times the
  // image's median Sobel magnitude (its texture and noise level: carpet, JPEG blocks, sensor
  // noise). 0: off. Rendered images have medians of 4.5-9 (bench_frontend pairs), so 5 leaves
  // their threshold at magnitude_threshold; photographs of carpeted fields have 12-18.
  double auto_factor = 0.0;
};

// Luma (ITU-R BT.601 weights) of an 8-bit BGR image into a reused buffer.
void bgrToLuma(const cv::Mat& bgr, cv::Mat& luma);

// Reusable gradient stage: holds all buffers, so repeated calls on same-size images allocate nothing.
class GradientStage {
 public:
  // The automatic threshold's median is taken over every kSampleStep-th pixel of every
  // kSampleStep-th row (from pixel (2, 2)): 2100 samples in 320x240. On the 64 photographs
  // of data/real, every 3rd pixel of every 3rd row (8400 samples) gives thresholds within
  // 1.7 % of these on average (6 % at most) and the same bench_frontend figures, at four
  // times the histogram's time (5.7 against 1.4 us per photograph).
  static constexpr int kSampleStep = 6;

  // luma must be CV_8UC1. Fills edges() and the per-pixel index map. top (optional, one entry
  // per column): pixels above row top[x] give no edge pixels (frontend/field_region.h).
  void compute(const cv::Mat& luma, const GradientParams& params, const int16_t* top = nullptr);

  const std::vector<EdgePixel>& edges() const { return edges_; }
  int width() const { return w_; }
  int height() const { return h_; }
  // Index into edges() of the edge pixel at integer (x, y), or -1. (x, y) must be inside.
  int edgeAt(int x, int y) const { return index_[static_cast<size_t>(y) * w_ + x]; }
  // The magnitude threshold used by the last compute() (magnitude_threshold or the automatic one).
  double threshold() const { return threshold_; }
  // CV_16S Sobel x and y. With a region (top), rows more than 3 above its highest column top
  // are not computed (they hold earlier images' values).
  const cv::Mat& gx() const { return gx_; }
  const cv::Mat& gy() const { return gy_; }

 private:
  // The phases of compute(), in order; each reads the per-image state the earlier ones set.
  // Declared inline and defined in gradient.cpp, their only user, so that the compiler may
  // inline them (position-independent code does not inline other global functions):
  // rowMagnitudes and suppressRow run once per row.
  // Sizes the buffers for a w x h image (or clears the last image's index entries).
  inline void prepare(int w, int h);
  // Sobel of the rows the suppression reads; sets y_exact_ and y_nms_.
  inline void sobel(const cv::Mat& luma, const int16_t* top);
  // The automatic threshold's samples into samples_all_ (none when !automatic); their count.
  inline size_t sampleMagnitudes(const cv::Mat& luma, bool automatic);
  // The median of the first count samples' squared magnitudes.
  inline int64_t medianSquared(size_t count);
  // threshold_ and thr2_32_ from the parameters and, with count > 0 samples, their median.
  inline void setThreshold(const GradientParams& params, size_t count);
  // col_thr_ and, with a region, the columns by top row (top_start_, top_cols_).
  inline void columnThresholds(const int16_t* top);
  // Squared magnitudes of row y into mag2_, and its mask of pixels at the threshold into bits.
  inline void rowMagnitudes(int y, uint8_t* bits);
  // Non-maximum suppression of rows y_nms_ .. h - 3 into the kept arrays (one per field) and
  // index_; the number kept.
  inline size_t suppress(const int16_t* top, int32_t* const* kept);
  // The suppression of row y (its mask bits), appending to the kept arrays after nk; the new count.
  inline size_t suppressRow(int y, const uint8_t* bits, int32_t* const* kept, size_t nk);

  int w_ = 0, h_ = 0;
  // Per image: rows of gx_, gy_ equal to the whole image's Sobel start at y_exact_; the
  // suppression tests rows y_nms_ on; masks are w64_ columns wide; thr2_32_ is the squared
  // threshold as a 32-bit lane value.
  int y_exact_ = 0, y_nms_ = 2;
  size_t w64_ = 0;
  int32_t thr2_32_ = 0;
  cv::Mat gx_, gy_;
  std::vector<int32_t> mag2_;
  // Histogram of sampled squared magnitudes for the automatic threshold: exact bins below
  // kFine, one bin for all above.
  static constexpr int32_t kFine = 4096;
  std::vector<uint32_t> hist_;
  std::vector<uint16_t> hist16_;  // four such histograms, when no bin can exceed 16 bits
  std::vector<int32_t> samples_all_;  // squared magnitudes of the median's samples
  std::vector<int32_t> row_mag2_;     // one row's, above the computed Sobel
  std::vector<int32_t> samples_;  // the samples at or above kFine, when the median is one
  double threshold_ = 0.0;
  std::vector<int32_t> index_;
  std::vector<int32_t> kept_;   // the suppression's candidates, one array per field
  // Two rows' masks, one bit per column (padded to 64): magnitude at the column's threshold.
  std::vector<uint8_t> above_;
  // Each column's squared threshold (INT32_MAX in the two columns at either border, in the
  // padding and, with a region, above the column's top row), and with a region the columns
  // whose top row the masks reach, by row (offsets top_start_).
  std::vector<int32_t> col_thr_;
  std::vector<int> top_start_, top_cols_, top_fill_;
  std::vector<EdgePixel> edges_;
};

// atan2 approximation (error < 2e-5 rad) returning [0, 2 pi).
float fastAngle(float y, float x);

}  // namespace stereoloc::frontend
