#pragma once
// Stage 7: goal corners from colour transitions (thesis 3.6).
//  1. Coarse: every coarse_step-th pixel of every coarse_step-th row is tested for blue and
//     yellow; the hits of each colour give a rectangular window (N/16 pixels tested).
//  2. Fine: every row of the window, widened by window_margin_px, is scanned at full
//     resolution for white->colour and colour->white transitions. The column of a transition
//     comes from the colour fractions of the mixed pixels between the last white and the
//     first coloured pixel (an area estimate: exact for a box-filtered or symmetric-blurred step).
//  3. Per colour and side, the column is the mean of the rows within
//     max(outlier_px, 3 * 1.4826 MAD) of the median (outliers rejected), v the mean row.
// Colour scores, from 8-bit BGR: yellow = min(R, G) - B (and R ~ G, which rejects the orange
// ball), blue = B - max(R, G); white is a score within +-white_max_score with luma at least
// white_min_luma.
//
// Side: -1 when the colour lies to the right of the white (the left edge of the goal in the
// image), +1 when it lies to the left.
#include <functional>
#include <opencv2/core/mat.hpp>
#include <vector>

#include "frontend/features.h"

namespace stereoloc::frontend {

struct GoalParams {
  int coarse_step = 4;            // thesis: every 4th pixel of every 4th row
  int min_coarse_hits = 2;        // coarse hits needed before a colour window is searched
  int window_margin_px = 6;       // widening of the coarse window
  int colour_min_score = 50;      // score of a goal-coloured pixel
  int white_max_score = 25;       // score of a white pixel (of the same colour channel pair)
  int white_min_luma = 90;        // luma of a white pixel
  int max_transition_px = 3;      // white and colour pixels at most this far apart
  int min_rows = 4;               // rows needed for a goal-corner estimate
  double outlier_px = 1.0;        // minimum rejection distance from the median column
  // Least share of the left edge's inlier rows on which its right-image match must be found.
  // A rectified pair shows the vertical edge on the same rows; where the right camera does not
  // see it (beyond its border), a few rows of another white/colour transition, e.g. a wall's
  // top edge, can still pass min_rows (4 of the left's 69 rows, 10 px off in disparity, on a
  // realistic `line`). Good matches on rendered pairs keep 71-100 % of the rows.
  double min_right_row_fraction = 0.5;
};

// One per-row transition.
struct Transition {
  int row = 0;
  float column = 0;  // px, sub-pixel
};

// The transitions of one colour and side in one image, and their robust column.
struct GoalEdge {
  GoalColor color = GoalColor::None;
  int side = 0;
  double u = 0, v = 0;      // robust column and mean row of the inlier rows
  int rows = 0;             // inlier rows
  std::vector<Transition> transitions;  // all rows, sorted by row
};

// Scans one row [x0, x1) of a BGR image for transitions of `color` on `side`; appends
// sub-pixel columns to `out` with this row.
void scanRowTransitions(const cv::Mat& bgr, int row, int x0, int x1, GoalColor color, int side, const GoalParams& params,
                        std::vector<Transition>& out);

// Median / MAD robust column of a list of transitions (inlier mean). Returns false when fewer
// than min_rows inliers remain.
bool robustColumn(const std::vector<Transition>& tr, const GoalParams& params, double& u, double& v, int& rows,
                  std::vector<float>& scratch);

// For an image resampled on demand (frontend/rectify.h): makes the pixels (rect.x + i step,
// rect.y + j step) inside rect valid in the image the stage reads.
using ColourPrepare = std::function<void(const cv::Rect& rect, int step)>;

// Coarse search and fine scan of the left image: up to one GoalEdge per colour and side. With
// `prepare`, bgr is valid only where prepare was asked for: the coarse grid, then each window.
void detectGoalEdges(const cv::Mat& bgr, const GoalParams& params, std::vector<GoalEdge>& edges,
                     std::vector<float>& scratch, const ColourPrepare* prepare = nullptr);

}  // namespace stereoloc::frontend
