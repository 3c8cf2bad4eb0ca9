#pragma once
// Stage 6: corners, T-junctions and line intersections from pairs of lines (Algorithm 4, 3.5).
//
// Lines: every marking becomes the centre line of its stripe: the line through the midpoints
// of its two edges when both were found (they converge under perspective), otherwise its edge
// moved by half the measured width towards the bright side. Other segments stay edge lines. Map landmarks sit on
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
// Other combinations (two arc chords, wall/wall, marking T marking) are not map landmarks and
// are dropped. The floor angle is measured after back-projecting both lines onto the floor
// with the rig (real marking corners are 90 deg there; the centre circle's chords are not,
// 6.1). Intersections of the same type closer than merge_px (three or more lines meeting)
// are averaged.
#include <vector>

#include "frontend/features.h"
#include "src/stereo_rig.h"

namespace stereoloc::frontend {

struct CornerParams {
  double delta_px = 8.0;               // delta (6.1)
  double min_image_angle_deg = 20.0;   // pairs closer to parallel give unstable intersections
  double corner_angle_tol_deg = 20.0;  // |floor angle - 90 deg| for an L corner
  double min_crossing_angle_deg = 45.0;
  double merge_px = 3.0;               // intersections closer than this are one feature
  double centre_merge_deg = 12.0;      // two opposite marking edges -> one centre line when this parallel
  double centre_merge_px = 2.5;        // ... and their centre lines this close (or half the width)
  // A non-marking edge is a wall foot candidate when it is bright above and dark below and its
  // image direction is within this angle of horizontal (deg). Walls seen obliquely near the
  // camera have steep feet in the image (a wall running away at 45 deg on the floor images at
  // 30-60 deg), so 30 deg missed the junctions there; vertical edges (goal posts, triangle
  // sides) stay excluded.
  double wall_foot_max_tilt_deg = 75.0;
  // snapLineEnds: a line end within snap_px of its intersection with another line (at an image
  // angle of at least snap_min_angle) moves onto it; an end within border_snap_px of the image
  // border moves onto the border.
  double snap_px = 8.0;              // = delta (6.1), the reach of Algorithm 4's end test
  double snap_min_angle_deg = 3.0;   // below, 0.05 px of line noise moves p by > 1 px
  double border_snap_px = 5.5;       // 2 px without gradient + 0.5 to the border + Gap_min
};

// Segments -> lines (see above). Appends nothing: `lines` is replaced.
void buildLines(const std::vector<Segment>& segments, const CornerParams& params, std::vector<LineFeature>& lines);

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
void findCorners(const std::vector<LineFeature>& lines, const StereoRig& rig, const CornerParams& params,
                 std::vector<PointFeature>& features);

// Intersection of the left-camera ray through pixel (u, v) with the floor, in the robot frame
// C0 at head pan 0 (mm). False when the ray does not go down.
bool floorPoint(const StereoRig& rig, double u, double v, double& x, double& y);

}  // namespace stereoloc::frontend
