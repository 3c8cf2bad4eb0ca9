#include "frontend/goal_corners.h"

#include <algorithm>
#include <cmath>

namespace stereoloc::frontend {
namespace {

constexpr int kOffHue = -1000;  // neither the goal colour nor white (e.g. the orange ball)

inline int colourScore(const uint8_t* p, GoalColor c) {
  const int b = p[0], g = p[1], r = p[2];
  if (c == GoalColor::Yellow) {
    const int s = std::min(r, g) - b;
    // Yellow has R ~ G; orange (the ball) has R >> G.
    return (s > 0 && 3 * std::abs(r - g) > s) ? kOffHue : s;
  }
  return b - std::max(r, g);
}
inline int luma(const uint8_t* p) { return (29 * p[0] + 150 * p[1] + 77 * p[2] + 128) >> 8; }

}  // namespace

void scanRowTransitions(const cv::Mat& bgr, int row, int x0, int x1, GoalColor color, int side, const GoalParams& prm,
                        std::vector<Transition>& out) {
  x0 = std::max(0, x0);
  x1 = std::min(bgr.cols, x1);
  if (row < 0 || row >= bgr.rows || x1 - x0 < 2) return;
  const uint8_t* p = bgr.ptr<uint8_t>(row);
  // Walk so that the white pixel comes first: rightwards for side -1, leftwards for side +1.
  const int step = side < 0 ? 1 : -1;
  const int start = side < 0 ? x0 : x1 - 1, stop = side < 0 ? x1 : x0 - 1;
  int last_white = -1000000;
  for (int x = start; x != stop; x += step) {
    const int s = colourScore(p + 3 * x, color);
    if (std::abs(s) <= prm.white_max_score) {
      if (luma(p + 3 * x) >= prm.white_min_luma) last_white = x;
      continue;
    }
    if (s < prm.colour_min_score) continue;
    const int dist = (x - last_white) * step;
    if (dist < 1 || dist > prm.max_transition_px) continue;
    // Colour level: the strongest of this and the next pixel further into the colour.
    int sc = s;
    const int xn = x + step;
    if (xn != stop) sc = std::max(sc, colourScore(p + 3 * xn, color));
    // White reference one pixel further out, so the last "white" pixel's own slight colour
    // (its colour fraction is below white_max_score) is counted too.
    int ref = last_white;
    const int outer = last_white - step;
    if (outer >= x0 && outer < x1 && std::abs(colourScore(p + 3 * outer, color)) <= prm.white_max_score) ref = outer;
    const double sw = colourScore(p + 3 * ref, color);
    // Area estimate: with alpha_k the colour fraction of the pixels between the white reference
    // and the full colour, the edge lies sum(1 - alpha_k) past the reference pixel's border.
    // Exact for any symmetric blur of a step, unlike interpolating the half level.
    double col = ref + 0.5 * step;
    const int end = xn != stop ? xn + step : xn;
    for (int k = ref + step; k != end; k += step) {
      const double a = std::clamp((colourScore(p + 3 * k, color) - sw) / (sc - sw), 0.0, 1.0);
      col += step * (1.0 - a);
    }
    out.push_back(Transition{row, static_cast<float>(col)});
    last_white = -1000000;
  }
}

bool robustColumn(const std::vector<Transition>& tr, const GoalParams& prm, double& u, double& v, int& rows,
                  std::vector<float>& scratch) {
  rows = 0;
  if (static_cast<int>(tr.size()) < prm.min_rows) return false;
  scratch.clear();
  for (const Transition& t : tr) scratch.push_back(t.column);
  const size_t mid = scratch.size() / 2;
  std::nth_element(scratch.begin(), scratch.begin() + mid, scratch.end());
  const double med = scratch[mid];
  for (float& s : scratch) s = std::fabs(s - static_cast<float>(med));
  std::nth_element(scratch.begin(), scratch.begin() + mid, scratch.end());
  const double tol = std::max(prm.outlier_px, 3.0 * 1.4826 * scratch[mid]);
  double su = 0, sv = 0;
  for (const Transition& t : tr)
    if (std::fabs(t.column - med) <= tol) {
      su += t.column;
      sv += t.row;
      ++rows;
    }
  if (rows < prm.min_rows) return false;
  u = su / rows;
  v = sv / rows;
  return true;
}

void detectGoalEdges(const cv::Mat& bgr, const GoalParams& prm, std::vector<GoalEdge>& edges,
                     std::vector<float>& scratch, const ColourPrepare* prepare) {
  edges.clear();
  const int step = std::max(1, prm.coarse_step);
  if (prepare) (*prepare)(cv::Rect(step / 2, step / 2, bgr.cols - step / 2, bgr.rows - step / 2), step);
  for (GoalColor color : {GoalColor::Blue, GoalColor::Yellow}) {
    int xmin = bgr.cols, xmax = -1, ymin = bgr.rows, ymax = -1, hits = 0;
    for (int y = step / 2; y < bgr.rows; y += step) {
      const uint8_t* p = bgr.ptr<uint8_t>(y);
      for (int x = step / 2; x < bgr.cols; x += step)
        if (colourScore(p + 3 * x, color) >= prm.colour_min_score) {
          ++hits;
          xmin = std::min(xmin, x);
          xmax = std::max(xmax, x);
          ymin = std::min(ymin, y);
          ymax = std::max(ymax, y);
        }
    }
    if (hits < prm.min_coarse_hits) continue;
    const int m = prm.window_margin_px;
    if (prepare) {
      const int y0 = std::max(0, ymin - m), x0 = std::max(0, xmin - m);
      (*prepare)(cv::Rect(x0, y0, std::min(bgr.cols, xmax + m + 1) - x0, std::min(bgr.rows - 1, ymax + m) + 1 - y0), 1);
    }
    for (int side : {-1, 1}) {
      GoalEdge ge;
      ge.color = color;
      ge.side = side;
      for (int y = std::max(0, ymin - m); y <= std::min(bgr.rows - 1, ymax + m); ++y)
        scanRowTransitions(bgr, y, xmin - m, xmax + m + 1, color, side, prm, ge.transitions);
      if (robustColumn(ge.transitions, prm, ge.u, ge.v, ge.rows, scratch)) edges.push_back(std::move(ge));
    }
  }
}

}  // namespace stereoloc::frontend
