#pragma once
// Stage 8: stereo correspondence along the epipolar row of the rectified pair, then
// triangulation through the rig model (3.4, 3.5) into Observations with R from (5.32).
//
// Goal corners: the same colour and side is searched in the right image on the rows where it
// was found in the left one, within the valid disparity range; the per-row disparities are
// combined robustly (median, MAD rejection, mean). Colour and side make the match unique.
// Corners, junctions, intersections: zero-mean normalised cross-correlation of a
// (2r+1)^2 luma patch along the row. All of them lie on the floor, where the disparity grows
// with the row (b/h px per row for an untilted rig): the right patch is sheared by that rate,
// and the search is restricted to +-floor_search_px around the disparity the floor predicts
// (the full valid range when the floor does not predict one). A match needs ZNCC >= min_zncc
// and a margin of `uniqueness` over any other local maximum; it is refined to sub-pixel by a
// parabola through the three best scores. An X-intersection located on the left image is then
// located on the right one too (crossingInRightImage, frontend/corners.h), which a row
// misalignment of the pair does not move; one that cannot be keeps the patch match and its slide
// gain.
#include <Eigen/Core>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <vector>

#include "frontend/goal_corners.h"
#include "src/core/field_map.h"
#include "src/core/measurement_model.h"
#include "src/core/stereo_rig.h"

namespace stereoloc::frontend {

// The pixel noise of one kind of stereo feature in (u, v, d): its left-image column u and row v
// and its disparity d = u_l - u_r (src/core/measurement_model.h stereoPixelCovariance). Measured
// with bench_pixel_noise on rendered pairs (docs/estimators.md, "Observation covariance").
struct PixelNoise {
  double sigma_u = 0.5;  // px, left column
  double sigma_v = 0.5;  // px, row (shared by both images)
  double sigma_d = 0.5;  // px, disparity
  double corr_ud = 0.0;  // correlation of the u and d errors, in (-1, 1)
  // The share of this covariance that one view's own errors make, (0, 1]
  // (Observation::single_view_share): below 1 where the sigmas were widened for errors that
  // repeat over consecutive sightings.
  double single_view_share = 1.0;
  // px^2, of (u_l, v_l, u_r, v_r)
  Eigen::Matrix4d covariance() const { return stereoPixelCovariance(sigma_u, sigma_v, sigma_d, corr_ud); }
};

struct StereoParams {
  double min_range_mm = 80.0;    // nearest landmark considered: the largest valid disparity
  double max_range_mm = 0.0;     // furthest; <= 0 means the rig's max_range_mm
  int patch_radius = 5;          // ZNCC patch half-size, px
  double min_zncc = 0.6;
  double uniqueness = 0.05;      // best score minus any other local maximum
  double floor_search_px = 4.0;  // half-width of the search around the floor disparity; <= 0: full range
  // Pixel noise per feature kind (replaces the thesis's sigma of 5.28); YAML keys
  // <kind>_sigma_u, <kind>_sigma_v, <kind>_sigma_d, <kind>_corr_ud with kind corner (marking
  // L corners, and any other point feature), junction (T-junctions), intersection (X crossings)
  // and goal (goal corners; their row is anywhere on a vertical edge, hence the large sigma_v).
  // sigma_v, corr_ud: second moments about zero of bench_pixel_noise --pairs=1500 --seed=1.
  // sigma_u and sigma_d: wider than those white figures, because a feature's errors repeat over
  // consecutive views of the same geometry, which the estimators treat as independent sightings,
  // and the EKF's single linearisation diverges with a sharper disparity (docs/estimators.md,
  // "Observation covariance"). X-intersections: pooled over the located ones and those that
  // keep the patch match (docs/frontend.md, "An X on the right image").
  // <kind>_single_view_share: the goal corners' sigma_u and sigma_d are twice the white figures
  // (0.078 and 0.105 px) for their repeats alone, so one view is a quarter of the variance; the
  // marking kinds' widening is partly for the EKF's linearisation, not a view's error, so they
  // claim none (and no global fix uses them: they are not identified).
  PixelNoise corner_noise{0.45, 0.13, 0.5, 0.08, 1.0};
  PixelNoise junction_noise{0.45, 0.05, 0.5, -0.13, 1.0};
  PixelNoise intersection_noise{0.5, 0.17, 0.5, 0.48, 1.0};
  PixelNoise goal_noise{0.15, 0.61, 0.21, 0.707, 0.25};
  const PixelNoise& noise(LandmarkType type) const {
    switch (type) {
      case LandmarkType::GoalCorner: return goal_noise;
      case LandmarkType::Junction: return junction_noise;
      case LandmarkType::Intersection: return intersection_noise;
      default: return corner_noise;
    }
  }
  Eigen::Matrix4d pixelCovariance(LandmarkType type) const { return noise(type).covariance(); }
};

struct DisparityRange {
  double min = 0, max = 0;  // px
};
DisparityRange validDisparities(const StereoRig& rig, const StereoParams& params);

// Right-image column of a left GoalEdge: nullopt when not found or out of the disparity range.
std::optional<double> matchGoalEdge(const cv::Mat& right_bgr, const GoalEdge& left, const DisparityRange& range,
                                    const GoalParams& goal_params, std::vector<Transition>& scratch_tr,
                                    std::vector<float>& scratch);

// Disparity of a floor feature at left pixel (u, v) by ZNCC on the lumas; nullopt when no
// unique match. `slide_gain`, when given, receives the match's slide gain: slideGain of the left
// patch plus the floor's disparity change per row (the shear), because the right image of a
// floor edge leans by that much more than the left's (u_r = u_l - d(v)), and its column on a row
// dv above the feature's is what the search finds.
std::optional<double> matchFloorFeature(const cv::Mat& left_luma, const cv::Mat& right_luma, const StereoRig& rig,
                                        double u, double v, const DisparityRange& range, const StereoParams& params,
                                        double* slide_gain = nullptr);

// The slide gain s of a patch matched along its row (Observation::slide_gain): when the right
// image shows the patch dv rows lower than the left (rows misaligned by the rectification), the
// row search's best column moves by s dv. First order (Lucas-Kanade with the column as the only
// unknown): the right patch on the left's row is L(x + e, y - dv) with e the column error, so
// sum (L - R)^2 ~ sum (Ix e - Iy dv)^2 is least at e = dv sum(Ix Iy) / sum(Ix^2). An edge running
// down to the right (Ix Iy < 0) meets the left's row dv px further left: s = -1 at 45 degrees; a
// vertical edge gives 0. Central differences of the left luma over the (2r+1)^2 patch centred at
// integer (uc, vc), pixels whose neighbours leave the image skipped; 0 where the patch has no
// column gradient. First order: on rendered corners the search's shift for a 1.5-row offset
// differs from it by up to 40 %; on realistic images (docs/realistic_world.md, "Noise model") it
// halves the marking features' u_r error. A search of the patch against its own rows +-1 away
// (the match's nonlinearity included) left more error there (0.74 px about each trial's mean,
// against 0.57).
double slideGain(const cv::Mat& left_luma, int uc, int vc, int patch_radius);

// Disparity the floor point seen at left pixel (u, v) would have; nullopt above the horizon.
std::optional<double> floorDisparity(const StereoRig& rig, double u, double v);

}  // namespace stereoloc::frontend
