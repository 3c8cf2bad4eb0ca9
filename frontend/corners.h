#pragma once
// Stage 6: corners, T-junctions and line intersections from pairs of lines (Algorithm 4, 3.5).
//
// Lines: every marking becomes the centre line of its stripe: the line through the midpoints
// of its two edges when both were found, taken along image rows for a steep stripe and along
// columns for a flat one, where they are the image of the floor centre (the edges converge
// under perspective, and their bisector is not; docs/frontend.md; see piece_gap_px for
// stripes broken by occluders), otherwise its edge moved by half the measured width towards
// the bright side. Crossings (X) are then refined on the image (refineCrossing). Other segments stay edge lines. Map landmarks sit on
// marking centre lines and on the wall foot, so this is where their image positions are.
//
// For each pair of lines at an image angle of at least min_image_angle, the intersection p
// (3.12, 3.13) is kept when it lies inside the image and within delta of both extents
// (the rotated-x test of Algorithm 4: a line's extent is [t_min, t_max] along its direction).
// A line "ends" at p when p is within delta of one of its ends (or beyond it), and "passes"
// p otherwise. Types:
//   marking ends   + marking ends,   floor angle 90 +- corner_angle_tol  -> MarkingCorner (L)
//   marking passes + marking passes, floor angle >= min_crossing_angle   -> Intersection (X)
//   marking ends   + wall foot (ends or passes)                           -> Junction (T)
//   marking ends   + marking passes, floor angle 90 +- corner_angle_tol   -> Junction (T), only
//                                                      with marking_junctions (RoboCup fields)
// Other combinations (two arc chords, wall/wall, marking T marking on MiroSot) are not map
// landmarks and are dropped. The floor angle is measured after back-projecting both lines onto the floor
// with the rig (real marking corners are 90 deg there; the centre circle's chords are not,
// 6.1). Intersections of the same type closer than merge_px (three or more lines meeting)
// are averaged.
#include <opencv2/core/mat.hpp>
#include <vector>

#include "frontend/features.h"
#include "src/core/stereo_rig.h"

namespace stereoloc::frontend {

struct CornerParams {
  double delta_px = 8.0;               // delta (6.1)
  double min_image_angle_deg = 20.0;   // pairs closer to parallel give unstable intersections
  double corner_angle_tol_deg = 20.0;  // |floor angle - 90 deg| for an L corner
  double min_crossing_angle_deg = 45.0;
  double merge_px = 3.0;               // intersections closer than this are one feature
  double centre_merge_deg = 12.0;      // two opposite marking edges -> one centre line when this parallel
  double centre_merge_px = 2.5;        // ... and their centre lines this close (or half the width)
  // Stripes broken by occluders (photographs with robots on the field): a marking edge pairs
  // with the opposite edge overlapping it most, and further pieces of either edge, within
  // centre_merge_px of that edge's line and at most this far beyond the stripe's extent (an
  // occluder's width), extend its centre line. 0: the first opposite edge found is the partner
  // and pieces stay separate lines (the default: on rendered pairs it raises the centre-line
  // figures by 0.1 point, but the image pipeline's batch NEES on `line` from below 4.2 to 4.4,
  // tests/src/study/test_line_consistency.cpp).
  double piece_gap_px = 0.0;
  // A non-marking edge is a wall foot candidate when it is bright above and dark below and its
  // image direction is within this angle of horizontal (deg). Walls seen obliquely near the
  // camera have steep feet in the image (a wall running away at 45 deg on the floor images at
  // 30-60 deg), so 30 deg missed the junctions there; vertical edges (goal posts, triangle
  // sides) stay excluded.
  double wall_foot_max_tilt_deg = 75.0;
  // A marking ending on another marking that runs on, perpendicular on the floor, is a
  // Junction (T) too. MiroSot has no such landmark (its T-junctions are markings on the wall
  // foot), so off by default; RoboCup fields have them at the penalty and goal areas and the
  // halfway line.
  bool marking_junctions = false;
  // snapLineEnds: a line end within snap_px of its intersection with another line (at an image
  // angle of at least snap_min_angle) moves onto it; an end within border_snap_px of the image
  // border moves onto the border.
  double snap_px = 8.0;              // = delta (6.1), the reach of Algorithm 4's end test
  double snap_min_angle_deg = 3.0;   // below, 0.05 px of line noise moves p by > 1 px
  double border_snap_px = 5.5;       // 2 px without gradient + 0.5 to the border + Gap_min
  // Stripe probe (findCorners with the luma image): a junction or L corner needs its marking's
  // stripe to really reach the meeting point. snapLineEnds moves an end up to snap_px onto
  // another line, so a marking that ends at a goal-area corner ~5 px below a wall foot (whose
  // ~1 px wide far arm was not found) was snapped onto the foot and became a junction (bench
  // seeds 5 and 6: 10 of the 23 false detections). The centre line is sampled every 1 px from
  // probe_start_px (plus half the other stripe's width over the sine of the image angle, for a
  // corner) to delta_px from the point; a sample is dark when its luma is below the floor's
  // plus probe_dark_fraction of the stripe's contrast, both measured at the line's middle
  // (stripe on the centre line, floor 0.5 width + probe_side_px across); probe_min_run dark
  // samples in a row reject the feature. Measured: gap samples sit at -3..+4 grey levels of
  // contrast against 150; a 1-2 px stripe straddling two rows dips to 0.38 of its middle's
  // contrast (seed 6), so 0.4 lost true corners and 0.25 does not. probe_min_run <= 0
  // disables the probe.
  double probe_start_px = 1.5;        // the wall foot's edge blurs 1 px; start past it
  double probe_side_px = 2.0;         // floor samples this far outside the stripe's edge
  double probe_dark_fraction = 0.25;  // of the stripe's contrast over the floor
  int probe_min_run = 2;             // consecutive dark samples (px): a gap, not noise
  // Arm probe (findCorners with the luma image): the far arm of a marking corner is often a
  // 1-2 px stripe that the segment stage does not find (bench seed 5: 8 of the 14 missed
  // corners), leaving the other arm with a free end. At each free marking end the missing arm
  // is looked for where the rig puts it: perpendicular to the marking on the floor. Two luma
  // profiles parallel to the marking, 0.5 width + 1.5 and + 4.5 px to one side, over
  // +-delta_px around the end must each show one bounded bump (a stripe crossing, not a wall's
  // step) brighter than the floor by arm_min_contrast of the marking's contrast, at positions
  // that agree within 1.5 px on where the arm meets the centre line; the arm must stay bright
  // for arm_length_px beyond them (one dark sample allowed), nothing may cross on the other
  // side, and the marking must not run on past the arm. arm_length_px <= 0 disables it.
  // Off by default (12 px when on): it finds corners the bench counts (seed 5 recall 88.9 ->
  // 94.4 %, seeds 4 and 6 unchanged), but its corners and traced junctions are less exact
  // (1.3 px in the unit test) and get the same pixel sigma as two-line intersections, so the
  // estimators paid for them: `make demo` (40 trials) line batch RMSE 1.7 -> 2.9 mm and NEES
  // 5.24 -> 12.9, circle PF NEES 73 -> 9975. Turn it on only with its own covariance.
  double arm_min_contrast = 0.3;  // thin stripes dip to 0.38 of their contrast (see above)
  double arm_length_px = 0.0;    // px along the arm, samples every 2 px
  // A junction's wall foot must have a wall above it: the luma wall_min_height_px - 1 and
  // wall_min_height_px above the junction, across the foot, is not floor (same dark level as
  // the stripe probe). The lower edge of a thin far marking whose upper edge was not found is
  // bright above and dark below like a wall foot, and a marking meeting it was a junction
  // (bench seeds 5, 6: 3 false junctions on a corner). A wall 50 mm tall is >= 8 px tall in
  // the image up to 1.7 m. <= 0 disables the test.
  double wall_min_height_px = 3.5;
};

// Segments -> lines (see above; the rig gives the horizon for the stripes' centre lines).
// Appends nothing: `lines` is replaced.
void buildLines(const std::vector<Segment>& segments, const StereoRig& rig, const CornerParams& params,
                std::vector<LineFeature>& lines);

// Clips every line's extent to the image [-0.5, width - 0.5] x [-0.5, height - 0.5] (the
// pixel area, where the renderer's truth is clipped too) and drops lines left with no extent.
// A stripe's centre line is built from its two edges' end points and their projections on
// each other, which can lie outside the image where the stripe leaves it at a slant.
void clipLinesToImage(int width, int height, std::vector<LineFeature>& lines);

// Refits the line ends where lines meet (Algorithm 4's intersection (3.12, 3.13), used for the
// extents): an end within snap_px of the intersection with another line moves onto it, when
// the other line ends there too (L, a bend of a wall foot or top) or passes it (T: a marking
// stem at the bar or the wall foot). The edge pixels cannot place such an end: the Sobel
// window blurs the last 1-2 px before a corner, at a shallow bend the next edge stays within
// the fitting band for several px, and a stripe's centre line ends half a width inside the
// bar it meets. Of several candidates the nearest is taken. Ends within border_snap_px of the
// image border are moved onto it. Run after clipLinesToImage.
void snapLineEnds(int width, int height, const CornerParams& params, std::vector<LineFeature>& lines);

// Lines -> point features (types MarkingCorner, Junction, Intersection); `features` is replaced.
// luma (CV_8UC1, the image of the lines) enables the stripe probe (see CornerParams); without
// it the types come from the lines alone.
void findCorners(const std::vector<LineFeature>& lines, const StereoRig& rig, const CornerParams& params,
                 std::vector<PointFeature>& features, const cv::Mat* luma = nullptr);

// The arm probe (see CornerParams) at one end of marking line m (its t_max end when at_max_end):
// true with the corner (u, v) on m's centre line when a missing perpendicular arm is found, and
// the arm's unit image direction in (arm_dx, arm_dy) when given.
bool probeMissingArm(const cv::Mat& luma, const StereoRig& rig, const LineFeature& m, bool at_max_end,
                     const CornerParams& params, double& u, double& v, double* arm_dx = nullptr,
                     double* arm_dy = nullptr);

// Follows an arm found by probeMissingArm (from corner (u, v), unit direction (ax, ay)) to the
// nearest wall foot among `lines` it crosses more than delta_px away: true with the junction
// (ju, jv) when the arm's centre line is bright (as in the stripe probe) all the way to it.
bool traceArmToWallFoot(const cv::Mat& luma, const std::vector<LineFeature>& lines, const LineFeature& m, double u,
                        double v, double ax, double ay, const CornerParams& params, double& ju, double& jv);

// The image row of the horizon (the floor's vanishing line) of the rig's left camera. Image rows
// are parallel to it (the rig has no roll).
double horizonRow(const StereoRig& rig);

// Moves the crossing (u, v) of marking lines a and b onto where their stripes cross: each
// line is the fit over its whole extent, and a curved marking (the centre circle's arcs) fitted
// with one line misses the crossing by a few tenths of a px (the circle seen from its centre:
// 0.25 px in the row, which the floor's disparity per row turns into a disparity error of the
// same sign in every view). Near the crossing, each stripe's centre is measured on 8 profiles
// on each side, clear of the other stripe (along rows for a steep stripe, along columns for a
// flat one, as in buildLines, with the horizon at horizon_row), and fitted with a quadratic in
// the line coordinate, whose value and slope at the crossing give the local line. False (and
// (u, v) unchanged) when a stripe has fewer than 3 profiles on a side, or the local lines move
// the crossing by more than 2 px.
bool refineCrossing(const cv::Mat& luma, const LineFeature& a, const LineFeature& b, double horizon_row, double& u,
                    double& v);

// The crossing's column and row in the right image of a rectified pair (px), for the crossing
// of marking lines a and b at left pixel (u_left, v_left) matched near column u_right (the patch
// correlation's, whose sub-pixel fit on the crossing's aliased image is off by 0.25 px RMS in the
// ideal world). Each line is carried to the right image through its floor points, re-measured
// there as refineCrossing does (a first pass 4 px wide, for rows a calibration error misaligns),
// and crossed. The right image of the crossing is that of the same floor point whatever the
// rows' misalignment, so no slide. False (outputs unchanged) when refineCrossing would fail or
// the crossing is more than 4 px from (u_right, v_left).
bool crossingInRightImage(const cv::Mat& right_luma, const StereoRig& rig, const LineFeature& a, const LineFeature& b,
                          double u_left, double v_left, double& u_right, double& v_right);

// The stripe probe: true unless marking line m's centre line shows a gap (probe_min_run dark
// samples) between s0 px and delta_px from the point at line coordinate tp, going into m.
// Also true when the probe cannot judge (reference contrast below 4 grey levels, or samples
// outside the image).
bool stripeReaches(const cv::Mat& luma, const LineFeature& m, double tp, double s0, const CornerParams& params);

// Intersection of the left-camera ray through pixel (u, v) with the floor, in the robot frame
// C0 at head pan 0 (mm). False when the ray does not go down.
bool floorPoint(const StereoRig& rig, double u, double v, double& x, double& y);

}  // namespace stereoloc::frontend
