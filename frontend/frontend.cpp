#include "frontend/frontend.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>
#include <opencv2/core.hpp>

#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc::frontend {
namespace {

// One table of every field, so load, save and the unknown-key check cannot drift apart.
struct Field {
  const char* section;
  const char* key;
  enum Kind { Double, Int, Bool } kind;
  void* ptr;
};

std::vector<Field> fields(FrontendParams& p) {
  return {
      {"field", "enabled", Field::Bool, &p.field.enabled},
      {"field", "step_px", Field::Int, &p.field.step_px},
      {"field", "chroma_tolerance", Field::Double, &p.field.chroma_tolerance},
      {"field", "luma_low", Field::Double, &p.field.luma_low},
      {"field", "luma_high", Field::Double, &p.field.luma_high},
      {"field", "min_run", Field::Int, &p.field.min_run},
      {"field", "smooth_columns", Field::Int, &p.field.smooth_columns},
      {"field", "margin_px", Field::Double, &p.field.margin_px},
      {"gradient", "magnitude_threshold", Field::Int, &p.gradient.magnitude_threshold},
      {"gradient", "auto_factor", Field::Double, &p.gradient.auto_factor},
      {"hough", "theta_step_deg", Field::Double, &p.hough.theta_step_deg},
      {"hough", "rho_step_px", Field::Double, &p.hough.rho_step_px},
      {"hough", "tolerance_deg", Field::Double, &p.hough.tolerance_deg},
      {"hough", "weight_by_magnitude", Field::Bool, &p.hough.weight_by_magnitude},
      {"peaks", "min_votes", Field::Int, &p.peaks.min_votes},
      {"peaks", "max_peaks", Field::Int, &p.peaks.max_peaks},
      {"peaks", "window_theta_bins", Field::Int, &p.peaks.window_theta_bins},
      {"peaks", "window_rho_bins", Field::Int, &p.peaks.window_rho_bins},
      {"segments", "gap_min_px", Field::Double, &p.segments.gap_min_px},
      {"segments", "gap_max_px", Field::Double, &p.segments.gap_max_px},
      {"segments", "min_length_px", Field::Double, &p.segments.min_length_px},
      {"segments", "min_piece_px", Field::Double, &p.segments.min_piece_px},
      {"segments", "min_density", Field::Double, &p.segments.min_density},
      {"segments", "direction_tolerance_deg", Field::Double, &p.segments.direction_tolerance_deg},
      {"segments", "band_px", Field::Double, &p.segments.band_px},
      {"segments", "member_band_px", Field::Double, &p.segments.member_band_px},
      {"segments", "refit_iterations", Field::Int, &p.segments.refit_iterations},
      {"segments", "straightness_px", Field::Double, &p.segments.straightness_px},
      {"segments", "straightness_bin_px", Field::Double, &p.segments.straightness_bin_px},
      {"segments", "step_px", Field::Double, &p.segments.step_px},
      {"segments", "tail_px", Field::Double, &p.segments.tail_px},
      {"segments", "rounds_per_peak", Field::Int, &p.segments.rounds_per_peak},
      {"segments", "release_unused", Field::Bool, &p.segments.release_unused},
      {"classify", "marking_width_mm", Field::Double, &p.classify.marking_width_mm},
      {"classify", "width_factor", Field::Double, &p.classify.width_factor},
      {"classify", "min_width_px", Field::Double, &p.classify.min_width_px},
      {"classify", "max_width_px", Field::Double, &p.classify.max_width_px},
      {"classify", "opposite_tolerance_deg", Field::Double, &p.classify.opposite_tolerance_deg},
      {"classify", "xi_h", Field::Double, &p.classify.xi_h},
      {"classify", "max_outer_difference", Field::Double, &p.classify.max_outer_difference},
      {"classify", "xi_l", Field::Double, &p.classify.xi_l},
      {"classify", "min_seen_share", Field::Double, &p.classify.min_seen_share},
      {"ends", "enabled", Field::Bool, &p.ends.enabled},
      {"ends", "side_px", Field::Double, &p.ends.side_px},
      {"ends", "min_fraction", Field::Double, &p.ends.min_fraction},
      {"ends", "min_run_px", Field::Double, &p.ends.min_run_px},
      {"ends", "min_contrast", Field::Double, &p.ends.min_contrast},
      {"ends", "extend_px", Field::Double, &p.ends.extend_px},
      {"ends", "extend_ref_px", Field::Double, &p.ends.extend_ref_px},
      {"corners", "delta_px", Field::Double, &p.corners.delta_px},
      {"corners", "min_image_angle_deg", Field::Double, &p.corners.min_image_angle_deg},
      {"corners", "corner_angle_tol_deg", Field::Double, &p.corners.corner_angle_tol_deg},
      {"corners", "min_crossing_angle_deg", Field::Double, &p.corners.min_crossing_angle_deg},
      {"corners", "merge_px", Field::Double, &p.corners.merge_px},
      {"corners", "centre_merge_deg", Field::Double, &p.corners.centre_merge_deg},
      {"corners", "centre_merge_px", Field::Double, &p.corners.centre_merge_px},
      {"corners", "piece_gap_px", Field::Double, &p.corners.piece_gap_px},
      {"corners", "wall_foot_max_tilt_deg", Field::Double, &p.corners.wall_foot_max_tilt_deg},
      {"corners", "marking_junctions", Field::Bool, &p.corners.marking_junctions},
      {"corners", "snap_px", Field::Double, &p.corners.snap_px},
      {"corners", "snap_min_angle_deg", Field::Double, &p.corners.snap_min_angle_deg},
      {"corners", "border_snap_px", Field::Double, &p.corners.border_snap_px},
      {"corners", "probe_start_px", Field::Double, &p.corners.probe_start_px},
      {"corners", "probe_side_px", Field::Double, &p.corners.probe_side_px},
      {"corners", "probe_dark_fraction", Field::Double, &p.corners.probe_dark_fraction},
      {"corners", "probe_min_run", Field::Int, &p.corners.probe_min_run},
      {"corners", "arm_min_contrast", Field::Double, &p.corners.arm_min_contrast},
      {"corners", "arm_length_px", Field::Double, &p.corners.arm_length_px},
      {"corners", "wall_min_height_px", Field::Double, &p.corners.wall_min_height_px},
      {"goals", "coarse_step", Field::Int, &p.goals.coarse_step},
      {"goals", "min_coarse_hits", Field::Int, &p.goals.min_coarse_hits},
      {"goals", "window_margin_px", Field::Int, &p.goals.window_margin_px},
      {"goals", "colour_min_score", Field::Int, &p.goals.colour_min_score},
      {"goals", "white_max_score", Field::Int, &p.goals.white_max_score},
      {"goals", "white_min_luma", Field::Int, &p.goals.white_min_luma},
      {"goals", "max_transition_px", Field::Int, &p.goals.max_transition_px},
      {"goals", "min_rows", Field::Int, &p.goals.min_rows},
      {"goals", "outlier_px", Field::Double, &p.goals.outlier_px},
      {"goals", "min_right_row_fraction", Field::Double, &p.goals.min_right_row_fraction},
      {"stereo", "min_range_mm", Field::Double, &p.stereo.min_range_mm},
      {"stereo", "max_range_mm", Field::Double, &p.stereo.max_range_mm},
      {"stereo", "patch_radius", Field::Int, &p.stereo.patch_radius},
      {"stereo", "min_zncc", Field::Double, &p.stereo.min_zncc},
      {"stereo", "uniqueness", Field::Double, &p.stereo.uniqueness},
      {"stereo", "floor_search_px", Field::Double, &p.stereo.floor_search_px},
      {"stereo", "corner_sigma_u", Field::Double, &p.stereo.corner_noise.sigma_u},
      {"stereo", "corner_sigma_v", Field::Double, &p.stereo.corner_noise.sigma_v},
      {"stereo", "corner_sigma_d", Field::Double, &p.stereo.corner_noise.sigma_d},
      {"stereo", "corner_corr_ud", Field::Double, &p.stereo.corner_noise.corr_ud},
      {"stereo", "corner_single_view_share", Field::Double, &p.stereo.corner_noise.single_view_share},
      {"stereo", "junction_sigma_u", Field::Double, &p.stereo.junction_noise.sigma_u},
      {"stereo", "junction_sigma_v", Field::Double, &p.stereo.junction_noise.sigma_v},
      {"stereo", "junction_sigma_d", Field::Double, &p.stereo.junction_noise.sigma_d},
      {"stereo", "junction_corr_ud", Field::Double, &p.stereo.junction_noise.corr_ud},
      {"stereo", "junction_single_view_share", Field::Double, &p.stereo.junction_noise.single_view_share},
      {"stereo", "intersection_sigma_u", Field::Double, &p.stereo.intersection_noise.sigma_u},
      {"stereo", "intersection_sigma_v", Field::Double, &p.stereo.intersection_noise.sigma_v},
      {"stereo", "intersection_sigma_d", Field::Double, &p.stereo.intersection_noise.sigma_d},
      {"stereo", "intersection_corr_ud", Field::Double, &p.stereo.intersection_noise.corr_ud},
      {"stereo", "intersection_single_view_share", Field::Double, &p.stereo.intersection_noise.single_view_share},
      {"stereo", "goal_sigma_u", Field::Double, &p.stereo.goal_noise.sigma_u},
      {"stereo", "goal_sigma_v", Field::Double, &p.stereo.goal_noise.sigma_v},
      {"stereo", "goal_sigma_d", Field::Double, &p.stereo.goal_noise.sigma_d},
      {"stereo", "goal_corr_ud", Field::Double, &p.stereo.goal_noise.corr_ud},
      {"stereo", "goal_single_view_share", Field::Double, &p.stereo.goal_noise.single_view_share},
  };
}

const char* kSections[] = {"field", "gradient", "hough", "peaks", "segments", "classify", "ends", "corners", "goals", "stereo"};

}  // namespace

void FrontendParams::validate() const {
  auto need = [](bool ok, const char* key, const char* what) {
    if (!ok) throw Error(std::string("frontend params: ") + key + ": " + what);
  };
  need(field.step_px >= 1 && field.step_px <= 32, "field.step_px", "must be in [1, 32]");
  need(field.chroma_tolerance > 0 && field.chroma_tolerance <= 2, "field.chroma_tolerance", "must be in (0, 2]");
  need(field.luma_low >= 0 && field.luma_high > field.luma_low, "field.luma_low/luma_high", "need 0 <= low < high");
  need(field.min_run >= 1, "field.min_run", "must be at least 1");
  need(field.smooth_columns >= 0, "field.smooth_columns", "must not be negative");
  need(field.margin_px >= 0, "field.margin_px", "must not be negative");
  need(gradient.magnitude_threshold > 0, "gradient.magnitude_threshold", "must be positive");
  need(gradient.auto_factor >= 0 && gradient.auto_factor <= 50, "gradient.auto_factor", "must be in [0, 50] (0: off)");
  const double n = 360.0 / hough.theta_step_deg;
  need(hough.theta_step_deg > 0 && std::fabs(n - std::round(n)) < 1e-6, "hough.theta_step_deg",
       "must be positive and divide 360");
  need(hough.rho_step_px > 0, "hough.rho_step_px", "must be positive");
  need(hough.tolerance_deg >= 0 && hough.tolerance_deg < 90, "hough.tolerance_deg", "must be in [0, 90)");
  need(peaks.min_votes > 0, "peaks.min_votes", "must be positive");
  need(peaks.max_peaks > 0, "peaks.max_peaks", "must be positive");
  need(peaks.window_theta_bins >= 0 && peaks.window_rho_bins >= 0, "peaks.window_*", "must not be negative");
  need(segments.gap_min_px > 0, "segments.gap_min_px", "must be positive");
  need(segments.gap_max_px >= segments.gap_min_px, "segments.gap_max_px", "must be at least gap_min_px");
  need(segments.min_length_px > 0, "segments.min_length_px", "must be positive");
  need(segments.min_piece_px >= 0, "segments.min_piece_px", "must not be negative");
  need(segments.min_density >= 0 && segments.min_density <= 2, "segments.min_density", "must be in [0, 2]");
  need(segments.direction_tolerance_deg > 0 && segments.direction_tolerance_deg < 90,
       "segments.direction_tolerance_deg", "must be in (0, 90)");
  need(segments.band_px > 0, "segments.band_px", "must be positive");
  need(segments.member_band_px >= 0, "segments.member_band_px", "must not be negative");
  need(segments.rounds_per_peak >= 1, "segments.rounds_per_peak", "must be at least 1");
  need(segments.refit_iterations >= 1, "segments.refit_iterations", "must be at least 1");
  need(segments.straightness_px > 0, "segments.straightness_px", "must be positive");
  need(segments.straightness_bin_px > 0, "segments.straightness_bin_px", "must be positive");
  need(segments.step_px >= 0, "segments.step_px", "must not be negative");
  need(segments.tail_px >= 0, "segments.tail_px", "must not be negative");
  need(classify.marking_width_mm >= 0, "classify.marking_width_mm", "must not be negative (0: from the map)");
  need(classify.width_factor > 0, "classify.width_factor", "must be positive");
  need(classify.min_width_px > 0 && classify.max_width_px >= classify.min_width_px, "classify.min/max_width_px",
       "need 0 < min <= max");
  need(classify.xi_h > 0 && classify.xi_h <= 1, "classify.xi_h", "must be in (0, 1]");
  need(classify.xi_l > 0 && classify.xi_l <= 1, "classify.xi_l", "must be in (0, 1]");
  need(classify.min_seen_share >= 0 && classify.min_seen_share <= 1, "classify.min_seen_share", "must be in [0, 1]");
  need(ends.side_px >= 0, "ends.side_px", "must not be negative");
  need(ends.min_fraction > 0 && ends.min_fraction <= 1, "ends.min_fraction", "must be in (0, 1]");
  need(ends.min_run_px >= 1, "ends.min_run_px", "must be at least 1");
  need(ends.min_contrast >= 0, "ends.min_contrast", "must not be negative");
  need(ends.extend_px >= 0, "ends.extend_px", "must not be negative");
  need(ends.extend_ref_px >= 4, "ends.extend_ref_px", "must be at least 4");
  need(corners.delta_px >= 0, "corners.delta_px", "must not be negative");
  need(corners.snap_px >= 0 && corners.border_snap_px >= 0, "corners.snap_px/border_snap_px", "must not be negative");
  need(corners.snap_min_angle_deg > 0 && corners.snap_min_angle_deg < 90, "corners.snap_min_angle_deg", "must be in (0, 90)");
  need(corners.merge_px >= 0, "corners.merge_px", "must not be negative");
  need(corners.piece_gap_px >= 0, "corners.piece_gap_px", "must not be negative");
  need(corners.probe_start_px >= 0 && corners.probe_side_px >= 0, "corners.probe_start_px/probe_side_px",
       "must not be negative");
  need(corners.probe_dark_fraction >= 0 && corners.probe_dark_fraction <= 1, "corners.probe_dark_fraction",
       "must be in [0, 1]");
  need(corners.arm_min_contrast > 0 && corners.arm_min_contrast <= 1, "corners.arm_min_contrast", "must be in (0, 1]");
  need(goals.coarse_step >= 1, "goals.coarse_step", "must be at least 1");
  need(goals.min_rows >= 1, "goals.min_rows", "must be at least 1");
  need(goals.min_right_row_fraction >= 0 && goals.min_right_row_fraction <= 1, "goals.min_right_row_fraction",
       "must be in [0, 1]");
  need(goals.max_transition_px >= 1, "goals.max_transition_px", "must be at least 1");
  need(stereo.min_range_mm > 0, "stereo.min_range_mm", "must be positive");
  need(stereo.patch_radius >= 1 && stereo.patch_radius <= 15, "stereo.patch_radius", "must be in [1, 15]");
  need(std::isfinite(stereo.max_range_mm), "stereo.max_range_mm", "must be finite (<= 0: the rig's)");
  need(std::isfinite(stereo.floor_search_px), "stereo.floor_search_px", "must be finite (<= 0: the full range)");
  // Scores are zero-mean normalised cross-correlations, in [-1, 1]; a margin between two is in [0, 2].
  need(stereo.min_zncc >= -1 && stereo.min_zncc <= 1, "stereo.min_zncc", "must be in [-1, 1]");
  need(stereo.uniqueness >= 0 && stereo.uniqueness <= 2, "stereo.uniqueness", "must be in [0, 2]");
  for (const PixelNoise* pn : {&stereo.corner_noise, &stereo.junction_noise, &stereo.intersection_noise, &stereo.goal_noise}) {
    need(pn->sigma_u > 0 && pn->sigma_v > 0 && pn->sigma_d > 0, "stereo.*_sigma_u/v/d", "must be positive");
    need(std::fabs(pn->corr_ud) < 1, "stereo.*_corr_ud", "must be in (-1, 1)");
    need(pn->single_view_share > 0 && pn->single_view_share <= 1, "stereo.*_single_view_share", "must be in (0, 1]");
  }
}

FrontendParams FrontendParams::load(const std::string& path) {
  FrontendParams p;
  YamlReader r(path);
  auto table = fields(p);
  // Unknown sections or keys are errors, so a misspelt parameter is never silently ignored.
  for (auto it = r.node().begin(); it != r.node().end(); ++it) {
    const std::string sec = (*it).name();
    if (std::find_if(std::begin(kSections), std::end(kSections), [&](const char* s) { return sec == s; }) ==
        std::end(kSections))
      r.fail(sec, "unknown section");
    const YamlNode node = r.child(sec);
    for (auto kt = node.node().begin(); kt != node.node().end(); ++kt) {
      const std::string key = (*kt).name();
      if (std::none_of(table.begin(), table.end(), [&](const Field& f) { return sec == f.section && key == f.key; }))
        node.fail(key, "unknown parameter");
    }
  }
  for (const Field& f : table) {
    if (!r.has(f.section)) continue;
    const YamlNode node = r.child(f.section);
    switch (f.kind) {
      case Field::Double: *static_cast<double*>(f.ptr) = node.getDouble(f.key, *static_cast<double*>(f.ptr)); break;
      case Field::Int: *static_cast<int*>(f.ptr) = node.getInt(f.key, *static_cast<int*>(f.ptr)); break;
      case Field::Bool: *static_cast<bool*>(f.ptr) = node.getBool(f.key, *static_cast<bool*>(f.ptr)); break;
    }
  }
  try {
    p.validate();
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return p;
}

void FrontendParams::save(const std::string& path) const {
  FrontendParams copy = *this;
  auto table = fields(copy);
  YamlWriter w;
  w.comment("stereoloc vision frontend parameters (thesis ch. 3, defaults from 6.1). Units: px, deg, mm.");
  for (const char* sec : kSections) {
    w.fs() << sec << "{";
    for (const Field& f : table) {
      if (std::string(f.section) != sec) continue;
      switch (f.kind) {
        case Field::Double: w.fs() << f.key << *static_cast<double*>(f.ptr); break;
        case Field::Int: w.fs() << f.key << *static_cast<int*>(f.ptr); break;
        case Field::Bool: w.fs() << f.key << (*static_cast<bool*>(f.ptr) ? 1 : 0); break;
      }
    }
    w.fs() << "}";
  }
  w.writeAtomically(path);
}

Frontend::Frontend(const StereoRig& rig, const FieldMap& map, const FrontendParams& params)
    : rig_(rig), map_(map), params_(params) {
  params_.validate();
  if (rig_.calibration() && rig_.calibration()->needsRemap()) rectifier_.emplace(*rig_.calibration());
  const int w = rig_.params().image_width, h = rig_.params().image_height;
  acc_.configure(w, h, params_.hough);
  // W'(v): the widest a marking can look at row v, from the floor distance seen there.
  const double line_width = params_.classify.marking_width_mm > 0 ? params_.classify.marking_width_mm
                            : map_.geometry()                     ? map_.geometry()->line_width
                                                                  : 10.0;
  width_per_row_.assign(static_cast<size_t>(h), static_cast<float>(params_.classify.min_width_px));
  for (int v = 0; v < h; ++v) {
    double x, y;
    if (!floorPoint(rig_, rig_.principalU(), v, x, y)) continue;
    const double depth = std::max(1.0, x - rig_.params().offset_x_mm);
    const double wv = params_.classify.width_factor * rig_.focal() * line_width / depth;
    width_per_row_[v] = static_cast<float>(std::clamp(wv, params_.classify.min_width_px, params_.classify.max_width_px));
  }
  // Goal corners: which of a goal's two corners is on the left, seen from inside the field.
  const Bounds& b = map_.bounds();
  const Eigen::Vector2d centre(0.5 * (b.xmin + b.xmax), 0.5 * (b.ymin + b.ymax));
  for (int c = 0; c < 2; ++c) {
    const GoalColor color = c == 0 ? GoalColor::Blue : GoalColor::Yellow;
    std::vector<const Landmark*> corners;
    for (const Landmark* l : map_.ofType(LandmarkType::GoalCorner))
      if (l->color == color) corners.push_back(l);
    if (corners.size() != 2) continue;
    const Eigen::Vector2d mid = 0.5 * (corners[0]->xy() + corners[1]->xy());
    const Eigen::Vector2d d = mid - centre;
    for (const Landmark* l : corners) {
      const Eigen::Vector2d q = l->xy() - mid;
      const double cross = d.x() * q.y() - d.y() * q.x();
      goal_ids_[c][cross > 0 ? 0 : 1] = l->id;  // left of the view direction -> image side -1
    }
  }
}

int Frontend::goalCornerLandmark(GoalColor color, int side) const {
  if (color == GoalColor::None || side == 0) return -1;
  return goal_ids_[color == GoalColor::Blue ? 0 : 1][side < 0 ? 0 : 1];
}

void Frontend::checkImage(const cv::Mat& img, const char* which) const {
  const std::string w = which;
  if (img.empty()) throw Error(w + " image: empty");
  if (img.depth() != CV_8U) throw Error(w + " image: expected 8 bits per channel, got depth code " + std::to_string(img.depth()));
  if (img.channels() != 3) throw Error(w + " image: expected 3 colour channels (BGR), got " + std::to_string(img.channels()));
  const int ew = rig_.params().image_width, eh = rig_.params().image_height;
  if (img.cols != ew || img.rows != eh)
    throw Error(w + " image: size " + std::to_string(img.cols) + "x" + std::to_string(img.rows) + " does not match the rig (" +
                std::to_string(ew) + "x" + std::to_string(eh) + ")" +
                (rig_.calibration() ? ", the image_size of " + rig_.calibration()->source : std::string()));
}

const std::vector<Segment>& Frontend::detectSegments(const cv::Mat& bgr) {
  checkImage(bgr, "input");
  bgrToLuma(bgr, left_luma_);
  return segmentsFromLuma(bgr);
}

const std::vector<Segment>& Frontend::segmentsFromLuma(const cv::Mat& bgr) {
  region_.compute(bgr, params_.field);
  grad_.compute(left_luma_, params_.gradient, region_.restricted() ? region_.top().data() : nullptr);
  used_.clear();
  acc_.vote(grad_.edges(), used_);
  detectPeaks(acc_, params_.peaks, peaks_);
  extractor_.extract(grad_.edges(), peaks_, params_.hough.rho_step_px, params_.segments, used_, result_.segments,
                     left_luma_.cols, left_luma_.rows);
  refineEndpoints(left_luma_, result_.segments);
  classifySegments(grad_, extractor_, width_per_row_, params_.classify, result_.segments, scratch_, &left_luma_);
  return result_.segments;
}

const FrontendResult& Frontend::detectFeatures(const cv::Mat& bgr) {
  FrontendResult& r = result_;
  r.features.clear();
  r.matched.clear();
  r.observations.clear();
  detectSegments(bgr);
  featuresFromSegments();
  return r;
}

void Frontend::featuresFromSegments() {
  FrontendResult& r = result_;
  buildLines(r.segments, rig_, params_.corners, r.lines);
  clipLinesToImage(rig_.params().image_width, rig_.params().image_height, r.lines);
  trimStripeEnds(left_luma_, params_.ends, r.lines, ends_scratch_);
  snapLineEnds(rig_.params().image_width, rig_.params().image_height, params_.corners, r.lines);
  findCorners(r.lines, rig_, params_.corners, r.features, &left_luma_);
}

const FrontendResult& Frontend::detectFeaturesRaw(const cv::Mat& raw_bgr) {
  if (!rectifier_) return detectFeatures(raw_bgr);
  checkImage(raw_bgr, "input");
  // The rectifier maps pairs; the right map's output of the same image is not used.
  rectifier_->rectify(raw_bgr, raw_bgr);
  return detectFeatures(rectifier_->left());
}

const FrontendResult& Frontend::process(const cv::Mat& left_in, const cv::Mat& right_in, double head_pan) {
  checkImage(left_in, "left");
  checkImage(right_in, "right");
  FrontendResult& r = result_;
  if (rectifier_) {
    // Luma path (rectify.h): only the left luma is rectified whole; the right luma and the
    // colour are rectified where the stages below read them.
    r.features.clear();
    r.matched.clear();
    r.observations.clear();
    rectifier_->beginPair(left_in, right_in, left_luma_);
    if (params_.field.enabled)
      rectifier_->colour(0, cv::Rect(0, 0, left_luma_.cols, left_luma_.rows), params_.field.step_px);
    segmentsFromLuma(rectifier_->colourImage(0));
    featuresFromSegments();
  } else {
    detectFeatures(left_in);
  }
  const cv::Mat& left = rectifier_ ? rectifier_->colourImage(0) : left_in;
  const cv::Mat& right = rectifier_ ? rectifier_->colourImage(1) : right_in;
  const DisparityRange range = validDisparities(rig_, params_.stereo);
  matchFloorFeatures(right, range);
  matchGoalCorners(left, right, range);
  observationsFromMatches(head_pan);
  return r;
}

void Frontend::matchFloorFeatures(const cv::Mat& right, const DisparityRange& range) {
  FrontendResult& r = result_;
  if (r.features.empty()) return;
  if (rectifier_)
    rectifyRightLumaAroundFeatures();
  else
    bgrToLuma(right, right_luma_);
  for (const PointFeature& f : r.features) {
    double gain = 0.0;
    const auto d = matchFloorFeature(left_luma_, right_luma_, rig_, f.u, f.v, range, params_.stereo, &gain);
    if (!d) continue;
    double u_right = f.u - *d;
    // An X located on the left image is located on the right one as well, so it does not slide
    // with the rows' misalignment as the patch match does (Observation::slide_gain); one that
    // cannot be (a stripe with too few profiles beside the crossing) keeps the patch match.
    double v_right = f.v;  // the observation keeps the left's row (StereoPixels)
    const bool located = f.type == LandmarkType::Intersection && f.located_on_image && f.line_a >= 0 &&
                         f.line_b >= 0 &&
                         crossingInRightImage(right_luma_, rig_, r.lines[f.line_a], r.lines[f.line_b], f.u, f.v,
                                              u_right, v_right);
    r.matched.push_back(StereoFeature{f, StereoPixels{f.u, f.v, u_right, f.v}, located ? 0.0 : gain, located});
  }
}

void Frontend::matchGoalCorners(const cv::Mat& left, const cv::Mat& right, const DisparityRange& range) {
  FrontendResult& r = result_;
  const ColourPrepare prepare_left = [this](const cv::Rect& rect, int step) { rectifier_->colour(0, rect, step); };
  detectGoalEdges(left, params_.goals, goal_edges_, scratch_, rectifier_ ? &prepare_left : nullptr);
  for (const GoalEdge& g : goal_edges_) {
    PointFeature f;
    f.type = LandmarkType::GoalCorner;
    f.u = g.u;
    f.v = g.v;
    f.color = g.color;
    f.side = g.side;
    f.landmark_id = goalCornerLandmark(g.color, g.side);
    r.features.push_back(f);
    if (rectifier_ && !g.transitions.empty()) {
      // matchGoalEdge scans the right image on rows of the left transitions.
      const int row0 = g.transitions.front().row, row1 = g.transitions.back().row;
      rectifier_->colour(1, cv::Rect(0, row0, right.cols, row1 - row0 + 1));
    }
    const auto ur = matchGoalEdge(right, g, range, params_.goals, scratch_tr_, scratch_);
    if (ur) r.matched.push_back(StereoFeature{f, StereoPixels{g.u, g.v, *ur, g.v}});
  }
}

void Frontend::observationsFromMatches(double head_pan) {
  FrontendResult& r = result_;
  for (const StereoFeature& m : r.matched) {
    Eigen::Matrix4d C = params_.stereo.pixelCovariance(m.feature.type);
    if (rectifier_) {
      // Resampling stretches the errors by the map's scale s (the larger of the two images, an
      // isotropic bound) and adds the map grid's rounding independently per image and axis.
      double s2 = 0, rounding2 = 0;
      const double u[2] = {m.pixels.u_left, m.pixels.u_right}, v[2] = {m.pixels.v_left, m.pixels.v_right};
      for (int cam = 0; cam < 2; ++cam) {
        const double r0 = rectifier_->effectiveSigma(cam, u[cam], v[cam], 0.0);
        const double r1 = rectifier_->effectiveSigma(cam, u[cam], v[cam], 1.0);
        s2 = std::max(s2, r1 * r1 - r0 * r0);
        rounding2 = std::max(rounding2, r0 * r0);
      }
      C = s2 * C + rounding2 * Eigen::Matrix4d::Identity();
    }
    try {
      r.observations.push_back(
          observationFromPixels(rig_, m.feature.landmark_id, m.feature.type, m.pixels, head_pan, C));
      r.observations.back().slide_gain = m.slide_gain;
      // The resampling's rounding term ((1/32)^2 / 12 px^2) is a view's own, but under 0.5 % of
      // a goal corner's variance: the kind's share stands for the whole.
      r.observations.back().single_view_share = params_.stereo.noise(m.feature.type).single_view_share;
    } catch (const GeometryError&) {
      // Disparity below the rig's minimum: cannot be triangulated; not an observation.
    }
  }
}

void Frontend::rectifyRightLumaAroundFeatures() {
  // matchFloorFeature reads the right luma on the rows of its patch around the feature's row.
  const int rad = params_.stereo.patch_radius;
  row_spans_.clear();
  for (const PointFeature& f : result_.features) {
    const int vc = static_cast<int>(std::lround(f.v));
    // crossingInRightImage reads profiles up to 40 px along the crossing lines.
    const int reach = f.type == LandmarkType::Intersection ? std::max(rad, 48) : rad;
    row_spans_.emplace_back(vc - reach, vc + reach + 1);
  }
  std::sort(row_spans_.begin(), row_spans_.end());
  std::pair<int, int> cur = row_spans_.front();
  for (size_t k = 1; k <= row_spans_.size(); ++k) {
    if (k < row_spans_.size() && row_spans_[k].first <= cur.second) {
      cur.second = std::max(cur.second, row_spans_[k].second);
      continue;
    }
    rectifier_->rightLumaRows(cur.first, cur.second, right_luma_);
    if (k < row_spans_.size()) cur = row_spans_[k];
  }
}

}  // namespace stereoloc::frontend
