#include "frontend/corners.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <cstdio>

namespace stereoloc::frontend {
namespace {

constexpr double kPi = 3.141592653589793;
double deg(double d) { return d * kPi / 180.0; }

// Undirected form of a directed line.
void undirect(double theta, double rho, double& t_out, double& r_out) {
  if (theta >= kPi) {
    t_out = theta - kPi;
    r_out = -rho;
  } else {
    t_out = theta;
    r_out = rho;
  }
}

double along(double theta, double x, double y) { return -x * std::sin(theta) + y * std::cos(theta); }

// The interval [lo, hi] of the line parameter t where the line lies inside the image (pixel
// centres at integers, so the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]); lo > hi when the
// line misses the image.
std::pair<double, double> imageInterval(const LineFeature& l, int width, int height) {
  return lineBoxInterval(l.rho, l.theta, -0.5, -0.5, width - 0.5, height - 0.5);
}

// Luma at (x, y), bilinear; -1 when the 2x2 neighbourhood leaves the image.
double lumaAt(const cv::Mat& g, double x, double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= g.cols || y0 + 1 >= g.rows) return -1.0;
  const double fx = x - x0, fy = y - y0;
  const uint8_t* r0 = g.ptr<uint8_t>(y0) + x0;
  const uint8_t* r1 = g.ptr<uint8_t>(y0 + 1) + x0;
  return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
}

// Luma on line m's centre line at coordinate t and, in `floor`, the darker of the two sides at
// +-(0.5 width + side) across (the floor even where the other side touches a wall or another
// stripe). False when a sample leaves the image.
bool stripeSamples(const cv::Mat& g, const LineFeature& m, double t, double side, double& centre, double& floor) {
  const double cx = m.x(t), cy = m.y(t), nx = std::cos(m.theta), ny = std::sin(m.theta);
  const double off = 0.5 * m.width + side;
  const double c = lumaAt(g, cx, cy), l = lumaAt(g, cx - off * nx, cy - off * ny), r = lumaAt(g, cx + off * nx, cy + off * ny);
  if (c < 0 || l < 0 || r < 0) return false;
  centre = c;
  floor = std::min(l, r);
  return true;
}

}  // namespace

bool stripeReaches(const cv::Mat& luma, const LineFeature& m, double tp, double s0, const CornerParams& prm) {
  if (prm.probe_min_run <= 0) return true;
  // References from the middle of the extent, where the stripe is what the line was fitted to
  // and its width is the measured one: stripe and floor luma, medians of 5 (robust to a sample
  // on a crossing line or an occluder). Near the point only the centre line is sampled: a near
  // stripe widens towards the camera (seed 6: 14.5 px at a corner whose line's median width was
  // 9.1 px), so side samples there can fall inside it.
  const double tm = 0.5 * (m.t_min + m.t_max), half = 0.5 * (m.t_max - m.t_min);
  double cs[5], fs[5];
  int n = 0;
  for (int k = -2; k <= 2; ++k)
    if (stripeSamples(luma, m, tm + std::clamp(2.0 * k, -half, half), prm.probe_side_px, cs[n], fs[n])) ++n;
  if (n < 3) return true;
  std::nth_element(cs, cs + n / 2, cs + n);
  std::nth_element(fs, fs + n / 2, fs + n);
  const double floor_ref = fs[n / 2], contrast = cs[n / 2] - floor_ref;
  if (contrast < 4.0) return true;  // no visible stripe to compare with: no verdict
  const double dark = floor_ref + prm.probe_dark_fraction * contrast;
  const double dir = tm >= tp ? 1.0 : -1.0;
  const double reach = std::min(prm.delta_px, std::fabs(tm - tp));
  int run = 0;
  for (double s = s0; s <= reach; s += 1.0) {
    const double t = tp + dir * s, c = lumaAt(luma, m.x(t), m.y(t));
    if (c < 0) {
      run = 0;
      continue;
    }
    run = c < dark ? run + 1 : 0;
    if (run >= prm.probe_min_run) return false;
  }
  return true;
}

bool floorPoint(const StereoRig& rig, double u, double v, double& x, double& y) {
  const double f = rig.focal(), b = rig.params().baseline_mm;
  const Eigen::Vector3d o = rig.visionToRobot(Eigen::Vector3d(0.0, 0.5 * b, 0.0), 0.0);
  const Eigen::Vector3d p =
      rig.visionToRobot(Eigen::Vector3d(1.0, 0.5 * b - (u - rig.principalU()) / f, -(v - rig.principalV()) / f), 0.0);
  const double dz = p.z() - o.z();
  if (!(dz < -1e-9)) return false;
  const double s = -o.z() / dz;
  x = o.x() + s * (p.x() - o.x());
  y = o.y() + s * (p.y() - o.y());
  return true;
}

void buildLines(const std::vector<Segment>& segments, const CornerParams& prm, std::vector<LineFeature>& lines) {
  lines.clear();
  for (size_t i = 0; i < segments.size(); ++i) {
    const Segment& s = segments[i];
    LineFeature l;
    const bool marking = s.cls == SegmentClass::Marking;
    undirect(s.theta, s.rho + (marking ? 0.5 * s.marking_width : 0.0), l.theta, l.rho);
    const double t1 = along(l.theta, s.x1, s.y1), t2 = along(l.theta, s.x2, s.y2);
    l.t_min = std::min(t1, t2);
    l.t_max = std::max(t1, t2);
    l.marking = marking;
    l.width = marking ? s.marking_width : 0.0;
    // Bright above (gradient pointing up the image) and not a stripe: the foot of a wall.
    l.wall_foot = !marking && std::sin(s.theta) < -std::cos(deg(prm.wall_foot_max_tilt_deg));
    l.support = s.pixels;
    l.source = static_cast<int>(i);
    lines.push_back(l);
  }
  // The two edges of one stripe: opposite gradients, nearly the same centre line. Under
  // perspective they converge, so their centre line is the line through the midpoints of
  // corresponding points (each edge's end points and their projections on the other edge).
  std::vector<uint8_t> gone(lines.size(), 0);
  for (size_t i = 0; i < lines.size(); ++i) {
    if (!lines[i].marking || gone[i]) continue;
    const Segment& a = segments[i];
    for (size_t j = i + 1; j < lines.size(); ++j) {
      if (!lines[j].marking || gone[j]) continue;
      const Segment& b = segments[j];
      if (std::cos(a.theta - b.theta) > -std::cos(deg(prm.centre_merge_deg))) continue;
      const LineFeature& li = lines[i];
      const LineFeature& lj = lines[j];
      const double tol = std::max(prm.centre_merge_px, 0.5 * std::max(a.marking_width, b.marking_width));
      auto dist = [](const LineFeature& l, double x, double y) {
        return std::fabs(x * std::cos(l.theta) + y * std::sin(l.theta) - l.rho);
      };
      const double tm = 0.5 * (li.t_min + li.t_max);
      if (dist(lj, li.x(tm), li.y(tm)) > tol) continue;
      const double u0 = along(lj.theta, li.x(li.t_min), li.y(li.t_min)), u1 = along(lj.theta, li.x(li.t_max), li.y(li.t_max));
      if (std::max(u0, u1) < lj.t_min - prm.delta_px || std::min(u0, u1) > lj.t_max + prm.delta_px) continue;
      // Midpoints of corresponding edge points.
      double mx[4], my[4];
      int n = 0;
      for (const Segment* p : {&a, &b}) {
        const Segment* q = p == &a ? &b : &a;
        const double qc = std::cos(q->theta), qs = std::sin(q->theta);
        for (int e = 0; e < 2; ++e) {
          const double x = e ? p->x2 : p->x1, y = e ? p->y2 : p->y1;
          const double d = x * qc + y * qs - q->rho;
          mx[n] = x - 0.5 * d * qc;
          my[n] = y - 0.5 * d * qs;
          ++n;
        }
      }
      double cx = 0, cy = 0;
      for (int k = 0; k < 4; ++k) {
        cx += mx[k] / 4;
        cy += my[k] / 4;
      }
      double sxx = 0, sxy = 0, syy = 0;
      for (int k = 0; k < 4; ++k) {
        sxx += (mx[k] - cx) * (mx[k] - cx);
        sxy += (mx[k] - cx) * (my[k] - cy);
        syy += (my[k] - cy) * (my[k] - cy);
      }
      const double phi = 0.5 * std::atan2(2 * sxy, sxx - syy);  // direction of the centre line
      LineFeature m = li;
      double th = phi + kPi / 2;  // normal
      while (th < 0) th += kPi;
      while (th >= kPi) th -= kPi;
      m.theta = th;
      m.rho = cx * std::cos(th) + cy * std::sin(th);
      // Each end of the centre line lies midway between the two edges' ends when they are
      // within a stripe width of each other (at an L corner the outer edge runs half a width
      // past the centre-line corner and the inner edge stops half a width short); further
      // apart, one edge is broken or occluded there and the longer one tells the extent.
      double ta[2] = {1e30, -1e30}, tb[2] = {1e30, -1e30};
      for (int k = 0; k < 4; ++k) {
        double* t = k < 2 ? ta : tb;
        const double v = along(th, mx[k], my[k]);
        t[0] = std::min(t[0], v);
        t[1] = std::max(t[1], v);
      }
      const double agree = std::max(a.marking_width, b.marking_width) + 1.0;
      m.t_min = std::fabs(ta[0] - tb[0]) <= agree ? 0.5 * (ta[0] + tb[0]) : std::min(ta[0], tb[0]);
      m.t_max = std::fabs(ta[1] - tb[1]) <= agree ? 0.5 * (ta[1] + tb[1]) : std::max(ta[1], tb[1]);
      m.support = li.support + lj.support;
      m.width = std::max(a.marking_width, b.marking_width);
      lines[i] = m;
      gone[j] = 1;
      break;
    }
  }
  size_t k = 0;
  for (size_t i = 0; i < lines.size(); ++i)
    if (!gone[i]) lines[k++] = lines[i];
  lines.resize(k);
}

void clipLinesToImage(int width, int height, std::vector<LineFeature>& lines) {
  size_t k = 0;
  for (LineFeature& l : lines) {
    const auto [lo, hi] = imageInterval(l, width, height);
    const double t0 = std::max(l.t_min, lo), t1 = std::min(l.t_max, hi);
    if (t1 <= t0) continue;
    l.t_min = t0;
    l.t_max = t1;
    lines[k++] = l;
  }
  lines.resize(k);
}

void snapLineEnds(int width, int height, const CornerParams& prm, std::vector<LineFeature>& lines) {
  const double min_sin = std::sin(deg(prm.snap_min_angle_deg));
  // Best intersection found for each end: (distance moved, new t).
  std::vector<std::pair<double, double>> best(2 * lines.size(), {1e30, 0.0});
  for (size_t i = 0; i < lines.size(); ++i)
    for (size_t j = i + 1; j < lines.size(); ++j) {
      const LineFeature& a = lines[i];
      const LineFeature& b = lines[j];
      const double det = std::cos(a.theta) * std::sin(b.theta) - std::sin(a.theta) * std::cos(b.theta);
      if (std::fabs(det) < min_sin) continue;
      // (3.12), (3.13)
      const double px = (a.rho * std::sin(b.theta) - b.rho * std::sin(a.theta)) / det;
      const double py = (b.rho * std::cos(a.theta) - a.rho * std::cos(b.theta)) / det;
      if (px < -0.5 || py < -0.5 || px > width - 0.5 || py > height - 0.5) continue;
      const double ta = along(a.theta, px, py), tb = along(b.theta, px, py);
      // Which end of each line is at p (-1: none); an end is at p within snap_px either way.
      auto endAt = [&](const LineFeature& l, double t) {
        if (t < l.t_min - prm.snap_px || t > l.t_max + prm.snap_px) return -2;  // p off the line
        if (std::fabs(t - l.t_min) <= prm.snap_px && std::fabs(t - l.t_min) <= std::fabs(t - l.t_max)) return 0;
        if (std::fabs(t - l.t_max) <= prm.snap_px) return 1;
        return -1;  // p inside the extent, away from both ends: the line passes p
      };
      const int ea = endAt(a, ta), eb = endAt(b, tb);
      if (ea == -2 || eb == -2 || (ea < 0 && eb < 0)) continue;
      // L: both end at p; T: one ends at p and the other passes it. Both move to p.
      auto offer = [&](size_t k, int e, const LineFeature& l, double t) {
        if (e < 0) return;
        const double moved = std::fabs(t - (e ? l.t_max : l.t_min));
        std::pair<double, double>& slot = best[2 * k + static_cast<size_t>(e)];
        if (moved < slot.first) slot = {moved, t};
      };
      offer(i, ea, a, ta);
      offer(j, eb, b, tb);
    }
  for (size_t k = 0; k < lines.size(); ++k) {
    LineFeature& l = lines[k];
    if (best[2 * k].first < 1e29) l.t_min = best[2 * k].second;
    if (best[2 * k + 1].first < 1e29) l.t_max = best[2 * k + 1].second;
    if (l.t_max < l.t_min) std::swap(l.t_min, l.t_max);
    // No gradient is computed in the outermost 2 px (frontend/gradient.cpp), so an end within
    // border_snap_px of the image border has no evidence of ending there: the line runs on to
    // the border, where the renderer's truth is clipped too.
    const auto [lo, hi] = imageInterval(l, width, height);
    if (hi < lo) continue;  // not in the image at all
    if (l.t_min - lo <= prm.border_snap_px) l.t_min = std::max(lo, std::min(l.t_min, lo));
    if (hi - l.t_max <= prm.border_snap_px) l.t_max = std::min(hi, std::max(l.t_max, hi));
  }
}

void findCorners(const std::vector<LineFeature>& lines, const StereoRig& rig, const CornerParams& prm,
                 std::vector<PointFeature>& features, const cv::Mat* luma) {
  features.clear();
  const double w = rig.params().image_width, h = rig.params().image_height;
  const double min_sin = std::sin(deg(prm.min_image_angle_deg));
  std::vector<int> counts;
  auto floorDir = [&](const LineFeature& l, double& dx, double& dy) {
    double xa, ya, xb, yb;
    if (!floorPoint(rig, l.x(l.t_min), l.y(l.t_min), xa, ya) || !floorPoint(rig, l.x(l.t_max), l.y(l.t_max), xb, yb))
      return false;
    dx = xb - xa;
    dy = yb - ya;
    return std::hypot(dx, dy) > 1e-6;
  };
  for (size_t i = 0; i < lines.size(); ++i) {
    for (size_t j = i + 1; j < lines.size(); ++j) {
      const LineFeature& a = lines[i];
      const LineFeature& b = lines[j];
      if (!a.marking && !b.marking) continue;
      const double det = std::cos(a.theta) * std::sin(b.theta) - std::sin(a.theta) * std::cos(b.theta);
      if (std::fabs(det) < min_sin) continue;
      // (3.12), (3.13)
      const double px = (a.rho * std::sin(b.theta) - b.rho * std::sin(a.theta)) / det;
      const double py = (b.rho * std::cos(a.theta) - a.rho * std::cos(b.theta)) / det;
      if (px < 0 || py < 0 || px > w - 1 || py > h - 1) continue;
      const double ta = along(a.theta, px, py), tb = along(b.theta, px, py);
      if (ta < a.t_min - prm.delta_px || ta > a.t_max + prm.delta_px) continue;
      if (tb < b.t_min - prm.delta_px || tb > b.t_max + prm.delta_px) continue;
      // At an L corner of two stripes the outer edge runs past the centre-line corner by half the
      // other stripe's width over the sine of their image angle, and buildLines ends a centre
      // line with its longer edge when the two edges' ends disagree; at image angles of 30-40 deg
      // near the camera that is 7-9 px, past delta (bench seed 6: 2 of 124 corners became
      // intersections, their centre lines 8.1-9.0 px past the corner). That overshoot, capped at
      // delta, counts as ending.
      const double sin_ab = std::fabs(det);
      const double over_a = a.marking && b.marking ? std::min(prm.delta_px, 0.5 * b.width / sin_ab) : 0.0;
      const double over_b = a.marking && b.marking ? std::min(prm.delta_px, 0.5 * a.width / sin_ab) : 0.0;
      const bool a_ends = ta < a.t_min + prm.delta_px + over_a || ta > a.t_max - prm.delta_px - over_a;
      const bool b_ends = tb < b.t_min + prm.delta_px + over_b || tb > b.t_max - prm.delta_px - over_b;
      LandmarkType type;
      if (a.marking && b.marking) {
        double ax, ay, bx, by;
        if (!floorDir(a, ax, ay) || !floorDir(b, bx, by)) continue;
        const double ang = std::acos(std::min(1.0, std::fabs(ax * bx + ay * by) / (std::hypot(ax, ay) * std::hypot(bx, by))));
        if (a_ends && b_ends) {
          if (std::fabs(ang - kPi / 2) > deg(prm.corner_angle_tol_deg)) continue;
          // Both stripes must reach the corner; each is probed from beyond the other stripe.
          if (luma && (!stripeReaches(*luma, a, ta, prm.probe_start_px + 0.5 * b.width / sin_ab, prm) ||
                       !stripeReaches(*luma, b, tb, prm.probe_start_px + 0.5 * a.width / sin_ab, prm)))
            continue;
          type = LandmarkType::MarkingCorner;
        } else if (!a_ends && !b_ends) {
          if (ang < deg(prm.min_crossing_angle_deg)) continue;
          type = LandmarkType::Intersection;
        } else {
          continue;
        }
      } else {
        const LineFeature& m = a.marking ? a : b;
        const LineFeature& o = a.marking ? b : a;
        const bool m_ends = a.marking ? a_ends : b_ends;
        if (!o.wall_foot || !m_ends) continue;
        // The marking must lie on the floor side of the wall foot: below the foot's line at the
        // marking's middle column. (Comparing with the junction's row instead rejected far
        // markings that run nearly parallel to the image rows and slope up towards the wall.)
        const double tm = 0.5 * (m.t_min + m.t_max), mx = m.x(tm), my = m.y(tm);
        const double so = std::sin(o.theta);
        if (std::fabs(so) < 1e-9 || my < (o.rho - mx * std::cos(o.theta)) / so) continue;
        // The stripe must run up to the wall foot (a T, Algorithm 4), not stop short of it.
        if (luma && !stripeReaches(*luma, m, a.marking ? ta : tb, prm.probe_start_px, prm)) continue;
        type = LandmarkType::Junction;
      }
      // Average with an existing feature of the same type nearby (3+ lines meeting).
      bool merged = false;
      for (size_t k = 0; k < features.size(); ++k) {
        PointFeature& f = features[k];
        if (f.type != type || std::hypot(f.u - px, f.v - py) > prm.merge_px) continue;
        const double n = counts[k];
        f.u = (f.u * n + px) / (n + 1);
        f.v = (f.v * n + py) / (n + 1);
        ++counts[k];
        merged = true;
        break;
      }
      if (merged) continue;
      PointFeature f;
      f.type = type;
      f.u = px;
      f.v = py;
      f.line_a = static_cast<int>(i);
      f.line_b = static_cast<int>(j);
      features.push_back(f);
      counts.push_back(1);
    }
  }
}

}  // namespace stereoloc::frontend
