// bench_frontend: accuracy of the vision frontend on rendered stereo pairs
// against the renderer's ground truth, then timings (Google Benchmark) of ours against
// cv::HoughLinesP and cv::createLineSegmentDetector on the same images.
//
//   bench_frontend [--pairs=N] [--goal-pairs=M] [--seed=S] [--no-table] [--diag] [benchmark flags]
//   bench_frontend --real=data/real [--stages[=passes]]   (the same table on the labelled photographs; see realTable;
//    matched on the parts outside the don't-care mask, collinear pieces of one stripe count once:
//    ScoreRules; STEREOLOC_BENCH_LABEL_EXTENT=1 matches whole labels and single detections instead)
//   (--diag: per-failure breakdown of the segment matching by reason, kind, length, row, occlusion,
//    luma contrast across the missed truth edge, and recall per truth kind)
//   Environment: STEREOLOC_BENCH_PARAMS=file.yaml scores other frontend parameters;
//   STEREOLOC_BENCH_SAMPLES=n renders with n x n samples per pixel (default 2, the renderer's);
//   STEREOLOC_BENCH_VERBOSE lists every failure; STEREOLOC_BENCH_DUMP=dir writes a few pairs.
//
// Test set (seeded): N general pairs at random poses (uniform on the field, any heading), a
// ball and 0-3 robots at random, half of them with the "bad illumination" of Fig. 6.2
// (darker, less contrast, more noise); M goal pairs looking towards a goal (+-25 deg) from
// random positions, for the goal-corner range statistics (thesis Table 6.3).
//
// Matching rule (the same for every detector): a detected segment matches a ground-truth
// segment when the undirected angle differs by at most 2 deg and both end points are within
// 3 px (either order). The visible pieces of one edge broken by an occluder also match as
// one segment from the first piece's start to the last piece's end (Fig. 6.1 'b'): that
// detection recalls every piece. The same holds for any run of consecutive truth pieces that
// lie closer than Gap_max along one line and whose union is straight to within 1 px (the
// fitting band): Algorithm 2 is specified to merge such collinear pixel groups into one
// segment, and far away the tops of walls, corner triangles and goals form one such
// near-straight silhouette. Ground-truth pieces shorter than L_min (30 px) are
// optional (not counted in recall; a detection of one is correct), and so is an inner top
// edge (wall_top, goal_top, triangle_top) that lies within 1 px of the top_outline silhouette
// over >= 80 % of its length: the top face between them is thinner than a pixel in the image,
// so they are one image edge with the silhouette's ends (see truthSegments; counted and
// printed). Detections on the
// centre circle (not straight, not in the truth) and on obstacles are ignored. The table
// prints how many truth pieces are optional and how many detections were ignored.
// Truth kinds: markings (centre lines), wall/goal feet and inner top edges, goal posts,
// corner triangles, and the top outline of walls and goals (their silhouette against the
// background; src/sim/renderer.h).
// Corner truth follows the segment truth (cornerDetectability): a corner, junction or
// intersection counts in recall only when two of its defining truth lines are themselves
// counted segments (>= L_min, reaching it within delta, at >= min_image_angle in the image);
// the others are listed by reason with their counts, and detections of them are ignored.
// The map's intersections lie on the centre circle, which is not in the segment truth.
// "Centre-line level" compares our output lines (marking centre lines, other edges) with the
// truth as given. "Edge level" compares raw edges: each marking's truth is replaced by its two
// side edges (the centre line moved by +-line_width/2 on the floor, projected), except a stripe
// narrower than 1.5 px in the image, which stays one edge (see kThinStripePx); ours are the
// segments before the centre-line stage. HoughLinesP and LSD are scored at edge level.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <map>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>

#include "frontend/frontend.h"
#include "src/core/error.h"
#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/sim/renderer.h"
#include "src/core/stereo_rig.h"
#include "src/io/image_file.h"

using namespace stereoloc;
using namespace stereoloc::frontend;

namespace {

constexpr double kPi = 3.141592653589793;

struct Pair {
  StereoImages img;
  bool bad_light = false;
  std::vector<Obstacle> obstacles;
};

struct Seg {
  Eigen::Vector2d a, b;
  bool marking = false;
  std::string name;
  bool optional = false;
  std::string kind;     // truth: the renderer's kind; detections: empty
  bool broken = false;  // truth: one of several visible pieces of the same edge (occluded)
};

double segAngle(const Seg& s) { return std::atan2(s.b.y() - s.a.y(), s.b.x() - s.a.x()); }

// The acute angle between the segments' lines (undirected), in [0, pi/2].
double angleBetween(const Seg& a, const Seg& b) {
  double da = std::fabs(segAngle(a) - segAngle(b));
  da = std::fmod(da, kPi);
  return std::min(da, kPi - da);
}

bool matches(const Seg& d, const Seg& g, double* endpoint_err) {
  if (angleBetween(d, g) > 2.0 * kPi / 180) return false;
  const double e1 = (d.a - g.a).norm() + (d.b - g.b).norm(), e2 = (d.a - g.b).norm() + (d.b - g.a).norm();
  const bool direct = e1 <= e2;
  const double ea = direct ? (d.a - g.a).norm() : (d.a - g.b).norm();
  const double eb = direct ? (d.b - g.b).norm() : (d.b - g.a).norm();
  if (ea > 3.0 || eb > 3.0) return false;
  if (endpoint_err) *endpoint_err = 0.5 * (ea + eb);
  return true;
}

// Why segments fail: counts per category (printed with --diag).
struct FailureBreakdown {
  std::map<std::string, long> missed, spurious;
  std::map<std::string, long> misclassified;  // matched edges with the wrong marking label: truth kind, direction, row
  bool verbose = false;  // print every failure (STEREOLOC_BENCH_VERBOSE)
  std::map<std::string, std::pair<long, long>> by_kind;  // truth kind -> (counted truth, recalled)
  cv::Mat luma;  // left luma of the pair being scored (for the contrast of missed truth edges)
};

// Luma step across a truth segment: the mean over its middle 80 % (1 px steps) of the luma
// 1.5 px on one side minus 1.5 px on the other (bilinear), absolute. Sensor noise averages out
// over the samples; a step below the frontend's gradient threshold (48 / 4 = 12 grey levels for
// an ideal step) is not a detectable edge in this image.
double truthContrast(const cv::Mat& luma, const Seg& g) {
  if (luma.empty()) return -1;
  const Eigen::Vector2d d = (g.b - g.a), u = d.normalized(), n(-u.y(), u.x());
  const double len = d.norm();
  auto at = [&](const Eigen::Vector2d& q) {
    const int x0 = static_cast<int>(std::floor(q.x())), y0 = static_cast<int>(std::floor(q.y()));
    if (x0 < 0 || y0 < 0 || x0 + 1 >= luma.cols || y0 + 1 >= luma.rows) return -1.0;
    const double fx = q.x() - x0, fy = q.y() - y0;
    return (1 - fy) * ((1 - fx) * luma.at<uint8_t>(y0, x0) + fx * luma.at<uint8_t>(y0, x0 + 1)) +
           fy * ((1 - fx) * luma.at<uint8_t>(y0 + 1, x0) + fx * luma.at<uint8_t>(y0 + 1, x0 + 1));
  };
  double sum = 0;
  int m = 0;
  for (double t = 0.1 * len; t <= 0.9 * len; t += 1.0) {
    const Eigen::Vector2d q = g.a + t * u;
    const double hi = at(q + 1.5 * n), lo = at(q - 1.5 * n);
    if (hi < 0 || lo < 0) continue;
    sum += hi - lo;
    ++m;
  }
  return m ? std::fabs(sum / m) : -1;
}

std::string contrastBin(double c) {
  return c < 0 ? "unknown" : c < 12 ? "< 12 grey levels" : c < 24 ? "12-24" : c < 48 ? "24-48" : ">= 48";
}

struct SegStats {
  long gt = 0, gt_hit = 0, det = 0, det_ok = 0, matched = 0, class_ok = 0;
  long gt_optional = 0, det_ignored = 0;  // excluded: truth pieces < L_min, detections on don't-care areas
  double endpoint_sum = 0;
  FailureBreakdown* why = nullptr;
  double recall() const { return gt ? double(gt_hit) / gt : 0; }
  double precision() const { return det ? double(det_ok) / det : 0; }
  double f() const { return recall() + precision() > 0 ? 2 * recall() * precision() / (recall() + precision()) : 0; }
  double endpoint() const { return matched ? endpoint_sum / matched : 0; }
};

// Don't-care mask: centre circle and obstacles, projected into the left image.
cv::Mat dontCare(const StereoRig& rig, const FieldMap& map, const Pair& p) {
  cv::Mat mask(rig.params().image_height, rig.params().image_width, CV_8UC1, cv::Scalar(0));
  const Pose2& robot = p.img.truth.robot;
  auto toRobot = [&](const Eigen::Vector3d& w) {
    const Eigen::Vector2d q = transformToLocal(robot, w.head<2>());
    return Eigen::Vector3d(q.x(), q.y(), w.z());
  };
  auto px = [&](const Eigen::Vector3d& w, cv::Point2f& out) {
    const auto q = rig.project(toRobot(w), p.img.truth.head_pan);
    if (!q || q->u_left < -500 || q->u_left > 1000 || q->v_left < -500 || q->v_left > 1000) return false;
    out = cv::Point2f(static_cast<float>(q->u_left), static_cast<float>(q->v_left));
    return true;
  };
  const FieldGeometry g = map.geometry() ? *map.geometry() : FieldGeometry();
  for (double r : {g.centre_circle_radius}) {
    std::vector<cv::Point> pts;
    for (int k = 0; k <= 360; ++k) {
      cv::Point2f q;
      const Eigen::Vector3d w(0.5 * g.length + r * std::cos(k * kPi / 180), 0.5 * g.width + r * std::sin(k * kPi / 180), 0);
      if (px(w, q)) {
        pts.emplace_back(q);
      } else if (pts.size() > 1) {
        cv::polylines(mask, pts, false, cv::Scalar(255), 7);
        pts.clear();
      }
    }
    if (pts.size() > 1) cv::polylines(mask, pts, false, cv::Scalar(255), 7);
  }
  for (const Obstacle& o : p.obstacles) {
    std::vector<cv::Point2f> pts;
    const double h = o.kind == Obstacle::Kind::Ball ? 0.5 * o.size : 0.5 * o.size * std::sqrt(2.0);
    for (int k = 0; k < 16; ++k)
      for (double z : {0.0, o.size}) {
        cv::Point2f q;
        if (px(Eigen::Vector3d(o.position.x() + h * std::cos(k * kPi / 8), o.position.y() + h * std::sin(k * kPi / 8), z), q))
          pts.push_back(q);
      }
    if (pts.size() < 3) continue;
    std::vector<cv::Point2f> hull;
    cv::convexHull(pts, hull);
    std::vector<cv::Point> ih(hull.begin(), hull.end());
    cv::fillConvexPoly(mask, ih, cv::Scalar(255));
    cv::polylines(mask, ih, true, cv::Scalar(255), 5);
  }
  return mask;
}

bool inMask(const cv::Mat& mask, const Seg& s) {
  int in = 0, n = 0;
  for (double t = 0; t <= 1.0; t += 0.1, ++n) {
    const Eigen::Vector2d q = s.a + t * (s.b - s.a);
    const int x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
    if (x >= 0 && y >= 0 && x < mask.cols && y < mask.rows && mask.at<uint8_t>(y, x)) ++in;
  }
  return in * 2 >= n;
}

// Truth at centre-line level (as given) or edge level (markings -> two side edges).
// Edge level, thin markings: a stripe whose image width stays below kThinStripePx is ONE edge
// pair the detector cannot resolve: Sobel's 3x3 support spans both sides, so its two opposite
// gradient lobes lie 1-2 px apart (inside one 3 px rho bin and the NMS neighbourhood) and come
// out as one ridge edge at best. Its truth at edge level is then one segment, the centre line
// (a detection of either side edge lies within the 3 px end-point tolerance of it); counted in
// *thin and printed.
constexpr double kThinStripePx = 1.5;
constexpr double kMergedTopPx = 1.0;     // see truthSegments: inner top edge within this of the silhouette
constexpr double kMergedTopShare = 0.8;  // ... over this share of its length

std::vector<Seg> truthSegments(const StereoRig& rig, const FieldMap& map, const Pair& p, bool edges, double min_len,
                               long* thin = nullptr, long* merged_tops = nullptr) {
  std::vector<Seg> out;
  const double hw = 0.5 * (map.geometry() ? map.geometry()->line_width : 10.0);
  for (const ImageSegment& s : p.img.truth.left.segments) {
    const bool marking = s.kind == "marking";
    const bool broken = std::count_if(p.img.truth.left.segments.begin(), p.img.truth.left.segments.end(),
                                      [&](const ImageSegment& o) { return o.name == s.name && o.kind == s.kind; }) > 1;
    if (!edges || !marking) {
      out.push_back(Seg{s.a, s.b, marking, s.name, (s.b - s.a).norm() < min_len, s.kind, broken});
      continue;
    }
    double ax, ay, bx, by;
    if (!floorPoint(rig, s.a.x(), s.a.y(), ax, ay) || !floorPoint(rig, s.b.x(), s.b.y(), bx, by)) continue;
    const Eigen::Vector2d A(ax, ay), B(bx, by);
    const Eigen::Vector2d n = Eigen::Vector2d(-(B - A).y(), (B - A).x()).normalized();
    {
      const auto qa0 = rig.project(Eigen::Vector3d((A - hw * n).x(), (A - hw * n).y(), 0), 0.0);
      const auto qa1 = rig.project(Eigen::Vector3d((A + hw * n).x(), (A + hw * n).y(), 0), 0.0);
      const auto qb0 = rig.project(Eigen::Vector3d((B - hw * n).x(), (B - hw * n).y(), 0), 0.0);
      const auto qb1 = rig.project(Eigen::Vector3d((B + hw * n).x(), (B + hw * n).y(), 0), 0.0);
      if (qa0 && qa1 && qb0 && qb1) {
        // Image width across the stripe (perpendicular to its image direction) at both ends.
        const Eigen::Vector2d dir = (s.b - s.a).normalized(), nn(-dir.y(), dir.x());
        const double wa = std::fabs(nn.dot(Eigen::Vector2d(qa1->u_left - qa0->u_left, qa1->v_left - qa0->v_left)));
        const double wb = std::fabs(nn.dot(Eigen::Vector2d(qb1->u_left - qb0->u_left, qb1->v_left - qb0->v_left)));
        if (std::max(wa, wb) < kThinStripePx) {
          out.push_back(Seg{s.a, s.b, true, s.name + "_thin", (s.b - s.a).norm() < min_len, s.kind, broken});
          if (thin && !out.back().optional) ++*thin;
          continue;
        }
      }
    }
    for (int side : {-1, 1}) {
      const auto pa = rig.project(Eigen::Vector3d((A + side * hw * n).x(), (A + side * hw * n).y(), 0), 0.0);
      const auto pb = rig.project(Eigen::Vector3d((B + side * hw * n).x(), (B + side * hw * n).y(), 0), 0.0);
      if (!pa || !pb) continue;
      Seg e{Eigen::Vector2d(pa->u_left, pa->v_left), Eigen::Vector2d(pb->u_left, pb->v_left), true,
            s.name + (side < 0 ? "_a" : "_b"), false, s.kind, broken};
      e.optional = (e.b - e.a).norm() < min_len;
      out.push_back(e);
    }
  }
  // Inner top edges merged with the silhouette: the camera (70 mm) looks down on the 50 mm
  // walls, goals and corner triangles, so between a top's inner edge (wall_top, goal_top,
  // triangle_top: wall face 0.71-0.78 against top face 0.84 luma) and its outer edge (the
  // top_outline, against the 0.46 background) lies the top face. Once that face is narrower
  // than kMergedTopPx in the image, the two edges are one image edge (the Sobel window spans
  // both; the face has no luma of its own), whose ends are the silhouette's: one detection
  // cannot be two segments with different ends. Such an inner edge (at least
  // kMergedTopShare of its length within kMergedTopPx of a top_outline piece) is counted
  // optional, like a piece < L_min; the silhouette stays counted. Counted in *merged_tops.
  for (Seg& g : out) {
    if (g.optional || !(g.kind == "wall_top" || g.kind == "goal_top" || g.name == "triangle_top")) continue;
    const double len = (g.b - g.a).norm();
    int n = 0, on = 0;
    for (double t = 0; t <= len; t += 1.0, ++n) {
      const Eigen::Vector2d q = g.a + t / len * (g.b - g.a);
      for (const Seg& o : out) {
        if (o.kind != "top_outline") continue;
        const double ol = (o.b - o.a).norm();
        if (ol < 1e-9) continue;
        const Eigen::Vector2d u = (o.b - o.a) / ol;
        const double ot = (q - o.a).dot(u), od = std::fabs(u.x() * (q - o.a).y() - u.y() * (q - o.a).x());
        if (ot >= -0.5 && ot <= ol + 0.5 && od <= kMergedTopPx) {
          ++on;
          break;
        }
      }
    }
    if (n > 0 && on >= kMergedTopShare * n) {
      g.optional = true;
      if (merged_tops) ++*merged_tops;
    }
  }
  return out;
}

// Position of q along g (0 at g.a, |b-a| at g.b) and its distance from g's infinite line.
void alongAcross(const Seg& g, const Eigen::Vector2d& q, double& t, double& d) {
  const Eigen::Vector2d u = (g.b - g.a).normalized();
  t = (q - g.a).dot(u);
  d = std::fabs(u.x() * (q - g.a).y() - u.y() * (q - g.a).x());
}

// d lies on g's line (angle <= 3 deg, both ends within 3 px of the line) and overlaps it.
bool onLine(const Seg& d, const Seg& g) {
  if (angleBetween(d, g) > 3.0 * kPi / 180) return false;
  double ta, da, tb, db;
  alongAcross(g, d.a, ta, da);
  alongAcross(g, d.b, tb, db);
  const double len = (g.b - g.a).norm();
  return da <= 3.0 && db <= 3.0 && std::max(ta, tb) > 0 && std::min(ta, tb) < len;
}

std::string lengthBin(double len) { return len < 60 ? "30-60" : len < 120 ? "60-120" : ">=120"; }
std::string rowBin(double y) { return y < 135 ? "<135" : y < 160 ? "135-160" : y < 200 ? "160-200" : ">=200"; }

// Per-failure breakdown: every missed truth segment and every spurious detection gets one
// reason and its kind, length, mean image row (the horizon of the untilted rig is row 119.5)
// and whether it is one of several pieces of an occluded edge.
void explainFailures(const std::vector<Seg>& gt, const std::vector<Seg>& det, const std::vector<uint8_t>& hit,
                     const std::vector<uint8_t>& det_hit, const cv::Mat& mask, FailureBreakdown& why) {
  for (size_t i = 0; i < gt.size(); ++i) {
    if (gt[i].optional || hit[i]) continue;
    const Seg& g = gt[i];
    const double len = (g.b - g.a).norm();
    std::string reason;
    int on = 0;
    double lo = 1e9, hi = -1e9;
    for (const Seg& d : det) {
      if (!onLine(d, g)) continue;
      ++on;
      double ta, da, tb, db;
      alongAcross(g, d.a, ta, da);
      alongAcross(g, d.b, tb, db);
      lo = std::min({lo, ta, tb});
      hi = std::max({hi, ta, tb});
    }
    if (on == 0) {
      bool near = false;
      for (const Seg& d : det) {
        double ta, da, tb, db;
        alongAcross(g, d.a, ta, da);
        alongAcross(g, d.b, tb, db);
        if (angleBetween(d, g) <= 8.0 * kPi / 180 && std::max(da, db) <= 8.0 && std::max(ta, tb) > 0 && std::min(ta, tb) < len)
          near = true;
      }
      reason = near ? "near but off (angle 3-8 deg or 3-8 px away)" : "not detected";
    } else if (on > 1) {
      reason = "split into pieces";
    } else {
      const double worst = std::max(std::fabs(lo), std::fabs(hi - len));
      const std::string by = worst < 5 ? " by 3-5 px" : worst < 10 ? " by 5-10 px" : " by >= 10 px";
      const bool short_a = lo > 3.0, short_b = hi < len - 3.0, long_a = lo < -3.0, long_b = hi > len + 3.0;
      reason = (short_a || short_b) && !(long_a || long_b) ? "one detection, ends short"
               : (long_a || long_b) && !(short_a || short_b) ? "one detection, runs past an end"
                                                              : "one detection, ends off";
      reason += (short_a || short_b || long_a || long_b) ? by : " (angle or offset)";
      const Eigen::Vector2d& wend = std::fabs(lo) > std::fabs(hi - len) ? g.a : g.b;
      if (wend.x() < 0.5 || wend.y() < 0.5 || wend.x() > mask.cols - 1.5 || wend.y() > mask.rows - 1.5) reason += ", at border";
    }
    const std::string kind = g.kind.empty() ? "?" : g.kind;
    if (why.verbose) {
      std::printf("    missed %-10s %-24s (%.1f,%.1f)-(%.1f,%.1f) contrast %.0f: %s\n", kind.c_str(), g.name.c_str(), g.a.x(),
                  g.a.y(), g.b.x(), g.b.y(), truthContrast(why.luma, g), reason.c_str());
      for (const Seg& d : det)
        if (onLine(d, g)) std::printf("        det (%.1f,%.1f)-(%.1f,%.1f)\n", d.a.x(), d.a.y(), d.b.x(), d.b.y());
    }
    why.missed["reason: " + reason]++;
    why.missed["kind:   " + kind]++;
    why.missed["length: " + lengthBin(len)]++;
    why.missed["row:    " + rowBin(0.5 * (g.a.y() + g.b.y()))]++;
    why.missed[std::string("pieces: ") + (g.broken ? "occluded (several pieces)" : "one piece")]++;
    why.missed["contr.: " + contrastBin(truthContrast(why.luma, g))]++;
  }
  for (size_t k = 0; k < det.size(); ++k) {
    if (det_hit[k]) continue;
    const Seg& d = det[k];
    if (inMask(mask, d)) continue;
    std::string reason = "phantom (no truth edge within 8 px / 8 deg)", kind = "-";
    for (const Seg& g : gt)
      if (onLine(d, g)) {
        reason = "on a truth edge, extent wrong";
        kind = g.kind;
        break;
      }
    if (kind == "-")
      for (const Seg& g : gt) {
        double ta, da, tb, db;
        alongAcross(g, d.a, ta, da);
        alongAcross(g, d.b, tb, db);
        const double len = (g.b - g.a).norm();
        if (angleBetween(d, g) <= 8.0 * kPi / 180 && std::max(da, db) <= 8.0 && std::max(ta, tb) > 0 && std::min(ta, tb) < len) {
          reason = "near a truth edge (3-8 px / 3-8 deg off)";
          kind = g.kind;
          break;
        }
      }
    if (why.verbose)
      std::printf("    spurious (%.1f,%.1f)-(%.1f,%.1f): %s\n", d.a.x(), d.a.y(), d.b.x(), d.b.y(), reason.c_str());
    why.spurious["reason: " + reason]++;
    why.spurious["kind:   " + kind]++;
    why.spurious["length: " + lengthBin((d.b - d.a).norm())]++;
    why.spurious["row:    " + rowBin(0.5 * (d.a.y() + d.b.y()))]++;
  }
}

void printBreakdown(const char* title, const FailureBreakdown& why) {
  std::printf("  %s\n", title);
  std::printf("    recall by truth kind:\n");
  for (const auto& [kind, c] : why.by_kind)
    std::printf("      %-14s %6.2f%% (%ld/%ld)\n", kind.c_str(), c.first ? 100.0 * c.second / c.first : 0.0, c.second, c.first);
  for (const auto* m : {&why.missed, &why.spurious}) {
    std::printf("    %s:\n", m == &why.missed ? "missed truth segments" : "spurious detections");
    std::string last;
    for (const auto& [key, n] : *m) {
      const std::string group = key.substr(0, 7);
      std::printf("      %s %-50s %6ld\n", group == last ? "       " : group.c_str(), key.substr(8).c_str(), n);
      last = group;
    }
  }
}

// --diag: the breakdowns at both levels of the matching.
void printBreakdowns(const FailureBreakdown& centre, const FailureBreakdown& edge) {
  printBreakdown("failure breakdown, centre-line level:", centre);
  printBreakdown("failure breakdown, edge level:", edge);
  std::printf("\n");
}

// Scoring rules of the real set beyond the rendered one (both off for rendered pairs, whose truth
// is exact). Hand labels of photographs cannot place an end under an occluder or inside the
// don't-care areas to 3 px, and a person sees one stripe where a detector may return it in
// collinear pieces:
//  - visible_part: truth and detections are matched on their part outside the don't-care mask
//    (from the first to the last sample, 0.5 px apart, that is not masked): a stripe running
//    under a robot, into the field boundary or onto the centre circle is scored up to where the
//    unscored area begins, for the truth and the detection alike. Truth whose visible part is
//    shorter than min_len is optional (as truth pieces under L_min always are).
//  - split_once: unmatched detections lying along one truth segment (angle <= 2 deg, both ends
//    within 3 px of its line, overlapping one another by at most 3 px) whose union has both end
//    points within 3 px of the truth's count as one correct detection of it.
struct ScoreRules {
  bool visible_part = false;
  bool split_once = false;
  double min_len = 30.0;
};

// s cut to its part outside the mask (see ScoreRules::visible_part); false when none is.
bool visiblePart(const cv::Mat& mask, Seg& s) {
  const double len = (s.b - s.a).norm();
  const int n = std::max(1, static_cast<int>(std::ceil(len / 0.5)));
  int first = -1, last = -1;
  for (int k = 0; k <= n; ++k) {
    const Eigen::Vector2d q = s.a + (static_cast<double>(k) / n) * (s.b - s.a);
    // An end on the image border lies on the pixels' outer edge (-0.5 or W - 0.5), which rounds
    // to a pixel outside the image: it takes the mask of the border pixel it belongs to.
    const int x = std::clamp(static_cast<int>(std::lround(q.x())), 0, mask.cols - 1);
    const int y = std::clamp(static_cast<int>(std::lround(q.y())), 0, mask.rows - 1);
    const bool hidden = mask.at<uint8_t>(y, x) != 0;
    if (hidden) continue;
    if (first < 0) first = k;
    last = k;
  }
  if (first < 0) return false;
  const Eigen::Vector2d a = s.a, d = s.b - s.a;
  s.a = a + (static_cast<double>(first) / n) * d;
  s.b = a + (static_cast<double>(last) / n) * d;
  return true;
}

void scoreSegments(const std::vector<Seg>& gt_in, const std::vector<Seg>& det_in, const cv::Mat& mask, SegStats& st,
                   double gap_max, const ScoreRules& rules = ScoreRules()) {
  std::vector<Seg> gt = gt_in, det = det_in;
  if (rules.visible_part) {
    for (Seg& g : gt)
      if (!visiblePart(mask, g) || (g.b - g.a).norm() < rules.min_len) g.optional = true;
    for (Seg& d : det) visiblePart(mask, d);  // wholly masked ones are ignored below (inMask of the original)
  }
  // Unions of the pieces of one broken edge, and of collinear pieces that touch (a wall and the
  // corner triangle's foot in line with it are one edge in the image).
  std::vector<size_t> parent(gt.size());
  for (size_t i = 0; i < gt.size(); ++i) parent[i] = i;
  std::function<size_t(size_t)> root = [&](size_t i) { return parent[i] == i ? i : parent[i] = root(parent[i]); };
  auto collinear = [&](const Seg& a, const Seg& b) {
    if (angleBetween(a, b) > 2.0 * kPi / 180) return false;
    const Eigen::Vector2d n = Eigen::Vector2d(-(a.b - a.a).y(), (a.b - a.a).x()).normalized();
    return std::fabs(n.dot(b.a - a.a)) < 1.5 && std::fabs(n.dot(b.b - a.a)) < 1.5;
  };
  // Pieces closer than Gap_max along their line whose union is straight to within 1 px (the
  // detector's fitting band) are one straight image edge, which Algorithm 2 is specified to
  // return as one segment (it merges collinear pixel groups under Gap_max): far away, the tops
  // of a wall, a corner triangle, the next wall and a goal's back lie within a pixel of one
  // straight silhouette, broken only where the truth's 3D pieces end.
  auto straightUnion = [&](const Seg& a, const Seg& b) {
    const Eigen::Vector2d pts[4] = {a.a, a.b, b.a, b.b};
    double best = -1;
    Eigen::Vector2d p0 = a.a, p1 = a.b;
    for (int u = 0; u < 4; ++u)
      for (int v = u + 1; v < 4; ++v)
        if ((pts[u] - pts[v]).norm() > best) {
          best = (pts[u] - pts[v]).norm();
          p0 = pts[u];
          p1 = pts[v];
        }
    const Eigen::Vector2d dir = (p1 - p0).normalized();
    for (const Eigen::Vector2d& q : pts)
      if (std::fabs(dir.x() * (q - p0).y() - dir.y() * (q - p0).x()) > 1.0) return false;
    return true;
  };
  for (size_t i = 0; i < gt.size(); ++i)
    for (size_t j = i + 1; j < gt.size(); ++j) {
      // Gap between the two pieces along their common line (0 when they overlap or touch).
      const Eigen::Vector2d dir = (gt[i].b - gt[i].a).normalized();
      const double ia = 0, ib = (gt[i].b - gt[i].a).dot(dir), ja = (gt[j].a - gt[i].a).dot(dir),
                   jb = (gt[j].b - gt[i].a).dot(dir);
      const double gap = std::max({0.0, std::min(ja, jb) - ib, ia - std::max(ja, jb)});
      const bool touch = gap < gap_max;
      if (gt[i].marking != gt[j].marking) continue;
      const bool ends_meet = std::min({(gt[i].a - gt[j].a).norm(), (gt[i].a - gt[j].b).norm(), (gt[i].b - gt[j].a).norm(),
                                       (gt[i].b - gt[j].b).norm()}) < 1.5;
      if (((gt[i].name == gt[j].name || ends_meet) && collinear(gt[i], gt[j])) || (touch && straightUnion(gt[i], gt[j])))
        parent[root(i)] = root(j);
    }
  std::map<size_t, std::vector<size_t>> groups;
  for (size_t i = 0; i < gt.size(); ++i) groups[root(i)].push_back(i);
  // Every run of consecutive pieces of a group (sorted along the line) is a candidate union, so
  // a detection covering two of three pieces still matches those two.
  std::vector<std::pair<Seg, std::vector<size_t>>> unions;
  for (const auto& group : groups) {
    std::vector<size_t> idx = group.second;
    if (idx.size() < 2) continue;
    const Eigen::Vector2d origin = gt[idx[0]].a, dir = (gt[idx[0]].b - gt[idx[0]].a).normalized();
    auto mid = [&](size_t i) { return (0.5 * (gt[i].a + gt[i].b) - origin).dot(dir); };
    std::sort(idx.begin(), idx.end(), [&](size_t x, size_t y) { return mid(x) < mid(y); });
    for (size_t first = 0; first < idx.size(); ++first)
      for (size_t last = first + 1; last < idx.size(); ++last) {
        Seg u = gt[idx[first]];
        double tmin = 1e30, tmax = -1e30;
        std::vector<size_t> members;
        for (size_t k = first; k <= last; ++k) {
          const size_t i = idx[k];
          members.push_back(i);
          for (const Eigen::Vector2d& q : {gt[i].a, gt[i].b}) {
            const double t = (q - origin).dot(dir);
            if (t < tmin) {
              tmin = t;
              u.a = q;
            }
            if (t > tmax) {
              tmax = t;
              u.b = q;
            }
          }
        }
        unions.emplace_back(u, members);
      }
  }
  std::vector<uint8_t> hit(gt.size(), 0), det_hit;
  for (const Seg& d : det) {
    bool ok = false;
    for (size_t i = 0; i < gt.size(); ++i) {
      double e;
      if (!matches(d, gt[i], &e)) continue;
      if (!ok) {
        ok = true;
        ++st.matched;
        st.endpoint_sum += e;
        st.class_ok += (d.marking == gt[i].marking) ? 1 : 0;
        if (d.marking != gt[i].marking && st.why) {
          const std::string dirn = gt[i].marking ? "marking called other" : "other called marking";
          st.why->misclassified[dirn + ", kind " + gt[i].kind]++;
          st.why->misclassified[dirn + ", row " + rowBin(0.5 * (gt[i].a.y() + gt[i].b.y()))]++;
          st.why->misclassified[dirn + ", length " + lengthBin((gt[i].b - gt[i].a).norm())]++;
        }
      }
      hit[i] = 1;
    }
    for (const auto& [u, members] : unions) {
      double e;
      if (!matches(d, u, &e)) continue;
      if (!ok) {
        ok = true;
        ++st.matched;
        st.endpoint_sum += e;
        st.class_ok += (d.marking == u.marking) ? 1 : 0;
      }
      for (size_t i : members) hit[i] = 1;
    }
    det_hit.push_back(ok ? 1 : 0);
  }
  long merged_away = 0;  // split_once: pieces beyond the first of each covering set
  if (rules.split_once) {
    // Targets: every truth segment, then every union of broken pieces.
    std::vector<std::pair<Seg, std::vector<size_t>>> targets;
    for (size_t i = 0; i < gt.size(); ++i) targets.emplace_back(gt[i], std::vector<size_t>{i});
    targets.insert(targets.end(), unions.begin(), unions.end());
    for (const auto& [g, members] : targets) {
      const double len = (g.b - g.a).norm();
      std::vector<std::pair<double, size_t>> pieces;  // (start along g, detection)
      for (size_t k = 0; k < det.size(); ++k) {
        if (det_hit[k] || angleBetween(det[k], g) > 2.0 * kPi / 180) continue;
        double ta, da, tb, db;
        alongAcross(g, det[k].a, ta, da);
        alongAcross(g, det[k].b, tb, db);
        if (da > 3.0 || db > 3.0 || std::max(ta, tb) < 0 || std::min(ta, tb) > len) continue;
        pieces.emplace_back(std::min(ta, tb), k);
      }
      if (pieces.size() < 2) continue;
      std::sort(pieces.begin(), pieces.end());
      bool chain = true;
      double reach = -1e9;
      Eigen::Vector2d first_end = g.a, last_end = g.b;
      double lo = 1e9, hi = -1e9;
      for (const auto& [start, k] : pieces) {
        if (start < reach - 3.0) chain = false;
        for (const Eigen::Vector2d& q : {det[k].a, det[k].b}) {
          double t, d;
          alongAcross(g, q, t, d);
          if (t < lo) {
            lo = t;
            first_end = q;
          }
          if (t > hi) {
            hi = t;
            last_end = q;
          }
          reach = std::max(reach, t);
        }
      }
      const double ea = (first_end - g.a).norm(), eb = (last_end - g.b).norm();
      if (!chain || ea > 3.0 || eb > 3.0) continue;
      ++st.matched;
      st.endpoint_sum += 0.5 * (ea + eb);
      st.class_ok += det[pieces.front().second].marking == g.marking ? 1 : 0;
      for (size_t i : members) hit[i] = 1;
      for (const auto& pc : pieces) det_hit[pc.second] = 1;
      merged_away += static_cast<long>(pieces.size()) - 1;
    }
  }
  for (size_t k = 0; k < det.size(); ++k) {
    if (!det_hit[k] && inMask(mask, det_in[k])) {  // don't care
      ++st.det_ignored;
      continue;
    }
    ++st.det;
    st.det_ok += det_hit[k];
  }
  st.det -= merged_away;
  st.det_ok -= merged_away;
  for (size_t i = 0; i < gt.size(); ++i) {
    if (gt[i].optional) {
      ++st.gt_optional;
      continue;
    }
    ++st.gt;
    st.gt_hit += hit[i];
    if (st.why) {
      st.why->by_kind[gt[i].kind].first++;
      st.why->by_kind[gt[i].kind].second += hit[i];
    }
  }
  if (st.why) explainFailures(gt, det_in, hit, det_hit, mask, *st.why);
}

struct Setup {
  FieldMap map = FieldMap::miroSot();
  StereoRig rig;
  std::vector<Pair> general, goals;
};

Setup& setup() {
  static Setup s;
  return s;
}

void buildSets(int n_general, int n_goal, uint64_t seed) {
  Setup& s = setup();
  RenderOptions good, bad;
  good.samples_per_axis = bad.samples_per_axis = std::getenv("STEREOLOC_BENCH_SAMPLES") ? std::atoi(std::getenv("STEREOLOC_BENCH_SAMPLES")) : 2;
  good.noise_sigma = 1.5;
  good.seed = seed;
  bad.noise_sigma = 3.0;
  bad.brightness = -40;
  bad.contrast = 0.7;
  bad.seed = seed + 1;
  const StereoRenderer r_good(s.map, s.rig, good), r_bad(s.map, s.rig, bad);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const FieldGeometry g = *s.map.geometry();
  auto randomObstacles = [&](const Eigen::Vector2d& robot, int max_robots) {
    std::vector<Obstacle> obs;
    const int k = static_cast<int>(U(rng) * (max_robots + 1));
    for (int i = 0; i <= k; ++i) {
      Obstacle o;
      o.kind = i == 0 ? Obstacle::Kind::Ball : Obstacle::Kind::Robot;
      o.size = i == 0 ? 42.7 : 75.0;
      for (int tries = 0; tries < 50; ++tries) {
        o.position = Eigen::Vector2d(60 + U(rng) * (g.length - 120), 60 + U(rng) * (g.width - 120));
        if ((o.position - robot).norm() > 130) break;
      }
      o.heading = U(rng) * 2 * kPi;
      obs.push_back(o);
    }
    return obs;
  };
  for (int i = 0; i < n_general; ++i) {
    Pair p;
    const Pose2 pose(80 + U(rng) * (g.length - 160), 80 + U(rng) * (g.width - 160), -kPi + 2 * kPi * U(rng));
    p.obstacles = randomObstacles(pose.translation(), 3);
    p.bad_light = i % 2 == 1;
    p.img = (p.bad_light ? r_bad : r_good).render(pose, 0.0, p.obstacles);
    s.general.push_back(std::move(p));
  }
  for (int i = 0; i < n_goal; ++i) {
    Pair p;
    const Eigen::Vector2d pos(80 + U(rng) * (g.length - 160), 80 + U(rng) * (g.width - 160));
    const Eigen::Vector2d goal(U(rng) < 0.5 ? 0.0 : g.length, 0.5 * g.width);
    const double heading = std::atan2(goal.y() - pos.y(), goal.x() - pos.x()) + (U(rng) - 0.5) * 50 * kPi / 180;
    if (U(rng) < 0.5) p.obstacles = randomObstacles(pos, 2);
    p.bad_light = i % 2 == 1;
    p.img = (p.bad_light ? r_bad : r_good).render(Pose2(pos.x(), pos.y(), heading), 0.0, p.obstacles);
    s.goals.push_back(std::move(p));
  }
}

struct RangeStats {
  std::vector<double> abs_err, norm_err;
  long wrong_id = 0, gt_visible = 0, detected = 0;
  std::vector<double> u_err, d_err;
};

void printRow(const char* name, const SegStats& s) {
  std::printf("  %-34s %8.2f%% %9.2f%% %7.2f%% %9.3f\n", name, 100 * s.recall(), 100 * s.precision(), 100 * s.f(), s.endpoint());
}

void describe(const char* what, const std::vector<double>& v, double scale, const char* unit) {
  if (v.empty()) {
    std::printf("  %-18s (no measurements)\n", what);
    return;
  }
  double mean = 0;
  for (double x : v) mean += x;
  mean /= v.size();
  double var = 0;
  for (double x : v) var += (x - mean) * (x - mean);
  const double sd = v.size() > 1 ? std::sqrt(var / (v.size() - 1)) : 0;
  std::printf("  %-18s %10.4g%s %10.4g%s %10.4g%s %10.4g%s\n", what, mean * scale, unit, sd * scale, unit,
              *std::min_element(v.begin(), v.end()) * scale, unit, *std::max_element(v.begin(), v.end()) * scale, unit);
}

std::vector<Seg> openCvSegments(const std::vector<cv::Vec4f>& lines, double min_len) {
  std::vector<Seg> out;
  for (const cv::Vec4f& l : lines) {
    Seg s{Eigen::Vector2d(l[0], l[1]), Eigen::Vector2d(l[2], l[3]), false, "", false, "", false};
    if ((s.b - s.a).norm() >= min_len) out.push_back(s);
  }
  return out;
}

void houghP(const cv::Mat& luma, cv::Mat& edges, std::vector<cv::Vec4i>& out) {
  cv::Canny(luma, edges, 50, 150);
  cv::HoughLinesP(edges, out, 1.0, kPi / 180, 30, 30, 10);
}

// Corner truth follows the segment truth: Algorithm 4 finds a corner, junction or intersection
// only from two detected lines, so a landmark is counted in recall only when two truth lines
// that define it are in the (non-optional) segment truth: a visible piece of at least L_min
// whose line passes the landmark within 1.5 px and whose extent reaches it within delta, the
// two at an image angle of at least min_image_angle. A junction needs a marking and a wall
// foot (the goal line of MiroSot is the wall foot), a corner or intersection two markings.
// Returns "" when detectable, else the reason (printed with counts; never silently dropped).
std::string cornerDetectability(const ImageLandmark& l, const std::vector<Seg>& gt_c, const CornerParams& cp) {
  std::vector<const Seg*> marks, feet;
  bool any_short = false;
  for (const Seg& g : gt_c) {
    const bool is_foot = g.kind == "wall_foot" || g.kind == "goal_foot";
    if (!g.marking && !is_foot) continue;
    double t, d;
    alongAcross(g, l.pixel, t, d);
    const double len = (g.b - g.a).norm();
    if (d > 1.5 || t < -cp.delta_px || t > len + cp.delta_px) continue;
    if (g.optional) {
      any_short = true;
      continue;
    }
    (g.marking ? marks : feet).push_back(&g);
  }
  const double min_ang = cp.min_image_angle_deg * kPi / 180;
  auto pairOk = [&](const std::vector<const Seg*>& x, const std::vector<const Seg*>& y, bool& any_pair) {
    for (const Seg* a : x)
      for (const Seg* b : y) {
        if (a == b) continue;
        any_pair = true;
        if (angleBetween(*a, *b) >= min_ang) return true;
      }
    return false;
  };
  bool any_pair = false;
  const bool ok = l.type == "junction" ? pairOk(marks, feet, any_pair) : pairOk(marks, marks, any_pair);
  if (ok) return "";
  // The map's intersections are where the halfway line crosses the centre circle; the circle is
  // not straight and not in the segment truth, so no truth line pair defines them.
  if (l.type == "intersection") return "intersection with the centre circle (arc not in the segment truth)";
  if (any_pair) return "defining lines at < min_image_angle in the image";
  if (any_short) return "a defining line visible only in pieces < L_min";
  return "a defining line not visible (occluded / out of image)";
}

// The accuracy table's counts over the test set: segments at centre-line and edge level (ours,
// cv::HoughLinesP, cv LSD), the classification, corners/junctions/intersections and the goal
// corners' stereo range.
class AccuracyTally {
 public:
  explicit AccuracyTally(const Frontend& fe) : s_(setup()), fe_(fe), lsd_(cv::createLineSegmentDetector(cv::LSD_REFINE_STD)) {
    ours_centre_.why = &why_centre_;
    ours_edge_.why = &why_edge_;
    why_centre_.verbose = std::getenv("STEREOLOC_BENCH_VERBOSE") != nullptr;
  }
  bool verbose() const { return why_centre_.verbose; }

  // One general pair: its lines and segments, corners and goal-corner ranges. `dump`, when
  // set, receives the pair's truth and detections as images.
  void scorePair(const Pair& p, const FrontendResult& r, const std::function<void(const std::vector<Seg>&,
                 const std::vector<Seg>&, const std::vector<Seg>&, const std::vector<Seg>&)>& dump) {
    const cv::Mat mask = dontCare(s_.rig, s_.map, p);
    bgrToLuma(p.img.left, why_centre_.luma);
    why_edge_.luma = why_centre_.luma;
    // Centre-line level.
    std::vector<Seg> det;
    for (const LineFeature& l : r.lines)
      det.push_back(Seg{Eigen::Vector2d(l.x(l.t_min), l.y(l.t_min)), Eigen::Vector2d(l.x(l.t_max), l.y(l.t_max)), l.marking, "", false, "", false});
    const std::vector<Seg> gt_c = truthSegments(s_.rig, s_.map, p, false, lmin(), nullptr, &merged_tops_);
    scoreSegments(gt_c, det, mask, ours_centre_, gapMax());
    scoreSegments(gt_c, det, mask, by_light_[p.bad_light ? 1 : 0], gapMax());
    // Edge level, ours and OpenCV.
    std::vector<Seg> edges;
    for (const Segment& sg : r.segments)
      edges.push_back(Seg{Eigen::Vector2d(sg.x1, sg.y1), Eigen::Vector2d(sg.x2, sg.y2), sg.cls == SegmentClass::Marking, "", false, "", false});
    const std::vector<Seg> gt_e = truthSegments(s_.rig, s_.map, p, true, lmin(), &thin_markings_);
    if (dump) dump(gt_c, det, gt_e, edges);
    SegStats before = ours_edge_;
    scoreSegments(gt_e, edges, mask, ours_edge_, gapMax());
    cls_n_ += ours_edge_.matched - before.matched;
    cls_ok_ += ours_edge_.class_ok - before.class_ok;
    scoreOpenCv(p, gt_e, mask);
    scoreCorners(p, r, gt_c);
    scoreGoalRanges(p, r);
  }

  void scoreGoalRanges(const Pair& p, const FrontendResult& r) {
    const Pose2& robot = p.img.truth.robot;
    std::map<int, Eigen::Vector2d> gt_px, gt_right;
    for (const ImageLandmark& l : p.img.truth.left.landmarks)
      if (l.type == "goal_corner") gt_px[l.id] = l.pixel;
    for (const ImageLandmark& l : p.img.truth.right.landmarks)
      if (l.type == "goal_corner") gt_right[l.id] = l.pixel;
    rs_.gt_visible += static_cast<long>(gt_px.size());
    for (const Observation& o : r.observations) {
      if (o.type != LandmarkType::GoalCorner || o.landmark_id < 0) continue;
      const auto it = gt_px.find(o.landmark_id);
      if (it == gt_px.end() || std::fabs(it->second.x() - o.pixels->u_left) > 3.0) {
        ++rs_.wrong_id;
        continue;
      }
      ++rs_.detected;
      const double truth = (s_.map.at(o.landmark_id).xy() - robot.translation()).norm();
      rs_.abs_err.push_back(std::fabs(o.range - truth));
      rs_.norm_err.push_back(std::fabs(o.range - truth) / truth);
      rs_.u_err.push_back(o.pixels->u_left - it->second.x());
      const auto jt = gt_right.find(o.landmark_id);
      if (jt != gt_right.end()) rs_.d_err.push_back(o.pixels->disparity() - (it->second.x() - jt->second.x()));
    }
  }

  void printSegments(bool diag) const {
    std::printf("\nstereoloc vision frontend: accuracy on %zu rendered pairs (%zu with bad illumination) + %zu goal pairs\n",
                s_.general.size(), s_.general.size() / 2, s_.goals.size());
    std::printf("matching: angle <= 2 deg, both end points <= 3 px; broken edges match as one; so do runs of truth pieces\n"
                "closer than Gap_max whose union is straight within 1 px (Algorithm 2 merges them); truth pieces < L_min\n"
                "optional; unmatched detections on the centre circle or obstacles ignored\n");
    std::printf("excluded at centre-line level: %ld optional truth pieces (of %ld), %ld detections ignored (of %ld)\n",
                ours_centre_.gt_optional, ours_centre_.gt_optional + ours_centre_.gt, ours_centre_.det_ignored,
                ours_centre_.det_ignored + ours_centre_.det);
    std::printf("  optional = shorter than L_min, or (%ld of them) an inner top edge (wall_top, goal_top, triangle_top)\n"
                "  within %.1f px of the top_outline silhouette over >= %.0f%% of its length: the top face between them\n"
                "  is thinner than that in the image, so the two are one image edge with the silhouette's ends\n\n",
                merged_tops_, kMergedTopPx, 100 * kMergedTopShare);
    std::printf("  %-34s %9s %10s %8s %9s\n", "segments", "recall", "precision", "F", "endpt px");
    printRow("ours, centre-line level (target)", ours_centre_);
    printRow("  good illumination", by_light_[0]);
    printRow("  bad illumination", by_light_[1]);
    printRow("ours, edge level", ours_edge_);
    std::printf("    (edge level: %ld markings narrower than %.1f px in the image are one truth edge, their centre line,\n"
                "     not two unresolvable side edges)\n", thin_markings_, kThinStripePx);
    printRow("cv::HoughLinesP (Canny), edge level", hough_edge_);
    printRow("cv LSD, edge level", lsd_edge_);
    std::printf("  targets: recall >= 97%%, precision >= 97%%, end-point error <= 1.0 px\n\n");
    if (diag) printBreakdowns(why_centre_, why_edge_);
    std::printf("  field-marking classification accuracy (matched edges): %.2f%% of %ld (target >= 98%%)\n",
                cls_n_ ? 100.0 * cls_ok_ / cls_n_ : 0.0, cls_n_);
    if (diag)
      for (const auto& [key, n] : why_edge_.misclassified) std::printf("    misclassified: %-50s %6ld\n", key.c_str(), n);
    std::printf("\n");
  }

  void printCorners() const {
    std::printf("  corners/junctions/intersections: recall %.2f%% (%ld/%ld), precision %.2f%% (%ld/%ld), mean error %.3f px\n",
                c_gt_ ? 100.0 * c_hit_ / c_gt_ : 0.0, c_hit_, c_gt_, c_det_ ? 100.0 * c_ok_ / c_det_ : 0.0, c_ok_, c_det_,
                c_ok_ ? c_err_ / c_ok_ : 0.0);
    long c_excl_total = 0;
    for (const auto& [why, n] : c_excluded_) c_excl_total += n;
    std::printf("    truth rule: a landmark counts when two truth lines that define it are detectable: each a visible\n"
                "    piece >= L_min (%.0f px) whose extent reaches the point within delta (%.0f px), through it within\n"
                "    1.5 px, at an image angle >= %.0f deg (Algorithm 4's pair test); a junction needs a marking and a\n"
                "    wall foot, a corner/intersection two markings. Excluded (detections of them ignored, %ld): %ld of %ld\n",
                lmin(), fe_.params().corners.delta_px, fe_.params().corners.min_image_angle_deg, c_det_ignored_,
                c_excl_total, c_excl_total + c_gt_);
    for (const auto& [why, n] : c_excluded_) std::printf("      %-60s %6ld\n", why.c_str(), n);
    for (const auto& [type, c] : c_type_)
      std::printf("    %-14s recall %6.2f%% (%ld/%ld)\n", type.c_str(), c.first ? 100.0 * c.second / c.first : 0.0, c.second,
                  c.first);
    std::printf("  targets: recall >= 95%%, precision >= 95%%, position error <= 0.5 px\n\n");
  }

  void printRanges() const {
    std::printf("goal-corner stereo range (format of thesis Table 6.3), %zu measurements; %ld of %ld visible detected, %ld wrong id\n",
                rs_.abs_err.size(), rs_.detected, rs_.gt_visible, rs_.wrong_id);
    std::printf("  %-18s %11s %11s %11s %11s\n", "", "Mean", "Std", "Min", "Max");
    describe("Absolute error", rs_.abs_err, 1.0, "  ");
    describe("Normalized error", rs_.norm_err, 100.0, " %");
    std::printf("  %-18s %11s %11s %11s %11s\n", "thesis Table 6.3", "5.18 %", "4.04 %", "0.0001 %", "35.91 %");
    std::printf("  target: mean normalized error <= 2.0 %% over >= 2000 measurements\n");
    describe("u_left error px", rs_.u_err, 1.0, "  ");
    describe("disparity err px", rs_.d_err, 1.0, "  ");
    std::printf("\n");
  }

 private:
  double lmin() const { return fe_.params().segments.min_length_px; }
  double gapMax() const { return fe_.params().segments.gap_max_px; }

  void scoreOpenCv(const Pair& p, const std::vector<Seg>& gt_e, const cv::Mat& mask) {
    bgrToLuma(p.img.left, luma_);
    std::vector<cv::Vec4i> hp;
    houghP(luma_, canny_, hp);
    std::vector<cv::Vec4f> hpf;
    for (const cv::Vec4i& l : hp) hpf.emplace_back(l[0], l[1], l[2], l[3]);
    scoreSegments(gt_e, openCvSegments(hpf, lmin()), mask, hough_edge_, gapMax());
    std::vector<cv::Vec4f> ls;
    lsd_->detect(luma_, ls);
    scoreSegments(gt_e, openCvSegments(ls, lmin()), mask, lsd_edge_, gapMax());
  }

  // Corners, junctions, intersections: the truth landmarks detectable by rule (the others are
  // optional: a detection of one is correct but not counted), each matched to the nearest
  // unused detection of its type within 3 px.
  void scoreCorners(const Pair& p, const FrontendResult& r, const std::vector<Seg>& gt_c) {
    std::vector<const ImageLandmark*> gl, gl_opt;
    for (const ImageLandmark& l : p.img.truth.left.landmarks) {
      if (l.type != "corner" && l.type != "junction" && l.type != "intersection") continue;
      const std::string why_not = cornerDetectability(l, gt_c, fe_.params().corners);
      if (why_not.empty()) {
        gl.push_back(&l);
      } else {
        gl_opt.push_back(&l);
        c_excluded_[why_not]++;
      }
    }
    std::vector<uint8_t> used(gl.size(), 0), used_opt(gl_opt.size(), 0);
    for (const PointFeature& f : r.features) {
      if (f.type == LandmarkType::GoalCorner) continue;
      bool on_optional = false;
      for (size_t k = 0; k < gl_opt.size() && !on_optional; ++k)
        if (!used_opt[k] && gl_opt[k]->type == toString(f.type) &&
            std::hypot(gl_opt[k]->pixel.x() - f.u, gl_opt[k]->pixel.y() - f.v) <= 3.0) {
          used_opt[k] = 1;
          on_optional = true;
        }
      if (on_optional) {
        ++c_det_ignored_;
        continue;
      }
      ++c_det_;
      int best = -1;
      double bd = 3.0;
      for (size_t k = 0; k < gl.size(); ++k) {
        const double d = std::hypot(gl[k]->pixel.x() - f.u, gl[k]->pixel.y() - f.v);
        if (!used[k] && gl[k]->type == toString(f.type) && d <= bd) {
          bd = d;
          best = static_cast<int>(k);
        }
      }
      if (best >= 0) {
        used[best] = 1;
        ++c_ok_;
        c_err_ += bd;
      } else if (verbose()) {
        std::printf("    false %-12s at (%.1f,%.1f); truth within 10 px:", toString(f.type).c_str(), f.u, f.v);
        for (const ImageLandmark& l : p.img.truth.left.landmarks)
          if (std::hypot(l.pixel.x() - f.u, l.pixel.y() - f.v) < 10)
            std::printf(" %s id %d (%.1f,%.1f)", l.type.c_str(), l.id, l.pixel.x(), l.pixel.y());
        std::printf("\n");
      }
    }
    for (size_t k = 0; k < gl.size(); ++k) {
      if (verbose() && !used[k]) {
        std::printf("    missed %-12s id %3d at (%.1f,%.1f); nearest detections:", gl[k]->type.c_str(), gl[k]->id,
                    gl[k]->pixel.x(), gl[k]->pixel.y());
        for (const PointFeature& f : r.features)
          if (std::hypot(gl[k]->pixel.x() - f.u, gl[k]->pixel.y() - f.v) < 10)
            std::printf(" %s (%.1f,%.1f)", toString(f.type).c_str(), f.u, f.v);
        std::printf("\n");
      }
      ++c_gt_;
      c_hit_ += used[k];
      c_type_[gl[k]->type].first++;
      c_type_[gl[k]->type].second += used[k];
    }
  }

  Setup& s_;
  const Frontend& fe_;
  cv::Ptr<cv::LineSegmentDetector> lsd_;
  cv::Mat luma_, canny_;
  SegStats ours_centre_, ours_edge_, hough_edge_, lsd_edge_;
  FailureBreakdown why_centre_, why_edge_;
  SegStats by_light_[2];
  long cls_n_ = 0, cls_ok_ = 0;
  long c_gt_ = 0, c_hit_ = 0, c_det_ = 0, c_ok_ = 0, c_det_ignored_ = 0;
  long thin_markings_ = 0;  // edge level: markings narrower than kThinStripePx, one truth edge each
  long merged_tops_ = 0;    // centre-line level: inner top edges merged with the silhouette (optional)
  std::map<std::string, long> c_excluded_;  // reason -> truth landmarks excluded from recall
  double c_err_ = 0;
  std::map<std::string, std::pair<long, long>> c_type_;  // type -> (gt, hit)
  RangeStats rs_;
};

// STEREOLOC_BENCH_DUMP=dir: the first pairs (STEREOLOC_BENCH_DUMP_PAIR: only that one) as images
// with their truth, and 4x overlays: truth blue (optional pieces grey), ours red (marking) /
// green (other), at centre-line and edge level.
class PairDumper {
 public:
  PairDumper() : dir_(std::getenv("STEREOLOC_BENCH_DUMP")), only_(std::getenv("STEREOLOC_BENCH_DUMP_PAIR")) {}

  // Writes the pair's images and truth when it is one to dump; true then.
  bool begin(const Pair& p, int pair_index) {
    if (!dir_ || dumped_ >= 6 || (only_ && std::atoi(only_) != pair_index)) return false;
    const std::string base = std::string(dir_) + "/pair" + std::to_string(dumped_++);
    writePngFile(base + "_left.png", p.img.left);
    writePngFile(base + "_right.png", p.img.right);
    std::FILE* f = std::fopen((base + "_truth.json").c_str(), "w");
    if (f) {
      std::fputs(truthToJson(p.img.truth, 0, p.img.left.cols, p.img.left.rows).c_str(), f);
      std::fclose(f);
    }
    return true;
  }
  // The overlays of the pair begin() last wrote.
  void overlays(const Pair& p, const std::vector<Seg>& gt_c, const std::vector<Seg>& det, const std::vector<Seg>& gt_e,
                const std::vector<Seg>& edges) const {
    for (int level = 0; level < 2; ++level) {
      cv::Mat big;
      cv::resize(p.img.left, big, cv::Size(), 4, 4, cv::INTER_NEAREST);
      auto P = [](const Eigen::Vector2d& q) { return cv::Point(static_cast<int>(std::lround(4 * q.x() + 1.5)), static_cast<int>(std::lround(4 * q.y() + 1.5))); };
      for (const Seg& g : level ? gt_e : gt_c) cv::line(big, P(g.a), P(g.b), g.optional ? cv::Scalar(128, 128, 128) : cv::Scalar(255, 0, 0), 1);
      for (const Seg& d : level ? edges : det) cv::line(big, P(d.a), P(d.b), d.marking ? cv::Scalar(0, 0, 255) : cv::Scalar(0, 255, 0), 1);
      writePngFile(std::string(dir_) + "/pair" + std::to_string(dumped_ - 1) + (level ? "_edges.png" : "_lines.png"), big);
    }
  }

 private:
  const char* dir_;
  const char* only_;
  int dumped_ = 0;
};

void accuracyTable(bool diag) {
  Setup& s = setup();
  // STEREOLOC_BENCH_PARAMS: a frontend parameter YAML to score instead of the defaults.
  const char* params_path = std::getenv("STEREOLOC_BENCH_PARAMS");
  Frontend fe(s.rig, s.map, params_path ? FrontendParams::load(params_path) : FrontendParams());
  AccuracyTally tally(fe);
  PairDumper dumper;
  int pair_index = 0;
  for (const Pair& p : s.general) {
    const FrontendResult& r = fe.process(p.img.left, p.img.right, p.img.truth.head_pan);
    const bool dumped = dumper.begin(p, pair_index);
    if (tally.verbose()) std::printf("  pair %d\n", pair_index);
    ++pair_index;
    tally.scorePair(p, r, [&](const std::vector<Seg>& gt_c, const std::vector<Seg>& det, const std::vector<Seg>& gt_e,
                              const std::vector<Seg>& edges) {
      if (dumped) dumper.overlays(p, gt_c, det, gt_e, edges);
    });
  }
  for (const Pair& p : s.goals) tally.scoreGoalRanges(p, fe.process(p.img.left, p.img.right, p.img.truth.head_pan));
  tally.printSegments(diag);
  tally.printCorners();
  tally.printRanges();
}

// ---- real photographs (data/real, format in data/real/README.md) ----
struct RealImage {
  std::string name;
  cv::Mat bgr;
  std::vector<Seg> centre, edges;  // truth: marking centre lines, marking side edges (visible runs)
  struct Corner {
    std::string type;
    Eigen::Vector2d p;
  };
  std::vector<Corner> corners;
  cv::Mat mask;  // don't care: above the field boundary, robots / people / balls, curved markings
};

std::vector<double> numbers(std::istringstream& in) {
  std::vector<double> v;
  double x;
  while (in >> x) v.push_back(x);
  return v;
}

// Reads one label file; throws with file:line on anything malformed.
RealImage loadReal(const std::string& dir, const std::string& name, double lmin) {
  RealImage im;
  im.name = name;
  const std::string img_path = dir + "/images/" + name + ".jpg", lab_path = dir + "/labels/" + name + ".txt";
  ImageRead read = readImageFile(img_path, ImageColour::Bgr);
  if (!read.problem.empty()) throw Error(img_path + ": cannot read the image (" + read.problem + ")");
  im.bgr = read.image;
  im.mask = cv::Mat(im.bgr.rows, im.bgr.cols, CV_8UC1, cv::Scalar(0));
  std::ifstream f(lab_path);
  if (!f) throw Error(lab_path + ": cannot open");
  std::string line;
  int ln = 0;
  std::vector<double> widths;
  while (std::getline(f, line)) {
    ++ln;
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    std::string kind;
    in >> kind;
    const std::string where = lab_path + ":" + std::to_string(ln) + ": ";
    auto pts = [&](const std::vector<double>& v) {
      if (v.size() < 4 || v.size() % 2) throw Error(where + kind + ": expected an even number (>= 4) of coordinates");
      std::vector<cv::Point> p;
      for (size_t k = 0; k < v.size(); k += 2) p.emplace_back(static_cast<int>(std::lround(v[k])), static_cast<int>(std::lround(v[k + 1])));
      return p;
    };
    if (kind == "marking") {
      double x1, y1, x2, y2, w;
      std::string kw, kg;
      int group;
      if (!(in >> x1 >> y1 >> x2 >> y2 >> kw >> w >> kg >> group) || kw != "width" || kg != "group")
        throw Error(where + "marking: expected x1 y1 x2 y2 width W group G");
      Seg s{Eigen::Vector2d(x1, y1), Eigen::Vector2d(x2, y2), true, group >= 0 ? "g" + std::to_string(group) : "m" + std::to_string(ln), false, "marking", false};
      s.optional = (s.b - s.a).norm() < lmin;
      im.centre.push_back(s);
      widths.push_back(w);
    } else if (kind == "edge") {
      double x1, y1, x2, y2;
      std::string of;
      int m;
      if (!(in >> x1 >> y1 >> x2 >> y2 >> of >> m) || of != "of" || m < 0 || m >= static_cast<int>(im.centre.size()))
        throw Error(where + "edge: expected x1 y1 x2 y2 of <marking index>");
      Seg s{Eigen::Vector2d(x1, y1), Eigen::Vector2d(x2, y2), true, im.centre[m].name + "e", false, "marking_edge", false};
      s.optional = (s.b - s.a).norm() < lmin;
      im.edges.push_back(s);
    } else if (kind == "corner") {
      RealImage::Corner c;
      double x, y;
      if (!(in >> c.type >> x >> y) || (c.type != "L" && c.type != "T" && c.type != "X"))
        throw Error(where + "corner: expected L|T|X x y");
      c.p = Eigen::Vector2d(x, y);
      im.corners.push_back(c);
    } else if (kind == "boundary") {
      std::vector<cv::Point> p = pts(numbers(in));
      // Everything above the boundary is outside the field; its edge itself is not a marking.
      std::vector<cv::Point> poly = p;
      poly.emplace_back(im.bgr.cols - 1, 0);
      poly.emplace_back(0, 0);
      poly.insert(poly.begin(), cv::Point(0, p.front().y));
      poly.emplace_back(im.bgr.cols - 1, p.back().y);
      std::vector<cv::Point> above = {cv::Point(0, 0)};
      above.emplace_back(0, p.front().y);
      above.insert(above.end(), p.begin(), p.end());
      above.emplace_back(im.bgr.cols - 1, p.back().y);
      above.emplace_back(im.bgr.cols - 1, 0);
      cv::fillPoly(im.mask, std::vector<std::vector<cv::Point>>{above}, cv::Scalar(255));
      cv::polylines(im.mask, p, false, cv::Scalar(255), 7);
    } else if (kind == "dontcare") {
      const std::vector<cv::Point> p = pts(numbers(in));
      cv::fillPoly(im.mask, std::vector<std::vector<cv::Point>>{p}, cv::Scalar(255));
      cv::polylines(im.mask, p, true, cv::Scalar(255), 5);
    } else if (kind == "curve") {
      cv::polylines(im.mask, pts(numbers(in)), false, cv::Scalar(255), 21);
    } else {
      throw Error(where + "unknown label kind \"" + kind + "\"");
    }
  }
  return im;
}

std::vector<std::string> realNames(const std::string& dir) {
  std::vector<std::string> names;
  if (!std::filesystem::is_directory(dir + "/labels")) throw Error(dir + "/labels: no such directory");
  for (const auto& e : std::filesystem::directory_iterator(dir + "/labels"))
    if (e.path().extension() == ".txt") names.push_back(e.path().stem().string());
  std::sort(names.begin(), names.end());
  return names;
}

double medianOf(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// CPU time of this process (all its threads, OpenCV's included), ms. On a shared machine the
// wall time of a pass is mostly the time other processes hold the cores.
double processCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// Median over `reps` passes of the mean CPU time per image of fn over all images, in ms.
template <typename F>
double timePerImage(const std::vector<const cv::Mat*>& imgs, int reps, F fn) {
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    const double t0 = processCpuMs();
    for (const cv::Mat* m : imgs) fn(*m);
    t.push_back((processCpuMs() - t0) / imgs.size());
  }
  return medianOf(t);
}

// Thread CPU time, ms (the stages below run on this thread only).
double threadCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// The stages of Frontend::detectFeatures one by one, each timed: the same calls in the same
// order on its own buffers (checked: the same segments, lines and point features as
// Frontend::detectFeatures on every image).
struct StagePipeline {
  static constexpr int kStages = 11;
  static constexpr const char* kNames[kStages] = {"luma",           "field region", "gradient",       "Hough votes",
                                                  "peaks",          "segments",     "segment ends",   "classification",
                                                  "lines",          "stripe ends",  "corners"};
  explicit StagePipeline(const Frontend& frontend) : fe(frontend) { acc.configure(fe.rig().params().image_width, fe.rig().params().image_height, fe.params().hough); }
  // Adds each stage's thread CPU time (ms) to t[0 .. kStages).
  void run(const cv::Mat& bgr, double* t) {
    const FrontendParams& p = fe.params();
    const int w = fe.rig().params().image_width, h = fe.rig().params().image_height;
    double t0 = threadCpuMs(), t1;
    auto lap = [&](int k) {
      t1 = threadCpuMs();
      t[k] += t1 - t0;
      t0 = t1;
    };
    bgrToLuma(bgr, luma);
    lap(0);
    region.compute(bgr, p.field);
    lap(1);
    grad.compute(luma, p.gradient, region.restricted() ? region.top().data() : nullptr);
    lap(2);
    used.clear();
    acc.vote(grad.edges(), used);
    lap(3);
    detectPeaks(acc, p.peaks, peaks);
    lap(4);
    extractor.extract(grad.edges(), peaks, p.hough.rho_step_px, p.segments, used, segments, luma.cols, luma.rows);
    lap(5);
    refineEndpoints(luma, segments);
    lap(6);
    classifySegments(grad, extractor, fe.markingWidthPerRow(), p.classify, segments, scratch, &luma);
    lap(7);
    buildLines(segments, fe.rig(), p.corners, lines);
    clipLinesToImage(w, h, lines);
    lap(8);
    trimStripeEnds(luma, p.ends, lines, ends_scratch);
    lap(9);
    snapLineEnds(w, h, p.corners, lines);
    findCorners(lines, fe.rig(), p.corners, features, &luma);
    lap(10);
  }
  const Frontend& fe;
  cv::Mat luma;
  FieldRegion region;
  GradientStage grad;
  HoughAccumulator acc;
  SegmentExtractor extractor;
  std::vector<HoughPeak> peaks;
  std::vector<uint8_t> used;
  std::vector<Segment> segments;
  std::vector<float> scratch;
  std::vector<LineFeature> lines;
  StripeEndScratch ends_scratch;
  std::vector<PointFeature> features;
};

bool sameDetections(StagePipeline& sp, Frontend& fe, const cv::Mat& bgr) {
  std::vector<double> t(StagePipeline::kStages, 0.0);
  sp.run(bgr, t.data());
  const FrontendResult& r = fe.detectFeatures(bgr);
  if (r.segments.size() != sp.segments.size() || r.lines.size() != sp.lines.size() || r.features.size() != sp.features.size())
    return false;
  for (size_t k = 0; k < r.segments.size(); ++k)
    if (r.segments[k].x1 != sp.segments[k].x1 || r.segments[k].y2 != sp.segments[k].y2 || r.segments[k].cls != sp.segments[k].cls)
      return false;
  for (size_t k = 0; k < r.features.size(); ++k)
    if (r.features[k].u != sp.features[k].u || r.features[k].v != sp.features[k].v || r.features[k].type != sp.features[k].type)
      return false;
  return true;
}

// --stages: thread CPU time of every stage per image, photographs (their parameters) and
// rendered left images (defaults), in alternating passes; medians over the passes.
void stageTable(Frontend& fe_real, const std::vector<const cv::Mat*>& real_imgs, Frontend& fe_rend,
                const std::vector<const cv::Mat*>& rend_imgs, int passes) {
  StagePipeline sp_real(fe_real), sp_rend(fe_rend);
  for (const cv::Mat* m : real_imgs)
    if (!sameDetections(sp_real, fe_real, *m)) throw Error("--stages: the staged pipeline differs from Frontend::detectFeatures on a photograph");
  for (const cv::Mat* m : rend_imgs)
    if (!sameDetections(sp_rend, fe_rend, *m)) throw Error("--stages: the staged pipeline differs from Frontend::detectFeatures on a rendered image");
  const int ns = StagePipeline::kStages;
  std::vector<std::vector<double>> tr(ns + 1), tg(ns + 1);
  for (int pass = 0; pass < passes; ++pass) {
    for (int side = 0; side < 2; ++side) {
      StagePipeline& sp = side == 0 ? sp_real : sp_rend;
      const std::vector<const cv::Mat*>& imgs = side == 0 ? real_imgs : rend_imgs;
      std::vector<double> t(ns, 0.0);
      for (const cv::Mat* m : imgs) sp.run(*m, t.data());
      double sum = 0;
      auto& out = side == 0 ? tr : tg;
      for (int k = 0; k < ns; ++k) {
        out[k].push_back(t[k] / imgs.size());
        sum += t[k] / imgs.size();
      }
      out[ns].push_back(sum);
    }
  }
  std::printf("  thread CPU time per image by stage, ms (median of %d alternating passes):\n", passes);
  std::printf("  %-16s %10s %10s\n", "stage", "photos", "rendered");
  for (int k = 0; k <= ns; ++k)
    std::printf("  %-16s %10.4f %10.4f\n", k < ns ? StagePipeline::kNames[k] : "sum", medianOf(tr[k]), medianOf(tg[k]));
  std::printf("\n");
}

// The scores on the photographs: our segments at centre-line and edge level, HoughLinesP's and
// LSD's at edge level, the marking classification and the corners.
class RealTally {
 public:
  RealTally(double lmin, double gap_max) : gap_max_(gap_max), lsd_(cv::createLineSegmentDetector(cv::LSD_REFINE_STD)) {
    rules_.visible_part = std::getenv("STEREOLOC_BENCH_LABEL_EXTENT") == nullptr;
    rules_.split_once = rules_.visible_part;
    rules_.min_len = lmin;
    why_centre_.verbose = verbose_;
    ours_centre_.why = &why_centre_;
    ours_edge_.why = &why_edge_;
  }
  RealTally(const RealTally&) = delete;
  RealTally& operator=(const RealTally&) = delete;

  void score(const RealImage& im, const FrontendResult& r) {
    if (verbose_) std::printf("  %s\n", im.name.c_str());
    bgrToLuma(im.bgr, why_centre_.luma);
    why_edge_.luma = why_centre_.luma;
    std::vector<Seg> det;
    for (const LineFeature& l : r.lines)
      if (l.marking)
        det.push_back(Seg{Eigen::Vector2d(l.x(l.t_min), l.y(l.t_min)), Eigen::Vector2d(l.x(l.t_max), l.y(l.t_max)), true, "", false, "", false});
    const SegStats before_c = ours_centre_;
    scoreSegments(im.centre, det, im.mask, ours_centre_, gap_max_, rules_);
    std::vector<Seg> edges;
    for (const Segment& sg : r.segments)
      edges.push_back(Seg{Eigen::Vector2d(sg.x1, sg.y1), Eigen::Vector2d(sg.x2, sg.y2), sg.cls == SegmentClass::Marking, "", false, "", false});
    const SegStats before = ours_edge_;
    scoreSegments(im.edges, edges, im.mask, ours_edge_, gap_max_, rules_);
    cls_n_ += ours_edge_.matched - before.matched;
    cls_ok_ += ours_edge_.class_ok - before.class_ok;
    scoreOpenCv(im);
    scoreCorners(im, r);
    if (verbose_)
      std::printf("  %s: centre lines %ld/%ld recalled, %ld/%ld detections correct\n", im.name.c_str(),
                  ours_centre_.gt_hit - before_c.gt_hit, ours_centre_.gt - before_c.gt,
                  ours_centre_.det_ok - before_c.det_ok, ours_centre_.det - before_c.det);
  }

  void printSegments(const std::string& dir, size_t images, bool diag) const {
    std::printf("\nstereoloc vision frontend on %zu real photographs (%s, 320x240, hand labels)\n", images, dir.c_str());
    std::printf("matching as on rendered pairs: angle <= 2 deg, both end points <= 3 px; pieces of one stripe broken by an\n"
                "occluder match as one; truth pieces < L_min optional; unmatched detections in the don't-care mask (above\n"
                "the field boundary, robots, people, balls, curved markings) ignored: %ld of %ld at centre-line level\n\n",
                ours_centre_.det_ignored, ours_centre_.det_ignored + ours_centre_.det);
    std::printf("  %-34s %9s %10s %8s %9s\n", "field-marking segments", "recall", "precision", "F", "endpt px");
    printRow("ours, centre-line level (target)", ours_centre_);
    printRow("ours, edge level", ours_edge_);
    printRow("cv::HoughLinesP (Canny), edge level", hough_edge_);
    printRow("cv LSD, edge level", lsd_edge_);
    std::printf("  targets: recall >= 85%%, precision >= 85%%, F above LSD and HoughLinesP\n\n");
    if (diag) printBreakdowns(why_centre_, why_edge_);
  }

  void printClassesAndCorners() const {
    std::printf("  field-marking classification (matched marking edges called marking): %.2f%% of %ld (target >= 95%%)\n\n",
                cls_n_ ? 100.0 * cls_ok_ / cls_n_ : 0.0, cls_n_);
    std::printf("  corners/junctions/intersections: recall %.2f%% (%ld/%ld), precision %.2f%% (%ld/%ld), mean error %.3f px\n",
                c_gt_ ? 100.0 * c_hit_ / c_gt_ : 0.0, c_hit_, c_gt_, c_det_ ? 100.0 * c_ok_ / c_det_ : 0.0, c_ok_, c_det_,
                c_ok_ ? c_err_ / c_ok_ : 0.0);
    for (const auto& [type, c] : c_type_)
      std::printf("    %-3s recall %6.2f%% (%ld/%ld)\n", type.c_str(), c.first ? 100.0 * c.second / c.first : 0.0, c.second,
                  c.first);
    std::printf("  targets: recall >= 80%%, precision >= 90%%, position error <= 1.5 px\n\n");
  }

 private:
  void scoreOpenCv(const RealImage& im) {
    bgrToLuma(im.bgr, luma_);
    std::vector<cv::Vec4i> hp;
    houghP(luma_, canny_, hp);
    std::vector<cv::Vec4f> hpf;
    for (const cv::Vec4i& l : hp) hpf.emplace_back(l[0], l[1], l[2], l[3]);
    scoreSegments(im.edges, openCvSegments(hpf, rules_.min_len), im.mask, hough_edge_, gap_max_, rules_);
    std::vector<cv::Vec4f> ls;
    lsd_->detect(luma_, ls);
    scoreSegments(im.edges, openCvSegments(ls, rules_.min_len), im.mask, lsd_edge_, gap_max_, rules_);
  }

  // A detection within 3 px of a labelled corner of its type is correct; detections in the
  // don't-care mask that match nothing are ignored.
  void scoreCorners(const RealImage& im, const FrontendResult& r) {
    std::vector<uint8_t> used(im.corners.size(), 0);
    for (const PointFeature& f : r.features) {
      if (f.type != LandmarkType::MarkingCorner && f.type != LandmarkType::Junction && f.type != LandmarkType::Intersection)
        continue;
      const std::string type = f.type == LandmarkType::MarkingCorner ? "L" : f.type == LandmarkType::Junction ? "T" : "X";
      int best = -1;
      double bd = 3.0;
      for (size_t k = 0; k < im.corners.size(); ++k) {
        const double d = (im.corners[k].p - Eigen::Vector2d(f.u, f.v)).norm();
        if (!used[k] && im.corners[k].type == type && d <= bd) {
          bd = d;
          best = static_cast<int>(k);
        }
      }
      const int x = static_cast<int>(std::lround(f.u)), y = static_cast<int>(std::lround(f.v));
      if (best < 0 && x >= 0 && y >= 0 && x < im.mask.cols && y < im.mask.rows && im.mask.at<uint8_t>(y, x)) continue;
      ++c_det_;
      if (best >= 0) {
        used[best] = 1;
        ++c_ok_;
        c_err_ += bd;
      } else if (verbose_) {
        std::printf("  %s: false %s at (%.1f, %.1f)\n", im.name.c_str(), type.c_str(), f.u, f.v);
      }
    }
    for (size_t k = 0; k < im.corners.size(); ++k) {
      ++c_gt_;
      c_hit_ += used[k];
      c_type_[im.corners[k].type].first++;
      c_type_[im.corners[k].type].second += used[k];
      if (verbose_ && !used[k])
        std::printf("  %s: missed %s at (%.1f, %.1f)\n", im.name.c_str(), im.corners[k].type.c_str(), im.corners[k].p.x(),
                    im.corners[k].p.y());
    }
  }

  const double gap_max_;
  const bool verbose_ = std::getenv("STEREOLOC_BENCH_VERBOSE") != nullptr;
  ScoreRules rules_;
  cv::Ptr<cv::LineSegmentDetector> lsd_;
  cv::Mat luma_, canny_;
  FailureBreakdown why_centre_, why_edge_;
  SegStats ours_centre_, ours_edge_, hough_edge_, lsd_edge_;
  long cls_n_ = 0, cls_ok_ = 0, c_gt_ = 0, c_hit_ = 0, c_det_ = 0, c_ok_ = 0;
  double c_err_ = 0;
  std::map<std::string, std::pair<long, long>> c_type_;  // per corner type: labelled, recalled
};

// CPU time per image on the photographs against rendered left images, same run, and the work
// each gives the frontend.
struct RealTimings {
  double t_real = 0, t_rendered = 0, ratio = 0, t_hough = 0, t_lsd = 0;
  double edges_real = 0, segments_real = 0, edges_rendered = 0, segments_rendered = 0;  // per image
};

RealTimings timeReal(Frontend& fe, const std::vector<const cv::Mat*>& real_imgs, Frontend& fe_rendered,
                     const std::vector<const cv::Mat*>& rendered_imgs) {
  auto ours = [&](Frontend& f) { return [&f](const cv::Mat& m) { benchmark::DoNotOptimize(f.detectFeatures(m).features.size()); }; };
  // Real and rendered passes alternate, so both see the same machine load; the ratio is the
  // median of the per-round ratios.
  std::vector<double> tr, tg, ratios;
  for (int round = 0; round < 21; ++round) {
    tr.push_back(timePerImage(real_imgs, 1, ours(fe)));
    tg.push_back(timePerImage(rendered_imgs, 1, ours(fe_rendered)));
    ratios.push_back(tr.back() / tg.back());
  }
  RealTimings t;
  t.t_real = medianOf(tr);
  t.t_rendered = medianOf(tg);
  t.ratio = medianOf(ratios);
  auto meanWork = [](Frontend& f, const std::vector<const cv::Mat*>& imgs, double& edge_px, double& segs) {
    edge_px = segs = 0;
    for (const cv::Mat* m : imgs) {
      segs += static_cast<double>(f.detectFeatures(*m).segments.size()) / imgs.size();
      edge_px += static_cast<double>(f.gradient().edges().size()) / imgs.size();
    }
  };
  meanWork(fe, real_imgs, t.edges_real, t.segments_real);
  meanWork(fe_rendered, rendered_imgs, t.edges_rendered, t.segments_rendered);
  cv::Mat luma, canny;
  std::vector<cv::Vec4i> hp_out;
  std::vector<cv::Vec4f> lsd_out;
  cv::Ptr<cv::LineSegmentDetector> lsd = cv::createLineSegmentDetector(cv::LSD_REFINE_STD);
  t.t_hough = timePerImage(real_imgs, 7, [&](const cv::Mat& m) { bgrToLuma(m, luma); houghP(luma, canny, hp_out); });
  t.t_lsd = timePerImage(real_imgs, 7, [&](const cv::Mat& m) { bgrToLuma(m, luma); lsd->detect(luma, lsd_out); });
  return t;
}

void realTable(const std::string& dir, bool diag, int stage_passes) {
  const std::string rig_path = dir + "/rig.yaml", params_path = dir + "/frontend.yaml";
  const StereoRig rig = std::filesystem::exists(rig_path) ? StereoRig::load(rig_path) : StereoRig();
  const char* env_params = std::getenv("STEREOLOC_BENCH_PARAMS");
  const FrontendParams prm = env_params ? FrontendParams::load(env_params)
                             : std::filesystem::exists(params_path) ? FrontendParams::load(params_path)
                                                                    : FrontendParams();
  Frontend fe(rig, FieldMap::miroSot(), prm);
  const double lmin = fe.params().segments.min_length_px;
  std::vector<RealImage> set;
  for (const std::string& n : realNames(dir)) set.push_back(loadReal(dir, n, lmin));
  RealTally tally(lmin, fe.params().segments.gap_max_px);
  for (const RealImage& im : set) tally.score(im, fe.detectFeatures(im.bgr));
  // Timing, same run: the real images and the left images of rendered pairs (seed 4).
  std::vector<const cv::Mat*> real_imgs, rendered_imgs;
  for (const RealImage& im : set) real_imgs.push_back(&im.bgr);
  buildSets(32, 0, 4);
  for (const Pair& p : setup().general) rendered_imgs.push_back(&p.img.left);
  Frontend fe_rendered(setup().rig, setup().map);
  const RealTimings t = timeReal(fe, real_imgs, fe_rendered, rendered_imgs);

  tally.printSegments(dir, set.size(), diag);
  tally.printClassesAndCorners();
  std::printf("  CPU time per image (median of 21 alternating passes), same run: ours lines + corners %.3f ms real, %.3f ms\n"
              "  rendered left images (32 pairs, seed 4): ratio %.3f (median of the passes' ratios; target <= 1.20);\n"
              "  HoughLinesP %.3f ms, LSD %.3f ms on the real images\n\n",
              t.t_real, t.t_rendered, t.ratio, t.t_hough, t.t_lsd);
  std::printf("  work per image: %.0f edge pixels and %.1f segments real, %.0f and %.1f rendered\n\n", t.edges_real,
              t.segments_real, t.edges_rendered, t.segments_rendered);
  if (stage_passes > 0) stageTable(fe, real_imgs, fe_rendered, rendered_imgs, stage_passes);
  std::printf("  thesis Table 6.1 (GBHT on real camera images, bad illumination): 48 lines, 50 detected, 3 missed,\n"
              "  5 spurious (recall 93.8%%, precision 90.0%%); 16 corners, 13 detected (recall 81.3%%)\n\n");
}

// ---- timings ----
void BM_Ours_Full(benchmark::State& st) {
  Setup& s = setup();
  Frontend fe(s.rig, s.map);
  size_t i = 0;
  for (auto _ : st) {
    const Pair& p = s.general[i++ % std::min<size_t>(s.general.size(), 32)];
    benchmark::DoNotOptimize(fe.process(p.img.left, p.img.right, 0.0).observations.size());
  }
}
void BM_Ours_SegmentsOnly(benchmark::State& st) {
  Setup& s = setup();
  Frontend fe(s.rig, s.map);
  size_t i = 0;
  for (auto _ : st) {
    const Pair& p = s.general[i++ % std::min<size_t>(s.general.size(), 32)];
    benchmark::DoNotOptimize(fe.detectSegments(p.img.left).size());
  }
}
// The same without the bend/step split and with Algorithm 2's pixel removal as printed: the
// cost of those two stages, measured in the same run.
void BM_Ours_SegmentsOnly_NoSplit(benchmark::State& st) {
  Setup& s = setup();
  FrontendParams prm;
  prm.segments.straightness_px = 1e9;
  prm.segments.release_unused = false;
  Frontend fe(s.rig, s.map, prm);
  size_t i = 0;
  for (auto _ : st) {
    const Pair& p = s.general[i++ % std::min<size_t>(s.general.size(), 32)];
    benchmark::DoNotOptimize(fe.detectSegments(p.img.left).size());
  }
}
void BM_OpenCV_HoughLinesP(benchmark::State& st) {
  Setup& s = setup();
  cv::Mat luma, edges;
  std::vector<cv::Vec4i> out;
  size_t i = 0;
  for (auto _ : st) {
    const Pair& p = s.general[i++ % std::min<size_t>(s.general.size(), 32)];
    bgrToLuma(p.img.left, luma);
    houghP(luma, edges, out);
    benchmark::DoNotOptimize(out.size());
  }
}
void BM_OpenCV_LSD(benchmark::State& st) {
  Setup& s = setup();
  cv::Ptr<cv::LineSegmentDetector> lsd = cv::createLineSegmentDetector(cv::LSD_REFINE_STD);
  cv::Mat luma;
  std::vector<cv::Vec4f> out;
  size_t i = 0;
  for (auto _ : st) {
    const Pair& p = s.general[i++ % std::min<size_t>(s.general.size(), 32)];
    bgrToLuma(p.img.left, luma);
    lsd->detect(luma, out);
    benchmark::DoNotOptimize(out.size());
  }
}

}  // namespace

int main(int argc, char** argv) {
  int pairs = 200, goal_pairs = 1300;
  uint64_t seed = 4;
  bool table = true, diag = false;
  int stage_passes = 0;
  std::string real_dir;
  std::vector<char*> rest;
  for (int i = 0; i < argc; ++i) {
    if (std::strncmp(argv[i], "--pairs=", 8) == 0) {
      pairs = std::max(1, std::atoi(argv[i] + 8));
    } else if (std::strncmp(argv[i], "--goal-pairs=", 13) == 0) {
      goal_pairs = std::max(0, std::atoi(argv[i] + 13));
    } else if (std::strncmp(argv[i], "--seed=", 7) == 0) {
      seed = std::strtoull(argv[i] + 7, nullptr, 10);
    } else if (std::strncmp(argv[i], "--real=", 7) == 0) {
      real_dir = argv[i] + 7;
    } else if (std::strncmp(argv[i], "--stages=", 9) == 0) {
      stage_passes = std::max(1, std::atoi(argv[i] + 9));
    } else if (std::strcmp(argv[i], "--stages") == 0) {
      stage_passes = 9;
    } else if (std::strcmp(argv[i], "--diag") == 0) {
      diag = true;
    } else if (std::strcmp(argv[i], "--no-table") == 0) {
      table = false;
    } else {
      rest.push_back(argv[i]);
    }
  }
  if (!real_dir.empty()) {
    try {
      realTable(real_dir, diag, stage_passes);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_frontend: %s\n", e.what());
      return 1;
    }
    return 0;
  }
  int n = static_cast<int>(rest.size());
  buildSets(pairs, table ? goal_pairs : 0, seed);
  if (table) accuracyTable(diag);
  for (auto [name, fn] : {std::pair{"ours_full_frontend_stereo_pair", &BM_Ours_Full},
                          std::pair{"ours_segments_only_left", &BM_Ours_SegmentsOnly},
                          std::pair{"ours_segments_only_left_without_split", &BM_Ours_SegmentsOnly_NoSplit},
                          std::pair{"opencv_canny_houghlinesp_left", &BM_OpenCV_HoughLinesP},
                          std::pair{"opencv_lsd_left", &BM_OpenCV_LSD}})
    benchmark::RegisterBenchmark(name, fn)->Unit(benchmark::kMicrosecond)->Repetitions(5)->ReportAggregatesOnly(true);
  benchmark::Initialize(&n, rest.data());
  benchmark::RunSpecifiedBenchmarks();
  return 0;
}
