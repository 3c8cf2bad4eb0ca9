#include "frontend/corners.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <utility>

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

// The sine of the angle from line a to line b (their unit normals' cross product).
double crossSin(const LineFeature& a, const LineFeature& b) {
  return std::cos(a.theta) * std::sin(b.theta) - std::sin(a.theta) * std::cos(b.theta);
}

// The crossing (u, v) of lines a and b (3.12, 3.13); false when they are closer to parallel
// than |sin| = min_sin.
bool crossLines(const LineFeature& a, const LineFeature& b, double min_sin, double& u, double& v) {
  const double det = crossSin(a, b);
  if (std::fabs(det) < min_sin) return false;
  u = (a.rho * std::sin(b.theta) - b.rho * std::sin(a.theta)) / det;
  v = (b.rho * std::cos(a.theta) - a.rho * std::cos(b.theta)) / det;
  return std::isfinite(u) && std::isfinite(v);
}

// The line through q0 and q1 (distinct), with the stripe attributes of `like` and its extent
// carried over (its ends projected onto the new line).
LineFeature lineThrough(const Eigen::Vector2d& q0, const Eigen::Vector2d& q1, const LineFeature& like) {
  const Eigen::Vector2d d = (q1 - q0).normalized();
  LineFeature l = like;
  // Direction (-sin theta, cos theta), theta folded into [0, pi).
  undirect(std::atan2(-d.x(), d.y()) + (d.x() > 0 ? 2.0 * kPi : 0.0), 0.0, l.theta, l.rho);
  l.rho = q0.x() * std::cos(l.theta) + q0.y() * std::sin(l.theta);
  const double t0 = along(l.theta, like.x(like.t_min), like.y(like.t_min));
  const double t1 = along(l.theta, like.x(like.t_max), like.y(like.t_max));
  l.t_min = std::min(t0, t1);
  l.t_max = std::max(t0, t1);
  return l;
}

// The interval [lo, hi] of the line parameter t where the line lies inside the image (pixel
// centres at integers, so the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5]); lo > hi when the
// line misses the image.
std::pair<double, double> imageInterval(const LineFeature& l, int width, int height) {
  return lineBoxInterval(l.rho, l.theta, -0.5, -0.5, width - 0.5, height - 0.5);
}

// The left camera's centre o and the point one unit along its ray through pixel (u, v), in the
// robot frame C0 at head pan 0 (mm): the ray is o + s (p - o).
void leftCameraRay(const StereoRig& rig, double u, double v, Eigen::Vector3d& o, Eigen::Vector3d& p) {
  const double f = rig.focal(), b = rig.params().baseline_mm;
  o = rig.visionToRobot(Eigen::Vector3d(0.0, 0.5 * b, 0.0), 0.0);
  p = rig.visionToRobot(Eigen::Vector3d(1.0, 0.5 * b - (u - rig.principalU()) / f, -(v - rig.principalV()) / f), 0.0);
}

// The row midway on the floor between rows va and vb of one image column, both below the horizon
// row v_h: a column is the image of a floor line running to the horizon, along which
// 1 / (v - v_h) is affine in distance, so the midpoint is the harmonic mean of v - v_h. Rows
// at or just below the horizon (no usable floor) fall back to the mean.
double floorMidRow(double va, double vb, double v_h) {
  const double da = va - v_h, db = vb - v_h;
  return da > 0.5 && db > 0.5 ? v_h + 2.0 * da * db / (da + db) : 0.5 * (va + vb);
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

// References from the middle of line m's extent, where the stripe is what the line was fitted
// to and its width is the measured one: floor luma (the darker of the two sides at
// +-(0.5 width + side) across: the floor even where the other side touches a wall or another
// stripe) and the stripe's contrast over it on the centre line, medians of 5 samples 2 px apart
// (robust to a sample on a crossing line or an occluder). A line known only to within `search`
// px takes the brightest sample within that of the centre line, and its floor that much further
// out. False without a visible stripe (contrast below 4 grey levels) or with samples outside the
// image.
bool stripeReference(const cv::Mat& luma, const LineFeature& m, double side, double& floor_ref, double& contrast,
                     double search = 0.0) {
  const double tm = 0.5 * (m.t_min + m.t_max), half = 0.5 * (m.t_max - m.t_min);
  const double nx = std::cos(m.theta), ny = std::sin(m.theta), off = 0.5 * m.width + side + search;
  double cs[5], fs[5];
  int n = 0;
  for (int k = -2; k <= 2; ++k) {
    const double t = tm + std::clamp(2.0 * k, -half, half), cx = nx * m.rho - t * ny, cy = ny * m.rho + t * nx;
    double c = lumaAt(luma, cx, cy);
    for (double h = 0.5; h <= search && c >= 0; h += 0.5) {
      const double below = lumaAt(luma, cx - h * nx, cy - h * ny), above = lumaAt(luma, cx + h * nx, cy + h * ny);
      c = below < 0 || above < 0 ? -1.0 : std::max({c, below, above});
    }
    const double l = lumaAt(luma, cx - off * nx, cy - off * ny), r = lumaAt(luma, cx + off * nx, cy + off * ny);
    if (c < 0 || l < 0 || r < 0) continue;
    cs[n] = c;
    fs[n] = std::min(l, r);
    ++n;
  }
  if (n < 3) return false;
  std::nth_element(cs, cs + n / 2, cs + n);
  std::nth_element(fs, fs + n / 2, fs + n);
  floor_ref = fs[n / 2];
  contrast = cs[n / 2] - floor_ref;
  return contrast >= 4.0;
}

}  // namespace

bool stripeReaches(const cv::Mat& luma, const LineFeature& m, double tp, double s0, const CornerParams& prm) {
  if (prm.probe_min_run <= 0) return true;
  // Near the point only the centre line is sampled: a near stripe widens towards the camera
  // (seed 6: 14.5 px at a corner whose line's median width was 9.1 px), so side samples there
  // can fall inside it.
  double floor_ref, contrast;
  if (!stripeReference(luma, m, prm.probe_side_px, floor_ref, contrast)) return true;  // no verdict
  const double tm = 0.5 * (m.t_min + m.t_max);
  const double dark = floor_ref + prm.probe_dark_fraction * contrast;
  const double dir = tm >= tp ? 1.0 : -1.0;
  const double reach = std::min(prm.delta_px, std::fabs(tm - tp));
  const double nx = std::cos(m.theta), ny = std::sin(m.theta);
  int run = 0;
  for (double s = s0; s <= reach; s += 1.0) {
    const double t = tp + dir * s, c = lumaAt(luma, nx * m.rho - t * ny, ny * m.rho + t * nx);
    if (c < 0) {
      run = 0;
      continue;
    }
    run = c < dark ? run + 1 : 0;
    if (run >= prm.probe_min_run) return false;
  }
  return true;
}

namespace {

// One luma profile along t in [t0, t1] (step 0.5 px) of the line parallel to m at lateral offset
// h (px, signed along m's normal). Runs of samples above floor + min_rise / 2 that touch the
// window's ends are steps (a wall beyond a wall foot) or stripes along the window, not a
// crossing; of the others exactly one must rise above floor + min_rise. Returns the centre of
// that bump (the midpoint of its half-height crossings), or NaN: no such bump, two of them,
// or samples outside the image.
double bumpCentre(const cv::Mat& luma, const LineFeature& m, double h, double t0, double t1, double floor_ref,
                  double min_rise, double& width) {
  constexpr int kMax = 96;
  double val[kMax];
  const int n = std::min(kMax, static_cast<int>((t1 - t0) / 0.5) + 1);
  // A straight profile lies inside the image when both its ends do; then no per-sample check.
  const double nx = std::cos(m.theta), ny = std::sin(m.theta);
  const double x0 = nx * (m.rho + h) - t0 * ny, y0 = ny * (m.rho + h) + t0 * nx, dx = -0.5 * ny, dy = 0.5 * nx;
  const double xe = x0 + (n - 1) * dx, ye = y0 + (n - 1) * dy;
  if (std::min(x0, xe) < 0 || std::min(y0, ye) < 0 || std::max(x0, xe) >= luma.cols - 1 || std::max(y0, ye) >= luma.rows - 1)
    return std::nan("");
  for (int k = 0; k < n; ++k) {
    const double x = x0 + k * dx, y = y0 + k * dy;
    const int xi = static_cast<int>(x), yi = static_cast<int>(y);
    const double fx = x - xi, fy = y - yi;
    const uint8_t* r0 = luma.ptr<uint8_t>(yi) + xi;
    const uint8_t* r1 = r0 + luma.step[0];
    val[k] = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  }
  const double level = floor_ref + 0.5 * min_rise;
  int found = 0, best = -1;
  for (int k = 0; k < n;) {
    if (val[k] < level) {
      ++k;
      continue;
    }
    int e = k, top = k;
    while (e + 1 < n && val[e + 1] >= level) {
      ++e;
      if (val[e] > val[top]) top = e;
    }
    if (k > 0 && e < n - 1 && val[top] >= floor_ref + min_rise) {
      ++found;
      best = top;
    }
    k = e + 1;
  }
  if (found != 1) return std::nan("");
  const double half = 0.5 * (val[best] + floor_ref);
  int lo = best, hi = best;
  while (lo > 0 && val[lo - 1] >= half) --lo;
  while (hi < n - 1 && val[hi + 1] >= half) ++hi;
  if (lo == 0 || hi == n - 1) return std::nan("");
  // Sub-sample crossings by linear interpolation.
  const double a = (lo - 1) + (half - val[lo - 1]) / std::max(1e-9, val[lo] - val[lo - 1]);
  const double b = hi + (val[hi] - half) / std::max(1e-9, val[hi] - val[hi + 1]);
  width = 0.5 * (b - a);
  return t0 + 0.5 * 0.5 * (a + b);
}

// The centre of stripe l where the image row (along_rows) or column through (x, y) crosses it,
// as a point, from the half-height crossings of one luma profile of +-reach px about (x, y);
// false when the profile shows no single bump. A row is the image of a floor line parallel to
// the horizon, along which the projection is affine: the centre is midway between the
// crossings. A column is the image of a floor line running to the horizon (row v_h): the
// centre is floorMidRow of the crossings (as in buildLines).
bool stripeCentreOnProfile(const cv::Mat& luma, bool along_rows, double v_h, double x, double y, double reach,
                           double floor_ref, double min_rise, Eigen::Vector2d& centre) {
  LineFeature profile;  // the row or column through (x, y), line coordinate = x or y
  profile.theta = along_rows ? 1.5 * kPi : 0.0;
  profile.rho = along_rows ? -y : x;
  const double c0 = along_rows ? x : y;
  double width = 0;
  const double c = bumpCentre(luma, profile, 0.0, c0 - reach, c0 + reach, floor_ref, min_rise, width);
  if (std::isnan(c)) return false;
  if (along_rows) {
    centre = Eigen::Vector2d(c, y);
    return true;
  }
  centre = Eigen::Vector2d(x, floorMidRow(c - 0.5 * width, c + 0.5 * width, v_h));
  return true;
}

// The local line of stripe l near its crossing with stripe o at l's coordinate tp: offset c0
// along l's normal at tp and slope c1 (see refineCrossing in corners.h).
bool crossingNear(const cv::Mat& luma, const LineFeature& l, const LineFeature& o, double v_h, double tp, double max_offset,
                  double& c0, double& c1) {
  // The stripe's floor and contrast where its profiles are, away from the crossing (the middle
  // of a short extent can be the crossing itself, where the other stripe brightens the floor).
  // A curved stripe leaves its fitted line on one side first: the side of higher contrast.
  double floor_ref = 0, contrast = 0;
  for (const double dir : {1.0, -1.0}) {
    LineFeature part = l;
    part.t_min = std::max(l.t_min, std::min(tp + dir * 8.0, tp + dir * 32.0));
    part.t_max = std::min(l.t_max, std::max(tp + dir * 8.0, tp + dir * 32.0));
    double f, c;
    if (part.t_max - part.t_min >= 8.0 && stripeReference(luma, part, 2.0, f, c, max_offset - 2.0) && c > contrast) {
      floor_ref = f;
      contrast = c;
    }
  }
  if (contrast <= 0) return false;
  constexpr int kPerSide = 8;
  const double nx = std::cos(l.theta), ny = std::sin(l.theta);
  const bool along_rows = std::fabs(nx) >= std::fabs(ny);
  const double reach = (0.5 * std::max(l.width, 2.0) + 1.0 + max_offset) / std::max(std::fabs(nx), std::fabs(ny));
  const double ox = std::cos(o.theta), oy = std::sin(o.theta), o_clear = 0.5 * std::max(o.width, 2.0) + 1.0;
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  Eigen::Vector3d Atb = Eigen::Vector3d::Zero();
  int side_count[2] = {0, 0};
  for (int side = 0; side < 2; ++side) {
    const double dir = side == 0 ? -1.0 : 1.0;
    for (double s = 1.0; s <= 40.0 && side_count[side] < kPerSide; s += 1.0) {
      const double t = tp + dir * s;
      if (t < l.t_min || t > l.t_max) break;
      const double x = l.x(t), y = l.y(t);
      // The whole profile must stay clear of the other stripe, on one side of it.
      const double ex = along_rows ? reach : 0.0, ey = along_rows ? 0.0 : reach;
      const double d0 = (x - ex) * ox + (y - ey) * oy - o.rho, d1 = (x + ex) * ox + (y + ey) * oy - o.rho;
      if (d0 * d1 <= 0 || std::min(std::fabs(d0), std::fabs(d1)) < o_clear) continue;
      Eigen::Vector2d c;
      if (!stripeCentreOnProfile(luma, along_rows, v_h, x, y, reach, floor_ref, 0.5 * contrast, c)) continue;
      const double h = c.x() * nx + c.y() * ny - l.rho, tc = along(l.theta, c.x(), c.y()) - tp;
      if (std::fabs(h) > max_offset) continue;
      const Eigen::Vector3d a(1.0, tc, tc * tc);
      AtA += a * a.transpose();
      Atb += a * h;
      ++side_count[side];
    }
  }
  if (side_count[0] < 3 || side_count[1] < 3) return false;
  const Eigen::Vector3d c = AtA.ldlt().solve(Atb);
  c0 = c[0];
  c1 = c[1];
  return std::isfinite(c0) && std::isfinite(c1);
}

}  // namespace

double horizonRow(const StereoRig& rig) {
  // The ray's climb is linear in the row (no roll): the horizon is where it is zero.
  auto dz = [&](double v) {
    Eigen::Vector3d o, p;
    leftCameraRay(rig, rig.principalU(), v, o, p);
    return p.z() - o.z();
  };
  const double d0 = dz(rig.principalV()), slope = dz(rig.principalV() + 1.0) - d0;
  return rig.principalV() - d0 / slope;
}

namespace {

// Each line near the crossing (u, v) re-measured on the image (crossingNear, profiles within
// max_offset px of the line) and returned as a local line; false when a stripe has too few
// profiles.
bool localLines(const cv::Mat& luma, const LineFeature& a, const LineFeature& b, double horizon_row, double u, double v,
                double max_offset, LineFeature local[2]) {
  const LineFeature* ls[2] = {&a, &b};
  for (int i = 0; i < 2; ++i) {
    const LineFeature& l = *ls[i];
    const double tp = along(l.theta, u, v);
    double c0, c1;
    if (!crossingNear(luma, l, *ls[1 - i], horizon_row, tp, max_offset, c0, c1)) return false;
    // The point at offset c0 along the normal from l's point at the crossing, and direction
    // (l's direction + c1 normal).
    const Eigen::Vector2d n(std::cos(l.theta), std::sin(l.theta)), d(-std::sin(l.theta), std::cos(l.theta));
    const Eigen::Vector2d q = Eigen::Vector2d(l.x(tp), l.y(tp)) + c0 * n, dir = d + c1 * n;
    local[i] = lineThrough(q, q + dir, l);
  }
  return true;
}

}  // namespace

bool refineCrossing(const cv::Mat& luma, const LineFeature& a, const LineFeature& b, double horizon_row, double& u,
                    double& v) {
  if (std::fabs(crossSin(a, b)) < 1e-3) return false;
  LineFeature local[2];
  double pu, pv;
  if (!localLines(luma, a, b, horizon_row, u, v, 2.0, local) || !crossLines(local[0], local[1], 1e-3, pu, pv))
    return false;
  if (std::hypot(pu - u, pv - v) > 2.0) return false;
  u = pu;
  v = pv;
  return true;
}

bool crossingInRightImage(const cv::Mat& right_luma, const StereoRig& rig, const LineFeature& a, const LineFeature& b,
                          double u_left, double v_left, double& u_right, double& v_right) {
  // The right image of a floor line: each point's floor point projected into the right camera,
  // then moved along the row so that the crossing lands on the match (whose column the floor
  // model may miss by a calibration error).
  double xc, yc;
  if (!floorPoint(rig, u_left, v_left, xc, yc)) return false;
  const auto pc = rig.project(Eigen::Vector3d(xc, yc, 0.0), 0.0);
  if (!pc) return false;
  const double shift = u_right - pc->u_right;
  auto toRight = [&](double u, double v, Eigen::Vector2d& q) {
    double x, y;
    if (!floorPoint(rig, u, v, x, y)) return false;
    const auto p = rig.project(Eigen::Vector3d(x, y, 0.0), 0.0);
    if (!p) return false;
    q = Eigen::Vector2d(p->u_right + shift, p->v_right);
    return true;
  };
  LineFeature right[2];
  const LineFeature* ls[2] = {&a, &b};
  for (int i = 0; i < 2; ++i) {
    const LineFeature& l = *ls[i];
    const double tp = along(l.theta, u_left, v_left);
    Eigen::Vector2d q0, q1;
    if (!toRight(l.x(tp - 8.0), l.y(tp - 8.0), q0) || !toRight(l.x(tp + 8.0), l.y(tp + 8.0), q1)) return false;
    right[i] = lineThrough(q0, q1, l);
    // The extent: 40 px either side of the match (the profiles' reach), within the left's ends
    // carried over where they have a floor point.
    const double tr = along(right[i].theta, u_right, v_left);
    right[i].t_min = tr - 40.0;
    right[i].t_max = tr + 40.0;
    Eigen::Vector2d e;
    for (const double te : {l.t_min, l.t_max})
      if (toRight(l.x(te), l.y(te), e)) {
        const double t = along(right[i].theta, e.x(), e.y());
        if (t < tr) right[i].t_min = std::max(right[i].t_min, t);
        else right[i].t_max = std::min(right[i].t_max, t);
      }
  }
  const double v_h = horizonRow(rig);
  double u = u_right, v = v_left;
  // The rows of a rectified pair may be misaligned by a px or two (calibration errors), which
  // moves a flat stripe as far across itself: a first pass within 4 px, then the tight one.
  LineFeature coarse[2];
  if (!localLines(right_luma, right[0], right[1], v_h, u, v, 4.0, coarse) || !crossLines(coarse[0], coarse[1], 1e-3, u, v))
    return false;
  if (std::hypot(u - u_right, v - v_left) > 4.0) return false;
  if (!refineCrossing(right_luma, coarse[0], coarse[1], v_h, u, v)) return false;
  if (std::hypot(u - u_right, v - v_left) > 4.0) return false;
  u_right = u;
  v_right = v;
  return true;
}

bool probeMissingArm(const cv::Mat& luma, const StereoRig& rig, const LineFeature& m, bool at_max_end,
                     const CornerParams& prm, double& u, double& v, double* arm_dx, double* arm_dy) {
  if (prm.arm_length_px <= 0 || !m.marking) return false;
  double floor_ref, contrast;
  if (!stripeReference(luma, m, prm.probe_side_px, floor_ref, contrast)) return false;
  const double te = at_max_end ? m.t_max : m.t_min, out = at_max_end ? 1.0 : -1.0;
  // The arm's image direction: perpendicular to m on the floor, at m's end.
  double x0, y0, x1, y1;
  const double t_in = te - out * std::min(10.0, 0.5 * (m.t_max - m.t_min));
  if (!floorPoint(rig, m.x(te), m.y(te), x0, y0) || !floorPoint(rig, m.x(t_in), m.y(t_in), x1, y1)) return false;
  const double fl = std::hypot(x0 - x1, y0 - y1);
  if (fl < 1e-6) return false;
  const double gx = -(y0 - y1) / fl, gy = (x0 - x1) / fl;  // floor perpendicular
  const auto q = rig.project(Eigen::Vector3d(x0 + 20.0 * gx, y0 + 20.0 * gy, 0.0), 0.0);
  if (!q) return false;
  double ax = q->u_left - m.x(te), ay = q->v_left - m.y(te);
  const double al = std::hypot(ax, ay);
  if (al < 1e-6) return false;
  ax /= al;
  ay /= al;
  const double nx = std::cos(m.theta), ny = std::sin(m.theta), ux = -ny, uy = nx;
  double an = ax * nx + ay * ny;
  if (std::fabs(an) < std::sin(deg(prm.min_image_angle_deg))) return false;
  const double bright = floor_ref + prm.probe_dark_fraction * contrast;
  const double h1 = 0.5 * m.width + 1.5, h2 = h1 + 3.0;
  // snapLineEnds may have moved the end up to snap_px outwards (onto a wall foot past a gap):
  // the window reaches delta + snap_px inwards.
  const double t0 = std::min(te - out * (prm.delta_px + prm.snap_px), te + out * prm.delta_px);
  const double t1 = std::max(te - out * (prm.delta_px + prm.snap_px), te + out * prm.delta_px);
  int found = 0;
  double tc = 0, sax = 0, say = 0, arm_w = 0;
  for (const double side : {1.0, -1.0}) {
    // The arm on this side of m: direction a with a . n of the side's sign.
    const double sx = an * side > 0 ? ax : -ax, sy = an * side > 0 ? ay : -ay;
    const double cot = (sx * ux + sy * uy) / std::fabs(an);  // t advance per px of lateral offset
    double w1 = 0, w2 = 0;
    const double c1 = bumpCentre(luma, m, side * h1, t0 + h1 * cot, t1 + h1 * cot, floor_ref, prm.arm_min_contrast * contrast, w1);
    if (std::isnan(c1)) continue;  // most free ends: no arm, one profile per side
    const double c2 = bumpCentre(luma, m, side * h2, t0 + h2 * cot, t1 + h2 * cot, floor_ref, prm.arm_min_contrast * contrast, w2);
    if (std::isnan(c2)) continue;
    const double tc1 = c1 - h1 * cot, tc2 = c2 - h2 * cot;
    if (std::fabs(tc1 - tc2) > 1.5) continue;
    ++found;
    arm_w = 0.5 * (w1 + w2) * std::fabs(an);  // across the arm
    tc = 0.5 * (tc1 + tc2);
    sax = sx;
    say = sy;
  }
  if (found != 1) return false;  // none, or an arm on both sides (m meets a crossing line: a T)
  // The arm stays a stripe beyond the profiles, along its expected direction: bright on its
  // centre line and floor on at least one side (a wall face is bright across; a stripe running
  // up to a wall foot has the wall on one side near its end).
  const double cx = m.x(tc), cy = m.y(tc), step = 1.0 / std::fabs(an);  // px along a per px across
  const double off = 0.5 * arm_w + prm.probe_side_px;
  int dark = 0, n = 0;
  for (double s = (h2 + 2.0) * step; s <= (h2 + 2.0) * step + prm.arm_length_px; s += 2.0) {
    const double x = cx + s * sax, y = cy + s * say;
    const double c = lumaAt(luma, x, y), l = lumaAt(luma, x - off * say, y + off * sax), r = lumaAt(luma, x + off * say, y - off * sax);
    if (c < 0 || l < 0 || r < 0) break;
    ++n;
    dark += c < bright || (l >= bright && r >= bright) ? 1 : 0;
  }
  if (n < 3 || dark > 1) return false;
  // Nothing continues the arm across m: an L, not a T of m into a crossing line (the centre
  // circle meeting the halfway line).
  int lit = 0;
  for (const double hh : {h1, h2, h2 + 2.0}) {
    const double c = lumaAt(luma, cx - hh * step * sax, cy - hh * step * say);
    lit += c >= bright ? 1 : 0;
  }
  if (lit >= 2) return false;
  // m ends at the arm: the arm's width is unknown, so somewhere between 2 px and delta past the
  // corner m's centre line must drop to the floor (a stripe running on stays bright).
  bool ends = false;
  for (double s = 2.0; s <= prm.delta_px; s += 1.0) {
    const double t = tc + out * s, c = lumaAt(luma, m.x(t) , m.y(t));
    if (c >= 0 && c < bright) {
      ends = true;
      break;
    }
  }
  if (!ends) return false;
  u = cx;
  v = cy;
  if (arm_dx) *arm_dx = sax;
  if (arm_dy) *arm_dy = say;
  return true;
}

bool floorPoint(const StereoRig& rig, double u, double v, double& x, double& y) {
  Eigen::Vector3d o, p;
  leftCameraRay(rig, u, v, o, p);
  const double dz = p.z() - o.z();
  if (!(dz < -1e-9)) return false;
  const double s = -o.z() / dz;
  x = o.x() + s * (p.x() - o.x());
  y = o.y() + s * (p.y() - o.y());
  return true;
}

namespace {

// A segment's line: a marking's edge moved to its centre line, with its extent along it.
LineFeature lineOfSegment(const Segment& s, int source, const CornerParams& prm) {
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
  l.source = source;
  return l;
}

// The other edge of marking line i's stripe: a later marking line of opposite gradient on nearly
// the same centre line that overlaps it along its length; lines.size() for none. cos_l, sin_l:
// each line's cos and sin of theta.
// With piece_gap_px > 0 the partner is the opposite edge that overlaps this one the most: a
// stripe whose one edge is broken by an occluder has several opposite pieces, and the first
// one found may be a short piece beyond the occluder, leaving the long piece to become a
// second centre line.
size_t oppositeEdge(size_t i, const std::vector<Segment>& segments, const std::vector<LineFeature>& lines,
                    const std::vector<double>& cos_l, const std::vector<double>& sin_l,
                    const std::vector<uint8_t>& gone, const CornerParams& prm) {
  const double opposite_cos = -std::cos(deg(prm.centre_merge_deg));
  const Segment& a = segments[i];
  size_t best = lines.size();
  double best_overlap = -1e30;
  for (size_t j = i + 1; j < lines.size(); ++j) {
    if (!lines[j].marking || gone[j]) continue;
    const Segment& b = segments[j];
    if (std::cos(a.theta - b.theta) > opposite_cos) continue;
    const LineFeature& li = lines[i];
    const LineFeature& lj = lines[j];
    auto xi = [&](double t) { return li.rho * cos_l[i] - t * sin_l[i]; };            // li.x(t)
    auto yi = [&](double t) { return li.rho * sin_l[i] + t * cos_l[i]; };            // li.y(t)
    auto alongJ = [&](double x, double y) { return -x * sin_l[j] + y * cos_l[j]; };  // along(lj.theta, x, y)
    const double tol = std::max(prm.centre_merge_px, 0.5 * std::max(a.marking_width, b.marking_width));
    const double tm = 0.5 * (li.t_min + li.t_max);
    if (std::fabs(xi(tm) * cos_l[j] + yi(tm) * sin_l[j] - lj.rho) > tol) continue;
    const double u0 = alongJ(xi(li.t_min), yi(li.t_min)), u1 = alongJ(xi(li.t_max), yi(li.t_max));
    if (std::max(u0, u1) < lj.t_min - prm.delta_px || std::min(u0, u1) > lj.t_max + prm.delta_px) continue;
    if (prm.piece_gap_px <= 0) return j;  // pieces off: the first opposite edge found
    const double overlap = std::min(std::max(u0, u1), lj.t_max) - std::max(std::min(u0, u1), lj.t_min);
    if (overlap > best_overlap) {
      best_overlap = overlap;
      best = j;
    }
  }
  return best;
}

// The centre line of the stripe whose edges are segments a and b (lines li and lj), with li's
// other fields. v_h: the horizon's row.
// Midpoints of corresponding edge points. An image row is the image of a floor line
// parallel to the horizon, along which the projection is affine: a steep stripe's centre
// is midway between its edges along the row. A flat stripe is crossed along the column,
// the image of a floor line towards the horizon: there the centre is floorMidRow. The
// perpendicular midpoints (the edges' bisector) miss the centre line by up to 0.3 px on
// a stripe seen at the side of the image, towards the image's centre. The extent still
// comes from the perpendicular midpoints (ex, ey): a row or column runs along a slanted
// stripe, and its midpoint of an edge's end lies up to half a width beyond the stripe's end.
LineFeature stripeCentreLine(const Segment& a, const Segment& b, const LineFeature& li, const LineFeature& lj,
                             double v_h) {
  double mx[4], my[4], ex[4], ey[4];
  int n = 0;
  const bool along_rows = std::fabs(std::cos(a.theta)) >= std::fabs(std::sin(a.theta));
  for (const Segment* p : {&a, &b}) {
    const Segment* q = p == &a ? &b : &a;
    const double qc = std::cos(q->theta), qs = std::sin(q->theta);
    for (int e = 0; e < 2; ++e) {
      const double x = e ? p->x2 : p->x1, y = e ? p->y2 : p->y1;
      const double d = x * qc + y * qs - q->rho;
      ex[n] = x - 0.5 * d * qc;
      ey[n] = y - 0.5 * d * qs;
      if (along_rows) {
        mx[n] = 0.5 * (x + (q->rho - y * qs) / qc);
        my[n] = y;
      } else {
        mx[n] = x;
        my[n] = floorMidRow(y, (q->rho - x * qc) / qs, v_h);
      }
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
    const double v = along(th, ex[k], ey[k]);
    t[0] = std::min(t[0], v);
    t[1] = std::max(t[1], v);
  }
  const double agree = std::max(a.marking_width, b.marking_width) + 1.0;
  m.t_min = std::fabs(ta[0] - tb[0]) <= agree ? 0.5 * (ta[0] + tb[0]) : std::min(ta[0], tb[0]);
  m.t_max = std::fabs(ta[1] - tb[1]) <= agree ? 0.5 * (ta[1] + tb[1]) : std::max(ta[1], tb[1]);
  m.support = li.support + lj.support;
  m.width = std::max(a.marking_width, b.marking_width);
  return m;
}

// Further pieces of either edge of the stripe (segments a = i and b = j) beyond an occluder
// (collinear with it, within piece_gap_px of the stripe's extent) belong to the same stripe:
// they extend its centre line m rather than becoming a second one half a width off. Marks them
// gone.
void absorbStripePieces(size_t i, size_t j, const std::vector<Segment>& segments, const std::vector<LineFeature>& lines,
                        const CornerParams& prm, LineFeature& m, std::vector<uint8_t>& gone) {
  const Segment& a = segments[i];
  const Segment& b = segments[j];
  const double th = m.theta;
  for (size_t k = i + 1; prm.piece_gap_px > 0 && k < lines.size(); ++k) {
    if (k == j || !lines[k].marking || gone[k]) continue;
    const Segment& c = segments[k];
    const Segment& same = std::cos(c.theta - a.theta) > 0 ? a : b;
    if (std::cos(c.theta - same.theta) < std::cos(deg(prm.centre_merge_deg))) continue;
    const double sc = std::cos(same.theta), ss = std::sin(same.theta);
    if (std::fabs(c.x1 * sc + c.y1 * ss - same.rho) > prm.centre_merge_px ||
        std::fabs(c.x2 * sc + c.y2 * ss - same.rho) > prm.centre_merge_px)
      continue;
    const double c0 = along(th, c.x1, c.y1), c1 = along(th, c.x2, c.y2);
    const double lo = std::min(c0, c1), hi = std::max(c0, c1);
    if (lo > m.t_max + prm.piece_gap_px || hi < m.t_min - prm.piece_gap_px) continue;
    m.t_min = std::min(m.t_min, lo);
    m.t_max = std::max(m.t_max, hi);
    m.support += lines[k].support;
    gone[k] = 1;
  }
}

}  // namespace

void buildLines(const std::vector<Segment>& segments, const StereoRig& rig, const CornerParams& prm,
                std::vector<LineFeature>& lines) {
  lines.clear();
  const double v_h = horizonRow(rig);
  for (size_t i = 0; i < segments.size(); ++i) lines.push_back(lineOfSegment(segments[i], static_cast<int>(i), prm));
  // The two edges of one stripe: opposite gradients, nearly the same centre line. Under
  // perspective they converge, and the centre line's image is not their bisector: it is the line
  // through the midpoints of corresponding points (each edge's end points and the point of the
  // other edge on the same floor line across the stripe; stripeCentreLine).
  std::vector<uint8_t> gone(lines.size(), 0);
  // Each line's cos and sin, for the pair tests (the same values LineFeature::x, y and along()
  // compute; a line's theta changes only when it is the merged line i, after its tests).
  std::vector<double> cos_l(lines.size()), sin_l(lines.size());
  for (size_t i = 0; i < lines.size(); ++i) {
    cos_l[i] = std::cos(lines[i].theta);
    sin_l[i] = std::sin(lines[i].theta);
  }
  for (size_t i = 0; i < lines.size(); ++i) {
    if (!lines[i].marking || gone[i]) continue;
    const size_t j = oppositeEdge(i, segments, lines, cos_l, sin_l, gone, prm);
    if (j == lines.size()) continue;
    LineFeature m = stripeCentreLine(segments[i], segments[j], lines[i], lines[j], v_h);
    absorbStripePieces(i, j, segments, lines, prm, m, gone);
    lines[i] = m;
    gone[j] = 1;
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
      double px, py;
      if (!crossLines(a, b, min_sin, px, py)) continue;
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

// True when (x, y) lies above (on the wall side of) a wall foot line, within its extent +- margin.
bool aboveWallFoot(const std::vector<LineFeature>& lines, double x, double y, double margin) {
  for (const LineFeature& o : lines) {
    if (!o.wall_foot) continue;
    const double sn = std::sin(o.theta), t = along(o.theta, x, y);
    if (std::fabs(sn) < 1e-6 || t < o.t_min - margin || t > o.t_max + margin) continue;
    if (y < (o.rho - x * std::cos(o.theta)) / sn - 0.5) return true;
  }
  return false;
}

bool traceArmToWallFoot(const cv::Mat& luma, const std::vector<LineFeature>& lines, const LineFeature& m, double u,
                        double v, double ax, double ay, const CornerParams& prm, double& ju, double& jv) {
  double floor_ref, contrast;
  if (prm.arm_length_px <= 0 || !stripeReference(luma, m, prm.probe_side_px, floor_ref, contrast)) return false;
  const double bright = floor_ref + prm.probe_dark_fraction * contrast;
  // The nearest wall foot the arm crosses (within its extent) is where it must end; a wall face
  // is bright too, so a farther foot (a wall or goal top) could be reached through it.
  const LineFeature* foot = nullptr;
  double best = 1e30;
  for (const LineFeature& o : lines) {
    if (!o.wall_foot) continue;
    const double c = std::cos(o.theta), sn = std::sin(o.theta);
    const double den = ax * c + ay * sn;
    if (std::fabs(den) < std::sin(deg(prm.min_image_angle_deg))) continue;
    const double s = (o.rho - u * c - v * sn) / den;  // px along the arm to the foot
    if (s <= 0 || s >= best) continue;
    const double t = along(o.theta, u + s * ax, v + s * ay);
    if (t < o.t_min - prm.delta_px || t > o.t_max + prm.delta_px) continue;
    best = s;
    foot = &o;
  }
  if (!foot || best <= prm.delta_px) return false;
  const double s = best, px = u + s * ax, py = v + s * ay;
  // Bright from the corner's profiles up to the foot: one dark sample in eight allowed, and the
  // last 1.5-2.5 px before the foot bright (the stripe probe's rule).
  int n = 0, dark = 0;
  for (double q = 0.5 * m.width + 4.0; q <= s - 1.5; q += 2.0) {
    const double l = lumaAt(luma, u + q * ax, v + q * ay);
    if (l < 0) return false;
    ++n;
    dark += l < bright ? 1 : 0;
  }
  if (n < 3 || 8 * dark > n) return false;
  if (lumaAt(luma, px - 1.5 * ax, py - 1.5 * ay) < bright || lumaAt(luma, px - 2.5 * ax, py - 2.5 * ay) < bright)
    return false;
  ju = px;
  jv = py;
  return true;
}

// True unless the edge o, taken for a wall foot, has no wall above it at (x, y): the luma
// wall_min_height_px - 1 and wall_min_height_px above o (along its normal, upwards) must be
// brighter than the floor by probe_dark_fraction of marking m's contrast. The lower edge of a
// thin far marking whose upper edge was not found is bright above and dark below too; 2-3 px
// above it is floor again. Also true when the probe cannot judge.
bool wallAbove(const cv::Mat& luma, const LineFeature& m, const LineFeature& o, double x, double y,
               const CornerParams& prm) {
  if (prm.wall_min_height_px <= 0) return true;
  double floor_ref, contrast;
  if (!stripeReference(luma, m, prm.probe_side_px, floor_ref, contrast)) return true;
  double nx = std::cos(o.theta), ny = std::sin(o.theta);
  if (ny > 0) {
    nx = -nx;
    ny = -ny;
  }
  const double bright = floor_ref + prm.probe_dark_fraction * contrast;
  for (const double d : {prm.wall_min_height_px - 1.0, prm.wall_min_height_px}) {
    const double l = lumaAt(luma, x + d * nx, y + d * ny);
    if (l >= 0 && l < bright) return false;
  }
  return true;
}

namespace {

// The direction of line l's extent on the floor (mm); false where an end is above the horizon
// or the extent has no length there.
bool floorDirection(const StereoRig& rig, const LineFeature& l, double& dx, double& dy) {
  double xa, ya, xb, yb;
  if (!floorPoint(rig, l.x(l.t_min), l.y(l.t_min), xa, ya) || !floorPoint(rig, l.x(l.t_max), l.y(l.t_max), xb, yb))
    return false;
  dx = xb - xa;
  dy = yb - ya;
  return std::hypot(dx, dy) > 1e-6;
}

// The feature where lines a and b meet, if they do inside the image and within delta of both
// extents and the meeting is a marking corner, an intersection, a junction of two markings or
// of a marking and a wall foot (Algorithm 4); its type, image point and whether the point was
// located on the image (an intersection's crossing refined on the luma). luma null: the line
// geometry alone decides.
// The image's size and horizon row (px) and the sine of the smallest image angle of two lines
// that may meet, computed once per image.
struct MeetingLimits {
  double w, h, v_h, min_sin;
};

bool meetingFeature(const LineFeature& a, const LineFeature& b, const StereoRig& rig, const CornerParams& prm,
                    const cv::Mat* luma, const MeetingLimits& limits, PointFeature* out) {
  if (!a.marking && !b.marking) return false;
  const double w = limits.w, h = limits.h, v_h = limits.v_h, min_sin = limits.min_sin;
  double px, py;
  if (!crossLines(a, b, min_sin, px, py)) return false;
  if (px < 0 || py < 0 || px > w - 1 || py > h - 1) return false;
  const double ta = along(a.theta, px, py), tb = along(b.theta, px, py);
  if (ta < a.t_min - prm.delta_px || ta > a.t_max + prm.delta_px) return false;
  if (tb < b.t_min - prm.delta_px || tb > b.t_max + prm.delta_px) return false;
  // At an L corner of two stripes the outer edge runs past the centre-line corner by half the
  // other stripe's width over the sine of their image angle, and buildLines ends a centre
  // line with its longer edge when the two edges' ends disagree; at image angles of 30-40 deg
  // near the camera that is 7-9 px, past delta (bench seed 6: 2 of 124 corners became
  // intersections, their centre lines 8.1-9.0 px past the corner). That overshoot, capped at
  // delta, counts as ending.
  const double sin_ab = std::fabs(crossSin(a, b));
  const double over_a = a.marking && b.marking ? std::min(prm.delta_px, 0.5 * b.width / sin_ab) : 0.0;
  const double over_b = a.marking && b.marking ? std::min(prm.delta_px, 0.5 * a.width / sin_ab) : 0.0;
  const bool a_ends = ta < a.t_min + prm.delta_px + over_a || ta > a.t_max - prm.delta_px - over_a;
  const bool b_ends = tb < b.t_min + prm.delta_px + over_b || tb > b.t_max - prm.delta_px - over_b;
  LandmarkType type;
  bool located = false;
  if (a.marking && b.marking) {
    double ax, ay, bx, by;
    if (!floorDirection(rig, a, ax, ay) || !floorDirection(rig, b, bx, by)) return false;
    const double ang =
        std::acos(std::min(1.0, std::fabs(ax * bx + ay * by) / (std::hypot(ax, ay) * std::hypot(bx, by))));
    if (a_ends && b_ends) {
      if (std::fabs(ang - kPi / 2) > deg(prm.corner_angle_tol_deg)) return false;
      // Both stripes must reach the corner; each is probed from beyond the other stripe.
      if (luma && (!stripeReaches(*luma, a, ta, prm.probe_start_px + 0.5 * b.width / sin_ab, prm) ||
                   !stripeReaches(*luma, b, tb, prm.probe_start_px + 0.5 * a.width / sin_ab, prm)))
        return false;
      type = LandmarkType::MarkingCorner;
    } else if (!a_ends && !b_ends) {
      if (ang < deg(prm.min_crossing_angle_deg)) return false;
      type = LandmarkType::Intersection;
      located = luma && refineCrossing(*luma, a, b, v_h, px, py);
    } else if (prm.marking_junctions) {
      // One stripe ends on the other, which runs on: a T of two markings (RoboCup fields'
      // penalty and goal areas, the halfway line on the touch line). Perpendicular on the
      // floor like an L, and the ending stripe must reach the other.
      if (std::fabs(ang - kPi / 2) > deg(prm.corner_angle_tol_deg)) return false;
      const LineFeature& m = a_ends ? a : b;
      const LineFeature& o = a_ends ? b : a;
      if (luma && !stripeReaches(*luma, m, a_ends ? ta : tb, prm.probe_start_px + 0.5 * o.width / sin_ab, prm))
        return false;
      type = LandmarkType::Junction;
    } else {
      return false;
    }
  } else {
    const LineFeature& m = a.marking ? a : b;
    const LineFeature& o = a.marking ? b : a;
    const bool m_ends = a.marking ? a_ends : b_ends;
    if (!o.wall_foot || !m_ends) return false;
    // The marking must lie on the floor side of the wall foot: below the foot's line at the
    // marking's middle column. (Comparing with the junction's row instead rejected far
    // markings that run nearly parallel to the image rows and slope up towards the wall.)
    const double tm = 0.5 * (m.t_min + m.t_max), mx = m.x(tm), my = m.y(tm);
    const double so = std::sin(o.theta);
    if (std::fabs(so) < 1e-9 || my < (o.rho - mx * std::cos(o.theta)) / so) return false;
    // The stripe must run up to the wall foot (a T, Algorithm 4), not stop short of it, and
    // the foot must have a wall above it.
    if (luma && (!stripeReaches(*luma, m, a.marking ? ta : tb, prm.probe_start_px, prm) ||
                 !wallAbove(*luma, m, o, px, py, prm)))
      return false;
    type = LandmarkType::Junction;
  }
  out->type = type;
  out->u = px;
  out->v = py;
  out->located_on_image = located;
  return true;
}

// Free marking ends (no feature within delta, not on the image border): probe for a missing
// arm, and follow a found arm to the wall foot it meets. Run after the pairs so that a corner
// from two found lines is never duplicated.
void probeFreeMarkingEnds(const std::vector<LineFeature>& lines, const StereoRig& rig, const CornerParams& prm,
                          const cv::Mat& luma, std::vector<PointFeature>& features) {
  const double w = rig.params().image_width, h = rig.params().image_height;
  auto near = [&](double x, double y) {
    for (const PointFeature& f : features)
      if (std::hypot(f.u - x, f.v - y) <= prm.delta_px) return true;
    return false;
  };
  for (size_t i = 0; i < lines.size(); ++i) {
    const LineFeature& m = lines[i];
    if (!m.marking) continue;
    const auto [lo, hi] = imageInterval(m, static_cast<int>(w), static_cast<int>(h));
    for (const bool at_max : {false, true}) {
      const double te = at_max ? m.t_max : m.t_min;
      if (te - lo < 0.5 || hi - te < 0.5) continue;  // clipped by the border: no evidence of an end
      if (near(m.x(te), m.y(te))) continue;
      // A feature found by the arm probe: only its marking line is known.
      auto addFeature = [&](LandmarkType type, double fu, double fv) {
        PointFeature f;
        f.type = type;
        f.u = fu;
        f.v = fv;
        f.line_a = static_cast<int>(i);
        features.push_back(f);
      };
      double u, v, ax, ay;
      if (!probeMissingArm(luma, rig, m, at_max, prm, u, v, &ax, &ay)) continue;
      if (u < 0 || v < 0 || u > w - 1 || v > h - 1 || near(u, v)) continue;
      // The arm lies on the floor: the bright face above a wall foot is no arm (seed 5: a
      // marking ending at a wall took the wall for its arm).
      bool on_wall = false;
      for (double q = 0.0; q <= prm.arm_length_px + 8.0 && !on_wall; q += 2.0) on_wall = aboveWallFoot(lines, u + q * ax, v + q * ay, prm.delta_px);
      if (on_wall) continue;
      addFeature(LandmarkType::MarkingCorner, u, v);
      // The arm was not found as a line, so neither was the junction where it meets a wall
      // (seed 5: 3 of the 5 missed junctions, each beside a corner found this way): follow it
      // to the nearest wall foot it crosses, if it stays bright all the way.
      double jx, jy;
      if (traceArmToWallFoot(luma, lines, m, u, v, ax, ay, prm, jx, jy) && !near(jx, jy) && jx >= 0 && jy >= 0 &&
          jx <= w - 1 && jy <= h - 1) {
        addFeature(LandmarkType::Junction, jx, jy);
      }
    }
  }
}

}  // namespace

void findCorners(const std::vector<LineFeature>& lines, const StereoRig& rig, const CornerParams& prm,
                 std::vector<PointFeature>& features, const cv::Mat* luma) {
  features.clear();
  const MeetingLimits limits{static_cast<double>(rig.params().image_width),
                             static_cast<double>(rig.params().image_height), horizonRow(rig),
                             std::sin(deg(prm.min_image_angle_deg))};
  std::vector<int> counts;
  for (size_t i = 0; i < lines.size(); ++i) {
    for (size_t j = i + 1; j < lines.size(); ++j) {
      PointFeature f;
      if (!meetingFeature(lines[i], lines[j], rig, prm, luma, limits, &f)) continue;
      // Average with an existing feature of the same type nearby (3+ lines meeting).
      bool merged = false;
      for (size_t k = 0; k < features.size(); ++k) {
        PointFeature& g = features[k];
        if (g.type != f.type || std::hypot(g.u - f.u, g.v - f.v) > prm.merge_px) continue;
        const double n = counts[k];
        g.u = (g.u * n + f.u) / (n + 1);
        g.v = (g.v * n + f.v) / (n + 1);
        g.located_on_image = g.located_on_image && f.located_on_image;
        ++counts[k];
        merged = true;
        break;
      }
      if (merged) continue;
      f.line_a = static_cast<int>(i);
      f.line_b = static_cast<int>(j);
      features.push_back(f);
      counts.push_back(1);
    }
  }
  if (!luma || prm.arm_length_px <= 0) return;
  probeFreeMarkingEnds(lines, rig, prm, *luma, features);
}

}  // namespace stereoloc::frontend
