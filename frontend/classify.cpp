#include "frontend/classify.h"

#include <algorithm>
#include <cmath>

namespace stereoloc::frontend {
namespace {

// Nearest integer, halves away from zero, as std::lround; that is a libm call, and it sat in
// the inner loop (the partner search below steps half a pixel at a time).
// The gradient stage finds no edge pixels this close to the image border (gradient.cpp).
constexpr int kNoEdgeFrame = 2;

inline int nearestInt(double v) {
  const int t = static_cast<int>(v);  // towards zero
  const double r = v - t;
  return r >= 0.5 ? t + 1 : (r <= -0.5 ? t - 1 : t);
}

// Luma 2 px outside both edges of the stripe (p's dark side and beyond its partner at `width`
// along the normal (c, s)) against the stripe's middle: a marking has floor on both sides.
bool floorOnBothSides(const cv::Mat* luma, const EdgePixel& p, double c, double s, double width, double max_diff) {
  if (!luma || max_diff <= 0) return true;
  auto at = [&](double d, int& out) {
    const int x = nearestInt(p.x + d * c), y = nearestInt(p.y + d * s);
    if (x < 0 || y < 0 || x >= luma->cols || y >= luma->rows) return false;
    out = luma->at<uint8_t>(y, x);
    return true;
  };
  int o1, o2, mid;
  // At the image border one outer side is unseen: keep the partner (the edge test alone).
  if (!at(-2.0, o1) || !at(width + 2.0, o2) || !at(0.5 * width, mid)) return true;
  const int contrast = mid - std::max(o1, o2);
  return contrast > 0 && std::abs(o1 - o2) <= max_diff * contrast;
}

}  // namespace

void classifySegments(const GradientStage& grad, const SegmentExtractor& extractor,
                      const std::vector<float>& max_width_per_row, const ClassifyParams& prm,
                      std::vector<Segment>& segments, std::vector<float>& widths, const cv::Mat* luma) {
  const auto& edges = grad.edges();
  const int w = grad.width(), h = grad.height();
  const double opp_cos = -std::cos(prm.opposite_tolerance_deg * kTwoPi / 360.0);
  for (size_t si = 0; si < segments.size(); ++si) {
    Segment& seg = segments[si];
    const int* b = extractor.pixelsBegin(si);
    const int* e = extractor.pixelsEnd(si);
    const long n = e - b;
    const double c = std::cos(seg.theta), s = std::sin(seg.theta);
    const double opp_deg = std::fmod(seg.theta * 360.0 / kTwoPi + 180.0, 360.0);
    const int stride = std::max(1, static_cast<int>(std::lround(1.0 / std::clamp(prm.xi_h, 1e-3, 1.0))));
    widths.clear();
    // A pixel whose search leaves the observed image (the gradient stage has no edge pixels in
    // the outer 2 px) before W' has no verdict: a stripe running out of the image shows its
    // partner edge only over part of its length. Such pixels are not counted, so the score is
    // over the pixels whose search was complete or found a partner; at least min_seen_share of
    // them must have one.
    long tested = 0, visited = 0;
    const long to_test = n > 0 ? (n - 1) / stride + 1 : 0;
    // Once so few pixels remain that even all of them with a partner cannot reach xi_l, the
    // segment is not a marking (Algorithm 3 stops at the decision too, on the accepting side).
    // Unseen pixels among the remaining ones could only lower the best reachable score, so the
    // test assumes none. The score is then the fraction over the pixels tested so far.
    bool rejected = false;
    for (long k = 0; k < n; k += stride) {
      const long remaining = to_test - visited;
      if (static_cast<double>(static_cast<long>(widths.size()) + remaining) <
          prm.xi_l * static_cast<double>(tested + remaining)) {
        rejected = true;
        break;
      }
      ++visited;
      const EdgePixel& p = edges[b[k]];
      double wmax = prm.min_width_px;
      if (!max_width_per_row.empty()) wmax = max_width_per_row[std::clamp<int>(p.iy, 0, h - 1)];
      int last_x = p.ix, last_y = p.iy;
      bool unseen = false;
      // Half-pixel steps along the normal, so no pixel of a diagonal partner edge is skipped.
      for (double d = 0.5; d <= wmax + 0.5; d += 0.5) {
        const int qx = nearestInt(p.x + d * c), qy = nearestInt(p.y + d * s);
        if (qx == last_x && qy == last_y) continue;
        last_x = qx;
        last_y = qy;
        if (qx < kNoEdgeFrame || qy < kNoEdgeFrame || qx >= w - kNoEdgeFrame || qy >= h - kNoEdgeFrame) {
          unseen = true;
          break;
        }
        const int qi = grad.edgeAt(qx, qy);
        if (qi < 0) continue;
        const EdgePixel& q = edges[qi];
        // Opposite within the tolerance. The pixel's 1 deg direction bin (its angle rounded)
        // decides unless it lies within a degree of the tolerance: the same result without the
        // float sin and cos per candidate (0.7 % of the frontend's instructions).
        double dd = std::fabs(q.dir_bin - opp_deg);
        if (dd > 180) dd = 360 - dd;
        const bool opposite = dd + 1.0 < prm.opposite_tolerance_deg   ? true
                              : dd - 1.0 > prm.opposite_tolerance_deg ? false
                                                                      : std::cos(q.angle) * c + std::sin(q.angle) * s <= opp_cos;
        if (opposite) {
          const double width = (q.x - p.x) * c + (q.y - p.y) * s;
          if (width > 0 && width <= wmax + 0.5 && floorOnBothSides(luma, p, c, s, width, prm.max_outer_difference))
            widths.push_back(static_cast<float>(width));
          unseen = false;
          break;
        }
      }
      if (!unseen) ++tested;
    }
    if (static_cast<double>(tested) < prm.min_seen_share * static_cast<double>(to_test)) rejected = true;
    seg.marking_score = tested > 0 ? static_cast<double>(widths.size()) / tested : 0.0;
    if (!rejected && tested > 0 && seg.marking_score >= prm.xi_l) {
      seg.cls = SegmentClass::Marking;
      std::nth_element(widths.begin(), widths.begin() + widths.size() / 2, widths.end());
      seg.marking_width = widths[widths.size() / 2];
    } else {
      seg.cls = SegmentClass::Other;
      seg.marking_width = 0;
    }
  }
}

}  // namespace stereoloc::frontend
