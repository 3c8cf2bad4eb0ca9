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
