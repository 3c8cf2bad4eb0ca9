#pragma once
// Types shared by the stages of the vision frontend (thesis chapter 3).
//
// Image coordinates: x = column (u), y = row (v), in px, with pixel centres at integer
// coordinates (the convention of src/core/stereo_rig.h). Line convention, used by every stage:
//
//     x cos(theta) + y sin(theta) = rho                                        (3.9)
//
// with the origin at pixel (0, 0). Unlike the thesis (theta in [0, pi)), our lines are
// DIRECTED: theta in [0, 2 pi) is the direction of the luma gradient, i.e. (cos theta,
// sin theta) points from the dark side to the bright side, and rho may be negative. The two
// sides of a white stripe therefore are two distinct lines with theta 180 deg apart, which is
// what the marking test (Algorithm 3) looks for. The Hough accumulator internally measures rho
// from the image centre to halve its size; that is private to frontend/gbht.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include "src/core/angles.h"
#include "src/core/field_map.h"

namespace stereoloc::frontend {

// One edge pixel after non-maximum suppression.
struct EdgePixel {
  float x = 0, y = 0;     // sub-pixel position along the gradient (px)
  int16_t ix = 0, iy = 0; // the integer pixel it was found at
  float angle = 0;        // gradient direction, rad in [0, 2 pi)
  float mag = 0;          // Sobel magnitude (luma units x 4)
  uint16_t dir_bin = 0;   // angle quantised to 1 deg, [0, 360)
};

// How a segment was classified (Algorithm 3 and the labels of the overlay).
enum class SegmentClass { Other, Marking };

// A straight edge segment (the "complete line description" of 3.3.3).
struct Segment {
  double theta = 0;                 // rad in [0, 2 pi), gradient direction (see above)
  double rho = 0;                   // px, origin at pixel (0, 0)
  double x1 = 0, y1 = 0, x2 = 0, y2 = 0;  // endpoints on the fitted line, px
  int pixels = 0;                   // edge pixels supporting it
  double rms = 0;                   // rms distance of its pixels from the line, px
  SegmentClass cls = SegmentClass::Other;
  double marking_width = 0;         // px, median stripe width when cls == Marking
  double marking_score = 0;         // fraction of tested pixels with a dual edge
  double length() const;
};

// An undirected infinite line with an extent, used for intersections (Algorithm 4).
// For markings it is the centre line of the stripe, otherwise the edge itself.
struct LineFeature {
  double theta = 0;         // rad in [0, pi)
  double rho = 0;           // px
  double t_min = 0, t_max = 0;  // extent along the line direction (-sin theta, cos theta), px
  bool marking = false;
  bool wall_foot = false;   // bright above, dark below: the foot of a wall seen from the field
  double width = 0;         // px, stripe width in the image (markings; the wider of two edges' widths)
  int support = 0;          // pixels
  int source = -1;          // index of the (first) segment it came from
  double x(double t) const;  // point at line coordinate t
  double y(double t) const;
};

// The interval [lo, hi] of t where the point (x0 + t dx, y0 + t dy) lies inside the box
// [xmin, xmax] x [ymin, ymax]: each side is a half-space linear in t (slab clipping). lo > hi
// when the path misses the box. Inline: the stripe-end sampler calls it per stripe.
inline std::pair<double, double> pathBoxInterval(double x0, double dx, double y0, double dy, double xmin, double ymin,
                                                 double xmax, double ymax) {
  double lo = -1e30, hi = 1e30;
  auto clip = [&](double p0, double dp, double pmin, double pmax) {  // pmin <= p0 + t dp <= pmax
    if (std::fabs(dp) < 1e-12) {
      if (p0 < pmin || p0 > pmax) hi = lo - 1;
      return;
    }
    double a = (pmin - p0) / dp, b = (pmax - p0) / dp;
    if (a > b) std::swap(a, b);
    lo = std::max(lo, a);
    hi = std::min(hi, b);
  };
  clip(x0, dx, xmin, xmax);
  clip(y0, dy, ymin, ymax);
  return {lo, hi};
}

// The same for the line (rho, theta), whose point at t is (rho cos - t sin, rho sin + t cos).
std::pair<double, double> lineBoxInterval(double rho, double theta, double xmin, double ymin, double xmax,
                                          double ymax);

// A point feature in the left image.
struct PointFeature {
  LandmarkType type = LandmarkType::Point;
  double u = 0, v = 0;      // px, left image
  GoalColor color = GoalColor::None;  // goal corners
  int side = 0;             // goal corners: -1 colour to the right of white (left edge of the goal), +1 the other
  int line_a = -1, line_b = -1;       // LineFeature indices (corners)
  int landmark_id = -1;     // set when globally unique
  bool located_on_image = false;      // crossings: moved onto where the stripes cross (refineCrossing)
};

}  // namespace stereoloc::frontend
