#pragma once
// Optional region of interest: the part of the image below the field boundary, found from the
// floor's colour. Photographs of a RoboCup field show stands, people, walls and banners above
// the far edge of the carpet, and their edge pixels cost most of the line stages' time and give
// phantom lines; no field marking lies there. Off by default: on the MiroSot field the walls
// and goals above the floor carry landmarks (wall feet, goal corners) and the carpet is dark.
//
// On a grid of every step_px-th pixel: the floor's chromaticity (b, g, r) / (b + g + r) and
// luma are the medians of every other grid sample in the bottom third of the image (the floor fills
// most of it); a sample is floor when its chromaticity lies within chroma_tolerance (L1) of the
// floor's and its luma within [luma_low, luma_high] times the floor's. A marking is white,
// i.e. not floor, but it lies on the floor: the boundary of a grid column is its topmost run
// of min_run floor samples, so markings, robots and balls below it do not matter. Columns
// without such a run keep the whole column. The column tops are smoothed by a median over
// 2 smooth_columns + 1 grid columns; the boundary is their lower convex hull (in rows: the
// floor's image is convex, so robots and people standing on the boundary do not cut into it),
// raised by margin_px (far markings lie right below the boundary).
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <utility>
#include <vector>

namespace stereoloc::frontend {

struct FieldRegionParams {
  bool enabled = false;
  int step_px = 4;                // grid spacing, px
  double chroma_tolerance = 0.06; // L1 distance of chromaticities (each in [0, 1], summing to 1)
  double luma_low = 0.5;          // floor luma range relative to the floor's median luma
  double luma_high = 1.8;
  int min_run = 2;                // grid samples of floor in a row that make a column's boundary
  int smooth_columns = 2;         // median over 2 n + 1 grid columns
  double margin_px = 6.0;         // the region starts this far above the boundary
};

class FieldRegion {
 public:
  // bgr: CV_8UC3. After it, top(x) is the first image row of the region in column x (0 when
  // disabled: the whole image).
  void compute(const cv::Mat& bgr, const FieldRegionParams& params);
  const std::vector<int16_t>& top() const { return top_; }
  bool restricted() const { return restricted_; }

 private:
  // The floor test of one grid sample, b, g, r in the low three bytes of word: the
  // chromaticity test multiplied through by the sum, no division per sample.
  struct FloorTest {
    float ref_c[3] = {0.0f, 0.0f, 0.0f};  // the floor's chromaticity (b, g, r)
    float lo = 0.0f, hi = 0.0f;           // the floor's luma range
    float tol = 0.0f;                     // chroma_tolerance
    inline uint8_t operator()(uint32_t word) const;
  };

  // The phases of compute(), in order; each reads the per-image state the earlier ones set.
  // Declared inline and defined in field_region.cpp, their only user, so that the compiler may
  // inline them (position-independent code does not inline other global functions).
  // The floor's reference samples from the bottom third into chroma_, luma_; false: none.
  inline bool sampleReference(const cv::Mat& bgr);
  // floor_ from the reference samples' medians and the parameters.
  inline void setFloorTest(const FieldRegionParams& p);
  // The grid columns' tops (grid_top_, run_), row by row with every column tested, while at
  // least a quarter of them are open; the first grid row not scanned.
  inline int scanAllColumns(const cv::Mat& bgr, int min_run);
  // One grid row gy of scanAllColumns; the number of columns it closes.
  inline int scanGridRow(const uint8_t* row, int gy, int min_run);
  // The remaining open columns from grid row gy down, testing only those.
  inline void scanOpenColumns(const cv::Mat& bgr, int gy, int min_run);
  // smoothed_: the median of each column's neighbours' tops.
  inline void smoothTops(int smooth_columns);
  // hull_: the lower convex hull of the smoothed tops, in pixels.
  inline void lowerHull();
  // top_ and restricted_ from the hull.
  inline void setTop(double margin_px);

  // Per image: its size, the grid spacing and size.
  int w_ = 0, h_ = 0, step_ = 1, gw_ = 0, gh_ = 0;
  FloorTest floor_;
  std::vector<int16_t> top_;
  std::vector<int> grid_top_, run_, smoothed_, window_;
  std::vector<std::pair<double, double>> hull_;
  std::vector<float> chroma_[3], luma_;
  std::vector<uint32_t> bgr_words_;  // one grid row's b, g, r (bytes 0, 1, 2 of each word)
  std::vector<float> pick_;  // the reference medians' values in their bin
  std::vector<uint16_t> bins_;  // each sample's bin
  std::vector<uint8_t> is_floor_;
  std::vector<int> open_cols_;  // the grid columns without a boundary yet, when few are left
  bool restricted_ = false;
};

}  // namespace stereoloc::frontend
