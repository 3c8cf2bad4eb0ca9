// Stage 4: peak verification and segment completion (Algorithm 2).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "frontend/gbht.h"
#include "frontend/gradient.h"
#include "frontend/peaks.h"
#include "frontend/segments.h"

using namespace stereoloc::frontend;
using stereoloc::kTwoPi;

namespace {

struct Pipeline {
  GradientStage g;
  HoughAccumulator acc;
  SegmentExtractor ex;
  std::vector<HoughPeak> peaks;
  std::vector<uint8_t> used;
  std::vector<Segment> segs;
  void operator()(const cv::Mat& img, const SegmentParams& sp = SegmentParams()) {
    g.compute(img, GradientParams());
    acc.configure(img.cols, img.rows, HoughParams());
    acc.vote(g.edges(), {});
    detectPeaks(acc, PeakParams(), peaks);
    ex.extract(g.edges(), peaks, 3.0, sp, used, segs);
    refineEndpoints(img, segs);
  }
  // Segments whose direction is within 5 deg of theta.
  std::vector<Segment> along(double theta) const {
    std::vector<Segment> out;
    for (const Segment& s : segs)
      if (std::cos(s.theta - theta) > std::cos(5 * kTwoPi / 360)) out.push_back(s);
    return out;
  }
};

// A bright band y in [y0, y0 + hgt) from x0 to x1, drawn with 4x4 supersampling along a slope.
cv::Mat slantedBand(double y0, double slope, double x0, double x1, double hgt, int w = 200, int h = 120) {
  cv::Mat img(h, w, CV_8UC1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      int in = 0;
      for (int k = 0; k < 16; ++k) {
        const double sx = x - 0.5 + (k % 4 + 0.5) / 4, sy = y - 0.5 + (k / 4 + 0.5) / 4;
        const double top = y0 + slope * sx;
        in += (sx >= x0 && sx <= x1 && sy >= top && sy < top + hgt) ? 1 : 0;
      }
      img.at<uint8_t>(y, x) = static_cast<uint8_t>(30 + 180 * in / 16);
    }
  return img;
}

}  // namespace

TEST(Segments, SubPixelLineAndEndpoints) {
  // Top edge of a band: y = 40.3 + 0.1 x from x = 20 to 180, bright below (theta ~ 90 deg).
  Pipeline run;
  run(slantedBand(40.3, 0.1, 20, 180, 30));
  const auto top = run.along(std::atan2(1.0, -0.1));
  ASSERT_EQ(top.size(), 1u);
  const Segment& s = top[0];
  // Expected line: -0.1 x + y = 40.3, normalised.
  const double n = std::hypot(0.1, 1.0);
  EXPECT_NEAR(s.theta, std::atan2(1.0 / n, -0.1 / n), 0.2 * kTwoPi / 360);
  EXPECT_NEAR(s.rho, 40.3 / n, 0.15);
  const double xa = std::min(s.x1, s.x2), xb = std::max(s.x1, s.x2);
  EXPECT_NEAR(xa, 20.0, 0.5);
  EXPECT_NEAR(xb, 180.0, 0.5);
  EXPECT_LT(s.rms, 0.2);
}

TEST(Segments, OccludedLineBecomesOneSegment) {
  // A horizontal step edge y = 60 (bright below) hidden by a "ball" (a disc of the bright
  // colour drawn over it) of 30 px diameter in the middle.
  cv::Mat img(120, 200, CV_8UC1, cv::Scalar(30));
  cv::rectangle(img, cv::Rect(10, 60, 180, 60), cv::Scalar(200), cv::FILLED);
  cv::circle(img, cv::Point(100, 60), 15, cv::Scalar(120), cv::FILLED, cv::LINE_AA);
  Pipeline run;
  run(img);
  const auto segs = run.along(kTwoPi / 4);  // bright below: gradient points down (+y)
  ASSERT_EQ(segs.size(), 1u);
  EXPECT_NEAR(std::min(segs[0].x1, segs[0].x2), 11, 2.0);
  EXPECT_NEAR(std::max(segs[0].x1, segs[0].x2), 188, 2.0);
}

TEST(Segments, DashedLineSplitsAtGapMinAndMergesUnderGapMax) {
  // Dashes of 40 px along y = 50 (edge of bright blocks), gaps of `gap` px.
  auto dashed = [](int gap) {
    cv::Mat img(100, 320, CV_8UC1, cv::Scalar(30));
    for (int x = 5; x + 40 < 320; x += 40 + gap) cv::rectangle(img, cv::Rect(x, 50, 40, 30), cv::Scalar(200), cv::FILLED);
    return img;
  };
  Pipeline run;
  SegmentParams sp;  // Gap_min 3, Gap_max 50, L_min 30
  run(dashed(20), sp);
  EXPECT_EQ(run.along(kTwoPi / 4).size(), 1u) << "gaps of 20 px < Gap_max merge";
  run(dashed(60), sp);
  EXPECT_GE(run.along(kTwoPi / 4).size(), 3u) << "gaps of 60 px > Gap_max split";
  sp.gap_max_px = 5;  // below the 20 px gaps: split again
  run(dashed(20), sp);
  EXPECT_GE(run.along(kTwoPi / 4).size(), 4u);
  // Pieces shorter than L_min are dropped.
  sp = SegmentParams();
  sp.min_length_px = 300;
  run(dashed(60), sp);
  EXPECT_TRUE(run.along(kTwoPi / 4).empty());
}

TEST(Segments, FitLineIsTotalLeastSquares) {
  std::vector<EdgePixel> px;
  for (int i = 0; i < 20; ++i) {
    EdgePixel e;
    e.x = static_cast<float>(i);
    e.y = static_cast<float>(2.0 * i + 5.0 + ((i % 2) ? 0.1 : -0.1));
    px.push_back(e);
  }
  std::vector<int> idx(px.size());
  for (size_t i = 0; i < idx.size(); ++i) idx[i] = static_cast<int>(i);
  double theta, rho, rms;
  ASSERT_TRUE(fitLine(px, idx.data(), idx.data() + idx.size(), 0.0, theta, rho, &rms));
  // Line y = 2x + 5  <=>  (2x - y) / sqrt5 = -5 / sqrt5, directed to agree with theta_hint 0.
  EXPECT_NEAR(std::cos(theta), 2 / std::sqrt(5.0), 1e-3);
  EXPECT_NEAR(rho, -5 / std::sqrt(5.0), 0.05);
  EXPECT_NEAR(rms, 0.1 / std::sqrt(5.0), 0.01);
  EXPECT_FALSE(fitLine(px, idx.data(), idx.data() + 1, 0.0, theta, rho));
}

namespace {
// Edge pixels along y = y0 + slope x (theta = 90 deg: gradient pointing down the image).
void addChain(std::vector<EdgePixel>& e, double x0, double x1, double y0, double slope, double jitter = 0.0) {
  int k = 0;
  for (double x = x0; x <= x1; x += 1.0, ++k) {
    EdgePixel p;
    p.x = static_cast<float>(x);
    p.y = static_cast<float>(y0 + slope * x + ((k % 3) - 1) * jitter);
    p.ix = static_cast<int16_t>(std::lround(p.x));
    p.iy = static_cast<int16_t>(std::lround(p.y));
    p.angle = static_cast<float>(kTwoPi / 4);
    e.push_back(p);
  }
}
std::vector<int> sortedAlong(const std::vector<EdgePixel>& e, double theta) {
  std::vector<int> idx(e.size());
  for (size_t i = 0; i < e.size(); ++i) idx[i] = static_cast<int>(i);
  std::sort(idx.begin(), idx.end(), [&](int a, int b) {
    return -e[a].x * std::sin(theta) + e[a].y * std::cos(theta) < -e[b].x * std::sin(theta) + e[b].y * std::cos(theta);
  });
  return idx;
}
}  // namespace

// Far away, a wall foot and the next wall's foot meet at an image angle of ~3 deg; one Hough
// cell collects both. Before the fix they came out as one segment running past both ends.
TEST(Segments, SplitAtBendsCutsAShallowBend) {
  std::vector<EdgePixel> e;
  addChain(e, 0, 59, 50.0, 0.0, 0.1);
  addChain(e, 60, 140, 50.0 - 60 * 0.05, 0.05, 0.1);  // +2.9 deg from x = 60 on
  const double theta = kTwoPi / 4;
  const std::vector<int> idx = sortedAlong(e, theta);
  std::vector<int> cuts;
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 0.75, cuts);
  ASSERT_EQ(cuts.size(), 3u);
  EXPECT_EQ(cuts.front(), 0);
  EXPECT_EQ(cuts.back(), static_cast<int>(idx.size()));
  EXPECT_NEAR(e[idx[cuts[1]]].x, 60.0, 3.0);  // refined: a bin alone is 4 px, DP's vertex up to 8
}

TEST(Segments, SplitAtBendsKeepsANoisyStraightLineWhole) {
  std::vector<EdgePixel> e;
  addChain(e, 0, 200, 30.0, 0.02, 0.3);
  const double theta = std::atan2(1.0, -0.02);
  const std::vector<int> idx = sortedAlong(e, theta);
  std::vector<int> cuts;
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 0.75, cuts);
  EXPECT_EQ(cuts.size(), 2u);
}

// Two parallel edges 2 px apart, end to end (a goal foot recessed behind a wall foot): a step.
TEST(Segments, SplitAtBendsCutsAStep) {
  std::vector<EdgePixel> e;
  addChain(e, 0, 70, 40.0, 0.0);
  addChain(e, 72, 150, 42.0, 0.0);
  const double theta = kTwoPi / 4;
  const std::vector<int> idx = sortedAlong(e, theta);
  std::vector<int> cuts;
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 0.75, cuts);
  ASSERT_GE(cuts.size(), 3u);
  bool near_step = false;
  for (size_t k = 1; k + 1 < cuts.size(); ++k) near_step |= std::fabs(e[idx[cuts[k]]].x - 71.0) < 6.0;
  EXPECT_TRUE(near_step);
}

// A far wall foot and the goal foot 1.7 px behind it, end to end with a gap where the weak goal
// foot has no pixels: Douglas-Peucker's chord passes within 0.85 px of every bin (a step h in
// the middle deviates by h / 2), so only the two-line step test cuts it, in the gap.
TEST(Segments, SplitAtBendsStepTestCutsAStepDouglasPeuckerMisses) {
  std::vector<EdgePixel> e;
  addChain(e, 0, 60, 40.0, 0.0);
  addChain(e, 90, 180, 41.7, 0.0);
  const double theta = kTwoPi / 4;
  const std::vector<int> idx = sortedAlong(e, theta);
  std::vector<int> cuts;
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 1.0, cuts);  // DP only
  EXPECT_EQ(cuts.size(), 2u);
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 1.0, cuts, SegmentParams().step_px);
  ASSERT_EQ(cuts.size(), 3u);
  // In the gap: the pixels on either side of the cut are the runs' ends (t = -x here).
  EXPECT_EQ(e[idx[cuts[1] - 1]].x, 90.0f);
  EXPECT_EQ(e[idx[cuts[1]]].x, 60.0f);
  // A straight noisy line and a shallow bend (no offset where the two lines meet) stay whole.
  std::vector<EdgePixel> f;
  addChain(f, 0, 200, 30.0, 0.02, 0.3);
  const double th = std::atan2(1.0, -0.02);
  const std::vector<int> jdx = sortedAlong(f, th);
  splitAtBends(f, jdx.data(), jdx.data() + jdx.size(), th, 4.0, 1.0, cuts, SegmentParams().step_px);
  EXPECT_EQ(cuts.size(), 2u);
  std::vector<EdgePixel> g;
  addChain(g, 0, 100, 50.0, 0.0);
  addChain(g, 101, 200, 50.0 - 100 * 0.01, 0.01);  // +0.6 deg: 1 px off the chord at most
  const std::vector<int> gdx = sortedAlong(g, kTwoPi / 4);
  splitAtBends(g, gdx.data(), gdx.data() + gdx.size(), kTwoPi / 4, 4.0, 1.0, cuts, SegmentParams().step_px);
  EXPECT_EQ(cuts.size(), 2u);
}

// A far wall foot running on into the next wall's foot at 0.9 deg, the bend in the middle: DP's
// chord passes the bend at 0.73 px (half the tail's 1.46 px), the two lines meet there without
// a step, and only the tail test (the short line's outer bin against the long line) cuts it.
TEST(Segments, SplitAtBendsTailTestCutsABendInTheMiddle) {
  std::vector<EdgePixel> e;
  addChain(e, 0, 100, 50.0, 0.0);
  addChain(e, 101, 200, 50.0 - 100 * 0.015, 0.015);
  const double theta = kTwoPi / 4;
  const std::vector<int> idx = sortedAlong(e, theta);
  const SegmentParams prm;
  std::vector<int> cuts;
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 1.0, cuts, prm.step_px, 0.0);
  EXPECT_EQ(cuts.size(), 2u);
  constexpr double kTailPx = 1.0;  // the setting measured in segments.h (off by default)
  splitAtBends(e, idx.data(), idx.data() + idx.size(), theta, 4.0, 1.0, cuts, prm.step_px, kTailPx);
  ASSERT_EQ(cuts.size(), 3u);
  EXPECT_NEAR(e[idx[cuts[1]]].x, 100.5, 3.0);
  // A straight noisy line stays whole.
  std::vector<EdgePixel> f;
  addChain(f, 0, 200, 30.0, 0.02, 0.3);
  const double th = std::atan2(1.0, -0.02);
  const std::vector<int> jdx = sortedAlong(f, th);
  splitAtBends(f, jdx.data(), jdx.data() + jdx.size(), th, 4.0, 1.0, cuts, prm.step_px, kTailPx);
  EXPECT_EQ(cuts.size(), 2u);
}

// A peak straddling two near-collinear edges used to remove the pixels of both; the edge
// it did not keep must still come out (release_unused).
TEST(Segments, TwoEdgesMeetingAtAShallowAngleGiveTwoSegments) {
  cv::Mat img(120, 240, CV_8UC1, cv::Scalar(30));
  // Bright below a polyline: flat at y = 60 for x < 110, then sloping down at 4 deg.
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      int in = 0;
      for (int k = 0; k < 16; ++k) {
        const double sx = x - 0.5 + (k % 4 + 0.5) / 4, sy = y - 0.5 + (k / 4 + 0.5) / 4;
        const double top = sx < 110 ? 60.0 : 60.0 + (sx - 110) * std::tan(4.0 * kTwoPi / 360);
        in += sy >= top ? 1 : 0;
      }
      img.at<uint8_t>(y, x) = static_cast<uint8_t>(30 + 180 * in / 16);
    }
  Pipeline run;
  run(img);
  const std::vector<Segment> segs = run.along(kTwoPi / 4);
  int flat = 0, sloped = 0;
  for (const Segment& s : segs) {
    const double slope = (s.y2 - s.y1) / (s.x2 - s.x1);
    if (std::fabs(slope) < 0.01 && std::max(s.x1, s.x2) < 116) ++flat;
    if (std::fabs(slope - std::tan(4.0 * kTwoPi / 360)) < 0.01 && std::min(s.x1, s.x2) > 104) ++sloped;
  }
  EXPECT_EQ(flat, 1);
  EXPECT_EQ(sloped, 1);
}

namespace {
// Edge pixels of a horizontal edge y = y0 + slope (x - x0) for x in [x0, x1], gradient down.
void addEdge(std::vector<EdgePixel>& edges, double x0, double x1, double y0, double slope) {
  for (int x = static_cast<int>(x0); x <= static_cast<int>(x1); ++x) {
    EdgePixel e;
    e.x = static_cast<float>(x);
    e.y = static_cast<float>(y0 + slope * (x - x0));
    e.ix = static_cast<int16_t>(x);
    e.iy = static_cast<int16_t>(std::lround(e.y));
    e.angle = static_cast<float>(kTwoPi / 4);
    e.mag = 200;
    e.dir_bin = 90;
    edges.push_back(e);
  }
}

// Segments over the pixel ranges [ranges[k].first, ranges[k].second) of `edges`.
void segmentsOf(const std::vector<EdgePixel>& edges, const std::vector<std::pair<int, int>>& ranges,
                std::vector<Segment>& segs, std::vector<int>& pix, std::vector<int>& off) {
  segs.clear();
  pix.clear();
  off.assign(1, 0);
  for (const auto& [b, e] : ranges) {
    for (int i = b; i < e; ++i) pix.push_back(i);
    Segment s;
    ASSERT_TRUE(fitLine(edges, pix.data() + off.back(), pix.data() + pix.size(), kTwoPi / 4, s.theta, s.rho));
    s.x1 = edges[b].x;
    s.y1 = edges[b].y;
    s.x2 = edges[e - 1].x;
    s.y2 = edges[e - 1].y;
    s.pixels = e - b;
    segs.push_back(s);
    off.push_back(static_cast<int>(pix.size()));
  }
}
}  // namespace

// Two pieces of one line (0.3 px apart, 20 px gap) that came from different peaks become one
// segment over both; pieces stepped by 2 px or 1.4 px, bent by 4 deg, or of opposite gradient
// stay apart.
TEST(Segments, CollinearPiecesOfDifferentPeaksMerge) {
  std::vector<EdgePixel> edges;
  addEdge(edges, 20, 100, 50.0, 0.0);   // [0, 81)
  addEdge(edges, 120, 200, 50.3, 0.0);  // [81, 162)
  std::vector<Segment> segs;
  std::vector<int> pix, off, scratch;
  segmentsOf(edges, {{0, 81}, {81, 162}}, segs, pix, off);
  mergeCollinearSegments(edges, SegmentParams(), segs, pix, off, scratch);
  ASSERT_EQ(segs.size(), 1u);
  EXPECT_NEAR(std::min(segs[0].x1, segs[0].x2), 20, 0.1);
  EXPECT_NEAR(std::max(segs[0].x1, segs[0].x2), 200, 0.1);
  EXPECT_EQ(segs[0].pixels, 162);
  ASSERT_EQ(off.size(), 2u);
  EXPECT_EQ(off[1], 162);

  for (int variant = 0; variant < 4; ++variant) {
    edges.clear();
    addEdge(edges, 20, 100, 50.0, 0.0);
    if (variant == 0) addEdge(edges, 120, 200, 52.0, 0.0);                           // 2 px step
    if (variant == 1) addEdge(edges, 101, 181, 50.0, std::tan(4.0 * kTwoPi / 360));  // 4 deg bend
    if (variant == 2) addEdge(edges, 120, 200, 50.3, 0.0);
    if (variant == 3) addEdge(edges, 120, 200, 51.4, 0.0);  // 1.4 px step: a joint fit passes between
    segmentsOf(edges, {{0, 81}, {81, 162}}, segs, pix, off);
    if (variant == 2) {  // opposite gradient: the other side of a stripe
      for (size_t k = 81; k < edges.size(); ++k) edges[k].angle = static_cast<float>(3 * kTwoPi / 4);
      segs[1].theta += kTwoPi / 2;
      segs[1].rho = -segs[1].rho;
    }
    mergeCollinearSegments(edges, SegmentParams(), segs, pix, off, scratch);
    EXPECT_EQ(segs.size(), 2u) << "variant " << variant;
  }
}

// An edge 32 px long that leaves the image shows edge pixels over about 28 px only (none in the
// outer 2 px, and the Sobel window loses the last px before the far corner): with the image
// size, the L_min test (30 px) credits the unobserved frame; without it the piece is dropped.
// The same at the right border.
TEST(Segments, EdgeLeavingTheImageIsCreditedTheUnobservedFrame) {
  for (int right = 0; right < 2; ++right) {
    cv::Mat img(120, 200, CV_8UC1, cv::Scalar(30));
    cv::rectangle(img, cv::Rect(right ? 200 - 32 : 0, 60, 32, 60), cv::Scalar(200), cv::FILLED);
    GradientStage g;
    g.compute(img, GradientParams());
    HoughAccumulator acc;
    acc.configure(img.cols, img.rows, HoughParams());
    acc.vote(g.edges(), {});
    std::vector<HoughPeak> peaks;
    detectPeaks(acc, PeakParams(), peaks);
    SegmentExtractor ex;
    std::vector<uint8_t> used;
    std::vector<Segment> with_size, without;
    ex.extract(g.edges(), peaks, 3.0, SegmentParams(), used, with_size, img.cols, img.rows);
    ex.extract(g.edges(), peaks, 3.0, SegmentParams(), used, without);
    auto horizontal = [](const std::vector<Segment>& v) {
      return std::count_if(v.begin(), v.end(), [](const Segment& s) { return std::fabs(s.y1 - s.y2) < 0.5 && std::fabs(s.y1 - 59.5) < 1; });
    };
    EXPECT_EQ(horizontal(with_size), 1) << "right " << right;
    EXPECT_EQ(horizontal(without), 0) << "right " << right;
  }
}

// One Hough peak whose cell holds pieces of three lines a few degrees apart (as a far corner
// triangle's foot, a wall foot and a goal foot): a fit through all of them has a compromise
// angle that the longest one leaves by more than the band. The fit starts from the longest
// gap-free run (the seed), so that edge comes out whole with its own angle and ends.
TEST(Segments, CellWithSeveralLinesSeedsOnTheLongestRun) {
  std::vector<EdgePixel> edges;
  auto add = [&](double x0, double x1, double y0, double deg) {
    const double a = kTwoPi / 4 + deg * kTwoPi / 360;  // gradient direction (down, tilted)
    for (int x = static_cast<int>(x0); x <= static_cast<int>(x1); ++x) {
      EdgePixel e;
      e.x = static_cast<float>(x);
      e.y = static_cast<float>(y0 + std::tan(deg * kTwoPi / 360) * (x - x0));
      e.ix = static_cast<int16_t>(x);
      e.iy = static_cast<int16_t>(std::lround(e.y));
      e.angle = static_cast<float>(a);
      e.mag = 200;
      e.dir_bin = static_cast<uint16_t>(std::lround(a * 360 / kTwoPi) % 360);
      edges.push_back(e);
    }
  };
  add(10, 50, 52.0, -4.0);   // short piece, tilted the other way
  add(60, 110, 50.0, 0.0);   // short piece
  add(160, 300, 50.0, 5.0);  // the long edge: 141 px at 5 deg
  HoughPeak peak;
  peak.theta = kTwoPi / 4 + 2.0 * kTwoPi / 360;
  peak.rho = 150 * std::cos(peak.theta) + 52.0 * std::sin(peak.theta);
  SegmentExtractor ex;
  std::vector<uint8_t> used;
  std::vector<Segment> segs;
  SegmentParams prm;
  prm.rounds_per_peak = 1;
  ex.extract(edges, {peak}, 3.0, prm, used, segs);
  int long_ok = 0;
  for (const Segment& s : segs) {
    const double xa = std::min(s.x1, s.x2), xb = std::max(s.x1, s.x2), sl = (s.y2 - s.y1) / (s.x2 - s.x1);
    if (std::fabs(xa - 160) < 1 && std::fabs(xb - 300) < 1 && std::fabs(sl - std::tan(5 * kTwoPi / 360)) < 0.002) ++long_ok;
  }
  EXPECT_EQ(long_ok, 1);
}

// Two parallel edges 1.5 px apart in one Hough cell (far away, a wall foot and a goal foot or
// marking edge): a least-squares line through all the pixels lies between them and belongs to
// neither; the offset is put where the pixels concentrate, so the segment is the stronger edge.
TEST(Segments, ParallelEdgesInOneCellGiveTheDenserEdgeNotTheirMean) {
  std::vector<EdgePixel> edges;
  auto add = [&](int x0, int x1, double y) {
    for (int x = x0; x <= x1; ++x) {
      EdgePixel e;
      e.x = static_cast<float>(x);
      e.y = static_cast<float>(y);
      e.ix = static_cast<int16_t>(x);
      e.iy = static_cast<int16_t>(std::lround(y));
      e.angle = static_cast<float>(kTwoPi / 4);
      e.mag = 200;
      e.dir_bin = 90;
      edges.push_back(e);
    }
  };
  add(20, 139, 50.0);  // 120 px
  add(40, 99, 51.5);   // 60 px, 1.5 px below
  HoughPeak peak;
  peak.theta = kTwoPi / 4;
  peak.rho = 50.7;
  SegmentExtractor ex;
  std::vector<uint8_t> used;
  std::vector<Segment> segs;
  ex.extract(edges, {peak}, 3.0, SegmentParams(), used, segs);
  ASSERT_FALSE(segs.empty());
  EXPECT_NEAR(segs[0].rho, 50.0, 0.05);
  EXPECT_NEAR(std::min(segs[0].x1, segs[0].x2), 20, 0.5);
  EXPECT_NEAR(std::max(segs[0].x1, segs[0].x2), 139, 0.5);
}

// A far edge's last pixels curl by more than band_px (the Sobel window turns at the corner,
// or the edge bends by a degree or two): beyond band_px they still belong to the line where
// they are its nearest pixels at their position along it (member_band_px), so the segment
// keeps its whole extent; with member_band_px 0 it ends 3 px short.
TEST(Segments, StrayEndPixelsWithinTheMemberBandKeepTheExtent) {
  std::vector<EdgePixel> edges;
  addEdge(edges, 20, 136, 50.0, 0.0);
  addEdge(edges, 137, 139, 51.2, 0.0);  // the last three pixels 1.2 px off the line
  HoughPeak peak;
  peak.theta = kTwoPi / 4;
  peak.rho = 50.0;
  for (double member : {2.0, 0.0}) {
    SegmentParams prm;
    prm.member_band_px = member;
    SegmentExtractor ex;
    std::vector<uint8_t> used;
    std::vector<Segment> segs;
    ex.extract(edges, {peak}, 3.0, prm, used, segs);
    ASSERT_EQ(segs.size(), 1u) << member;
    EXPECT_NEAR(std::min(segs[0].x1, segs[0].x2), 20, 0.5) << member;
    EXPECT_NEAR(std::max(segs[0].x1, segs[0].x2), member > 0 ? 139 : 136, 0.5) << member;
  }
}
