#include "frontend/classify.h"

#include <algorithm>
#include <cmath>

namespace stereoloc::frontend {

void classifySegments(const GradientStage& grad, const SegmentExtractor& extractor,
                      const std::vector<float>& max_width_per_row, const ClassifyParams& prm,
                      std::vector<Segment>& segments, std::vector<float>& widths) {
  const auto& edges = grad.edges();
  const int w = grad.width(), h = grad.height();
  const double opp_cos = -std::cos(prm.opposite_tolerance_deg * kTwoPi / 360.0);
  for (size_t si = 0; si < segments.size(); ++si) {
    Segment& seg = segments[si];
    const int* b = extractor.pixelsBegin(si);
    const int* e = extractor.pixelsEnd(si);
    const long n = e - b;
    const double c = std::cos(seg.theta), s = std::sin(seg.theta);
    const int stride = std::max(1, static_cast<int>(std::lround(1.0 / std::clamp(prm.xi_h, 1e-3, 1.0))));
    widths.clear();
    long tested = 0;
    for (long k = 0; k < n; k += stride) {
      const EdgePixel& p = edges[b[k]];
      ++tested;
      double wmax = prm.min_width_px;
      if (!max_width_per_row.empty()) wmax = max_width_per_row[std::clamp<int>(p.iy, 0, h - 1)];
      int last_x = p.ix, last_y = p.iy;
      // Half-pixel steps along the normal, so no pixel of a diagonal partner edge is skipped.
      for (double d = 0.5; d <= wmax + 0.5; d += 0.5) {
        const int qx = static_cast<int>(std::lround(p.x + d * c)), qy = static_cast<int>(std::lround(p.y + d * s));
        if (qx == last_x && qy == last_y) continue;
        last_x = qx;
        last_y = qy;
        if (qx < 0 || qy < 0 || qx >= w || qy >= h) break;
        const int qi = grad.edgeAt(qx, qy);
        if (qi < 0) continue;
        const EdgePixel& q = edges[qi];
        if (std::cos(q.angle) * c + std::sin(q.angle) * s <= opp_cos) {
          const double width = (q.x - p.x) * c + (q.y - p.y) * s;
          if (width > 0 && width <= wmax + 0.5) widths.push_back(static_cast<float>(width));
          break;
        }
      }
    }
    seg.marking_score = tested > 0 ? static_cast<double>(widths.size()) / tested : 0.0;
    if (tested > 0 && seg.marking_score >= prm.xi_l) {
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
