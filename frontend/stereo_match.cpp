#include "frontend/stereo_match.h"

#include <algorithm>
#include <cmath>

#include "frontend/corners.h"

namespace stereoloc::frontend {

DisparityRange validDisparities(const StereoRig& rig, const StereoParams& prm) {
  const double fb = rig.focal() * rig.params().baseline_mm;
  const double far = prm.max_range_mm > 0 ? prm.max_range_mm : rig.params().max_range_mm;
  DisparityRange r;
  r.min = std::max(rig.params().min_disparity_px, fb / std::max(far, 1.0));
  r.max = fb / std::max(prm.min_range_mm, 1.0);
  return r;
}

std::optional<double> floorDisparity(const StereoRig& rig, double u, double v) {
  double x, y;
  if (!floorPoint(rig, u, v, x, y)) return std::nullopt;
  const auto px = rig.project(Eigen::Vector3d(x, y, 0.0), 0.0);
  if (!px) return std::nullopt;
  return px->u_left - px->u_right;
}

std::optional<double> matchGoalEdge(const cv::Mat& right_bgr, const GoalEdge& left, const DisparityRange& range,
                                    const GoalParams& gp, std::vector<Transition>& tr, std::vector<float>& scratch) {
  // Rows the left edge was found on, inliers only.
  const double tol = 1.5;
  tr.clear();
  const int x0 = static_cast<int>(std::floor(left.u - range.max)) - 3;
  const int x1 = static_cast<int>(std::ceil(left.u - range.min)) + 4;
  int last_row = -1;
  for (const Transition& t : left.transitions) {
    if (std::fabs(t.column - left.u) > tol || t.row == last_row) continue;
    last_row = t.row;
    const size_t before = tr.size();
    scanRowTransitions(right_bgr, t.row, x0, x1, left.color, left.side, gp, tr);
    // Per-row disparity; several transitions on a row are all kept for the robust estimate.
    for (size_t k = before; k < tr.size(); ++k) tr[k].column = static_cast<float>(left.u) - tr[k].column;
  }
  double d, v;
  int rows;
  if (!robustColumn(tr, gp, d, v, rows, scratch)) return std::nullopt;
  if (rows < gp.min_right_row_fraction * left.rows) return std::nullopt;
  if (d < range.min || d > range.max) return std::nullopt;
  return left.u - d;
}

double slideGain(const cv::Mat& L, int uc, int vc, int r) {
  double sxx = 0, sxy = 0;
  for (int y = std::max(vc - r, 1); y <= std::min(vc + r, L.rows - 2); ++y) {
    const uint8_t* up = L.ptr<uint8_t>(y - 1);
    const uint8_t* row = L.ptr<uint8_t>(y);
    const uint8_t* down = L.ptr<uint8_t>(y + 1);
    for (int x = std::max(uc - r, 1); x <= std::min(uc + r, L.cols - 2); ++x) {
      const double ix = 0.5 * (static_cast<double>(row[x + 1]) - row[x - 1]);
      const double iy = 0.5 * (static_cast<double>(down[x]) - up[x]);
      sxx += ix * ix;
      sxy += ix * iy;
    }
  }
  return sxx > 0 ? sxy / sxx : 0.0;
}

std::optional<double> matchFloorFeature(const cv::Mat& L, const cv::Mat& R, const StereoRig& rig, double u, double v,
                                        const DisparityRange& range, const StereoParams& prm, double* slide_gain) {
  const int r = prm.patch_radius;
  const int uc = static_cast<int>(std::lround(u)), vc = static_cast<int>(std::lround(v));
  if (uc - r < 0 || vc - r < 0 || uc + r >= L.cols || vc + r >= L.rows) return std::nullopt;
  double dmin = range.min, dmax = range.max, shear = 0.0;
  const auto dc = floorDisparity(rig, uc, vc);
  if (dc) {
    const auto d1 = floorDisparity(rig, uc, vc + 1);
    if (d1) shear = *d1 - *dc;
    if (prm.floor_search_px > 0) {
      dmin = std::max(dmin, *dc - prm.floor_search_px);
      dmax = std::min(dmax, *dc + prm.floor_search_px);
    }
  }
  const int di0 = static_cast<int>(std::floor(dmin)) - 1, di1 = static_cast<int>(std::ceil(dmax)) + 1;
  if (di1 < di0) return std::nullopt;
  // Left patch statistics.
  const int n = (2 * r + 1) * (2 * r + 1);
  double sl = 0, sll = 0;
  for (int dy = -r; dy <= r; ++dy) {
    const uint8_t* p = L.ptr<uint8_t>(vc + dy);
    for (int dx = -r; dx <= r; ++dx) {
      sl += p[uc + dx];
      sll += static_cast<double>(p[uc + dx]) * p[uc + dx];
    }
  }
  const double varl = sll - sl * sl / n;
  if (varl < 1e-6 * n) return std::nullopt;
  double scores[256];
  const int nd = std::min(256, di1 - di0 + 1);
  for (int k = 0; k < nd; ++k) {
    const int d = di0 + k;
    double sr = 0, srr = 0, slr = 0;
    bool inside = true;
    for (int dy = -r; dy <= r && inside; ++dy) {
      const double off = -d - shear * dy;  // left pixel uc+dx maps to right column uc+dx+off
      const double xs = uc + off;
      const int xi = static_cast<int>(std::floor(xs));
      const double fr = xs - xi;
      if (xi - r < 0 || xi + r + 1 >= R.cols) {
        inside = false;
        break;
      }
      const uint8_t* p = L.ptr<uint8_t>(vc + dy);
      const uint8_t* q = R.ptr<uint8_t>(vc + dy);
      for (int dx = -r; dx <= r; ++dx) {
        const double rv = (1.0 - fr) * q[xi + dx] + fr * q[xi + dx + 1];
        sr += rv;
        srr += rv * rv;
        slr += rv * p[uc + dx];
      }
    }
    const double varr = srr - sr * sr / n;
    scores[k] = (!inside || varr < 1e-6 * n) ? -1.0 : (slr - sl * sr / n) / std::sqrt(varl * varr);
  }
  int best = -1;
  for (int k = 0; k < nd; ++k)
    if (best < 0 || scores[k] > scores[best]) best = k;
  if (best <= 0 || best >= nd - 1 || scores[best] < prm.min_zncc) return std::nullopt;
  for (int k = 0; k < nd; ++k) {
    if (std::abs(k - best) <= 1) continue;
    const bool local_max = (k == 0 || scores[k] >= scores[k - 1]) && (k == nd - 1 || scores[k] >= scores[k + 1]);
    if (local_max && scores[k] > scores[best] - prm.uniqueness) return std::nullopt;
  }
  const double a = scores[best - 1], b = scores[best], c = scores[best + 1];
  const double den = a - 2 * b + c;
  const double sub = den < 0 ? 0.5 * (a - c) / den : 0.0;
  // d holds at the patch centre row; move it to the feature's row along the floor.
  const double d = di0 + best + std::clamp(sub, -0.5, 0.5) + shear * (v - vc);
  if (d < range.min || d > range.max) return std::nullopt;
  // The right image's floor edges lean by the floor's shear more than the left's (the search
  // shears the patch by it): a row offset moves the right column by the left patch's gain plus it.
  if (slide_gain) *slide_gain = slideGain(L, uc, vc, r) + shear;
  return d;
}

}  // namespace stereoloc::frontend
