#pragma once
// Stage 4: peak verification and segment completion (Algorithm 2), with a least-squares refit.
//
// For each peak, strongest first:
//  1. collect the unused edge pixels whose gradient direction is within +-direction_tolerance
//     of theta and that lie within rho_step/2 + 1 px of the peak's line;
//  2. fit the line by total least squares to the longest run of them without a gap over Gap_min
//     along the line (the seed: a cell often holds pieces of several lines a few deg apart),
//     take the offset where the pixels concentrate at that
//     angle (a histogram of their distances), then re-collect within +-band_px of it and
//     refit (refit_iterations times): this is the "connected pixels in compliance with theta"
//     step, done geometrically, and the recomputation of rho and theta that section 3.7
//     suggests; the sub-pixel band keeps parallel edges 1-2 px apart apart;
//  3. project the pixels onto the line ("rotate by Omega", Fig. 3.6), sort, split where
//     consecutive pixels are more than gap_min apart, drop pieces shorter than min_piece_px
//     (isolated noise), merge pieces closer than gap_max, and keep the results at least
//     min_length long with at least min_density pixels per px of length;
//  4. refit each kept segment on its own pixels: sub-pixel theta, rho and endpoints;
//  5. mark the collected pixels used, so later (weaker) peaks cannot reuse them;
//  6. repeat 1-5 for the same peak on the pixels left (up to rounds_per_peak times);
//  7. merge segments of different peaks that are one line (mergeCollinear in segments.cpp):
//     collinear within straightness_px, not overlapping, closer than Gap_max.
// Order note: the thesis drops pieces shorter than L_min before merging; we merge first, so a
// line broken by noise into short pieces still comes out whole.
#include <cstdint>
#include <opencv2/core/mat.hpp>
#include <utility>
#include <vector>

#include "frontend/features.h"
#include "frontend/peaks.h"

namespace stereoloc::frontend {

struct SegmentParams {
  double gap_min_px = 3.0;          // Gap_min (6.1)
  double gap_max_px = 50.0;         // Gap_max (6.1)
  double min_length_px = 30.0;      // L_min (6.1)
  double min_piece_px = 4.0;        // pieces shorter than this (after the Gap_min split) are noise
  double min_density = 0.4;         // supporting pixels per px of segment length
  double direction_tolerance_deg = 10.0;  // pixel gradient vs line direction
  // Max distance of a pixel from the refitted line, px. Sub-pixel on purpose: far away, a wall
  // foot, a goal foot and a marking edge lie 1-2 px apart at the same image angle and one
  // Hough cell (3 px) holds them all; a least-squares line through all of them belongs to
  // none. So the line's offset is first put where the pixels concentrate (the densest
  // 2 band_px wide window of their distances at the fitted angle), and only pixels within
  // +-band_px of it, then of its refit, belong to it; the others stay for the next round.
  double band_px = 1.0;
  // ... and pixels out to this far from it join the line where they are its nearest pixel at
  // their position along it (1 px cells; see extract()): since the renderer integrates edge
  // pixels over their area (adc1c70), a far edge's pixels follow its true 1-3 deg bends and its
  // curl into a corner smoothly and stray 1-2 px from one fitted line, and with band_px alone
  // the line stopped short. A parallel edge 1-2 px beside it has pixels at the same positions,
  // nearer ones on the line itself, so the two stay apart. bench_frontend 200 pairs,
  // centre-line recall / precision without -> with (2.0): seed 4 55.5 / 61.0 -> 61.4 / 65.5 %,
  // seed 5 53.8 / 59.8 -> 58.4 / 63.8 %, seed 6 54.1 / 58.9 -> 58.6 / 63.5 %; corners within
  // one landmark of it.
  double member_band_px = 2.0;
  int refit_iterations = 2;
  // A group of collinear-looking pixels is split where it bends or steps by more than this:
  // far away, a wall foot, a goal foot and a marking lie a pixel or two apart at image angles
  // of a few degrees, and one Hough cell collects them all.
  double straightness_px = 1.0;
  double straightness_bin_px = 4.0;  // pixels are averaged in bins this long along the line
  // ... and split where two lines fitted to the bin means on either side of the best split are
  // more than this far apart there (a step; see splitAtBends). Douglas-Peucker alone missed
  // steps near a run's end: a far wall foot with the goal foot 1.9 px behind it, which have a
  // 34 px gap between them where the weak goal foot has no pixels, stayed within 1 px of DP's
  // chord and came out as one compromise line (bench_frontend seed 4, pair 1). 0: off.
  // bench_frontend 200 pairs, centre-line recall / precision without -> with (1.5): seed 4
  // 61.4 / 65.5 -> 61.7 / 65.8 %, seed 5 58.4 / 63.8 -> 58.5 / 63.7 %, seed 6 58.6 / 63.5 ->
  // 58.8 / 63.8 % (corner precision 90.6 -> 92.0 %). 1.0 split the tops of walls and goals,
  // whose truth is one edge where it is straight within 1 px (seed 4: 61.4 / 65.6 %, corner
  // recall 96.0 -> 95.2 %).
  double step_px = 1.5;
  // ... or where the shorter of those two lines' outer bin lies more than this off the longer
  // one, extended (a bend DP misses: in the middle of a run the chord passes a bend at half the
  // tail's deviation). Far away a wall foot runs on into the next wall's or the goal's foot at
  // 1-3 deg, and the segment ran 10-20 px past its corner. bench_frontend seed 4 (with
  // step_px 1.5) 61.7 / 65.8 -> 62.3 / 66.9 %, corners 96.0 / 96.0 -> 96.0 / 96.7 %; 0.8
  // gave 61.8 / 66.5 % but corner recall 94.4 %. 0: off.
  // Off by default: after the corner probes (corners.h) it costs corners on seed 6. Measured
  // (200 pairs; 1.0 -> 0): segments seed 4 62.3 / 66.9 -> 61.7 / 65.8 %, seed 5 58.4 / 64.4 ->
  // 58.5 / 63.7 %, seed 6 59.6 / 64.8 -> 58.8 / 63.8 %; corners seed 4 97.6 / 100 -> 97.6 /
  // 98.4 %, seed 5 94.4 / 96.0 -> 94.4 / 96.8 %, seed 6 93.5 / 98.3 -> 95.2 / 97.5 %. The
  // segment gain is 1 point against a 97 % target far away; corner recall >= 95 % is near.
  double tail_px = 0.0;
  // A peak is verified again on its leftover pixels (the next of several edges in one cell,
  // whose own peaks Algorithm 1's window suppressed), at most this many times. Each round fits
  // from the longest gap-free run of the cell's pixels (the seed), so the others need a round.
  int rounds_per_peak = 3;
  // Remove only the pixels of accepted segments (true), or every pixel a peak collected
  // (false, Algorithm 2 as printed): a peak that straddles two nearby lines must not eat the
  // pixels of the one it does not keep.
  bool release_unused = true;
};

// Reusable buffers of splitAtBends (no allocation once warmed up).
struct BendScratch {
  struct Bin {
    double t, d;
    int first;
  };
  std::vector<Bin> bins;
  std::vector<uint8_t> keep;
  std::vector<std::pair<int, int>> stack;
  std::vector<std::pair<int, int>> runs;
  std::vector<double> sums;
};

// Splits the pixels [begin, end) (sorted by their coordinate t along the line theta) into
// straight runs: the mean pixel of every bin_px-long stretch is a vertex of a polyline, which
// is simplified by Douglas-Peucker with tolerance tol_px; every kept interior vertex is a split,
// then moved (within +-2 bins) to where the two runs' own fitted lines explain the pixels best.
// With step_px > 0 each run is also split where two lines fitted to the bin means on either side
// of the best split (least squared residual) are more than step_px apart there: a step, which
// DP misses near a run's end; with tail_px > 0 also where the shorter line's outer bin mean lies
// more than tail_px off the longer line (a bend). Appends the run boundaries (indices into [begin, end), ascending,
// first 0, last end-begin) to `cuts`. Runs shorter than 2 bins are never split further.
void splitAtBends(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta, double bin_px,
                  double tol_px, std::vector<int>& cuts, double step_px = 0.0, double tail_px = 0.0);
void splitAtBends(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta, double bin_px,
                  double tol_px, std::vector<int>& cuts, BendScratch& scratch, double step_px = 0.0,
                  double tail_px = 0.0);

class SegmentExtractor {
 public:
  // `used` has one flag per edge pixel (resized and cleared here). Replaces `segments`.
  // width, height: the image size (0: unknown). The gradient stage computes no edge pixels in
  // the outer 2 px, so a piece whose end pixel lies within 2.5 + Gap_min px of the image border
  // (measured along the line) is credited the length up to the border in the L_min test: a
  // 30 px edge leaving the image would otherwise show only 27.5 px and be dropped.
  void extract(const std::vector<EdgePixel>& edges, const std::vector<HoughPeak>& peaks, double rho_step_px,
               const SegmentParams& params, std::vector<uint8_t>& used, std::vector<Segment>& segments,
               int width = 0, int height = 0);
  // Edge-pixel indices of segment i of the last extract() call (same order as `segments`).
  const int* pixelsBegin(size_t i) const { return pix_.data() + off_[i]; }
  const int* pixelsEnd(size_t i) const { return pix_.data() + off_[i + 1]; }
  // true: the pools are filled and filtered pixel by pixel through `edges` and `used` (the
  // reference the branch-free scans of fillPool() and collect() are tested against; the same
  // pools and segments either way).
  void setReferencePools(bool reference) { reference_pools_ = reference; }

 private:
  void collect(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used, double theta, double rho,
               double band, int tol_bins);
  void fillPool(const std::vector<EdgePixel>& edges, const std::vector<uint8_t>& used, double theta, double rho,
                double band, int tol_bins);
  // The phases of extract(): the pixels sorted by direction bin (and their bounding box); the
  // longest gap-free run of the candidates along the peak's line as the fit's seed (false: none
  // as long as min_piece_px); the shift of rho to the densest band of the candidates (false:
  // none); the candidates that pass the direction test and the nearest-pixel rule, marked used,
  // sorted along the line in proj_ (false: fewer than min_pixels); and the pieces of proj_ split
  // at Gap_min, merged under Gap_max, cut at bends and appended to `segments`.
  struct BorderCredit;  // the L_min test's credit for an end near the image border (see extract)
  void bucketByDirection(const std::vector<EdgePixel>& edges);
  bool seedLongestRun(const std::vector<EdgePixel>& edges, double theta, const SegmentParams& prm);
  bool densestBand(const std::vector<EdgePixel>& edges, double theta, double rho, double rho_step_px,
                   const SegmentParams& prm, double* shift);
  // (c, s: cos and sin of theta, computed once for both.)
  bool lineMembers(const std::vector<EdgePixel>& edges, std::vector<uint8_t>& used, double theta, double c, double s,
                   double rho, double tol_cos, double min_pixels, const SegmentParams& prm);
  void splitAndEmit(const std::vector<EdgePixel>& edges, std::vector<uint8_t>& used, double theta, double c, double s,
                    double rho, const SegmentParams& prm, const BorderCredit& border_credit,
                    std::vector<Segment>& segments);
  // The current peak's candidate pixels (bins pool_b0_ +- pool_tol_bins_, offsets per bin).
  std::vector<int> pool_, pool_off_;
  double pool_theta_ = 0, pool_rho_ = 0, pool_band_ = 0;
  int pool_b0_ = 0, pool_tol_bins_ = 0;
  bool pool_valid_ = false;
  double box_[4] = {0, 0, 0, 0};  // edge-pixel bounding box x0, y0, x1, y1
  std::vector<int> merge_pix_;
  struct Piece {
    size_t b, e;
    float t0, t1;
  };
  std::vector<Piece> merged;
  std::vector<int> bucket_start_, bucket_items_;
  // Positions of the pixels in bucket order and of the pool's pixels in pool order, and whether
  // each pixel is used (edge-pixel index order): contiguous operands for the scans.
  std::vector<float> bucket_x_, bucket_y_, pool_x_, pool_y_;
  bool reference_pools_ = false;
  std::vector<int> cand_;
  std::vector<std::pair<float, int>> proj_;
  std::vector<uint64_t> keys_, sorted_keys_;
  std::vector<int> key_start_;
  std::vector<int> pix_, off_;
  std::vector<int> piece_, cuts_;
  std::vector<int> hist_, seed_;
  BendScratch bend_scratch_;
};

// Algorithm 2 merges the pieces of one line closer than Gap_max, but only within one peak's
// pixels; a line whose pieces voted into neighbouring Hough cells comes out as several
// segments. This merges two segments of the same gradient direction (within 2 deg) whose end
// points all lie within straightness_px of the line fitted to both pixel sets, that overlap by
// at most Gap_min and are less than Gap_max apart, and refits them (repeated until no pair
// merges). `pix` and `off` hold each segment's edge-pixel indices (segment i is
// pix[off[i]] .. pix[off[i + 1]]) and are updated with the segments; `scratch` is a buffer.
void mergeCollinearSegments(const std::vector<EdgePixel>& edges, const SegmentParams& params,
                            std::vector<Segment>& segments, std::vector<int>& pix, std::vector<int>& off,
                            std::vector<int>& scratch);

// Moves each end of a segment to where the step across it fades to half its contrast, by
// sampling the luma on both sides (+-1.5 px) along the line from 2 px inside to 4 px beyond
// the last edge pixel. The Sobel window loses the last 1-2 px before a corner (their
// gradient turns), so the edge pixels alone end short.
void refineEndpoints(const cv::Mat& luma, std::vector<Segment>& segments);

// Total-least-squares line through the given edge pixels, directed to agree with
// theta_hint. Returns false when fewer than 2 pixels or degenerate.
bool fitLine(const std::vector<EdgePixel>& edges, const int* begin, const int* end, double theta_hint, double& theta,
             double& rho, double* rms = nullptr);

}  // namespace stereoloc::frontend
