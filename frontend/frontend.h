#pragma once
// The vision frontend of thesis chapter 3: a rectified 8-bit BGR stereo pair in, landmark
// observations (range, bearing, R) out. Stages, each in its own unit:
//   gradient (Sobel on luma, NMS)   -> frontend/gradient.h
//   GBHT (3.3.1)                    -> frontend/gbht.h
//   peaks (Algorithm 1)             -> frontend/peaks.h
//   segments (Algorithm 2 + refit)  -> frontend/segments.h
//   marking classification (Alg. 3) -> frontend/classify.h
//   corners / junctions (Alg. 4)    -> frontend/corners.h
//   goal corners (3.6)              -> frontend/goal_corners.h
//   stereo match, triangulation     -> frontend/stereo_match.h
// Line convention: frontend/features.h. The line stages run on the left image only; the right
// image is read only around the left features, along their epipolar rows.
// A rig with an OpenCV calibration that needs it gets its raw pairs rectified first
// (frontend/rectify.h: the left luma whole, the right luma and the colour only where the stages
// read them); the observations then carry rectified pixels and a pixel sigma that includes the
// resampling.
#include <opencv2/core/mat.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "frontend/classify.h"
#include "frontend/corners.h"
#include "frontend/field_region.h"
#include "frontend/gbht.h"
#include "frontend/goal_corners.h"
#include "frontend/gradient.h"
#include "frontend/peaks.h"
#include "frontend/rectify.h"
#include "frontend/segments.h"
#include "frontend/stereo_match.h"
#include "frontend/stripe_ends.h"
#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"

namespace stereoloc::frontend {

// Every parameter of the frontend, with the thesis's defaults (6.1) where it gives them.
struct FrontendParams {
  FieldRegionParams field;
  GradientParams gradient;
  HoughParams hough;
  PeakParams peaks;
  SegmentParams segments;
  ClassifyParams classify;
  StripeEndParams ends;
  CornerParams corners;
  GoalParams goals;
  StereoParams stereo;

  // YAML through cv::FileStorage: sections field, gradient, hough, peaks, segments, classify, ends, corners,
  // goals, stereo holding the fields above by name; missing keys keep their defaults, unknown
  // keys and out-of-range values are errors naming file and key.
  static FrontendParams load(const std::string& path);
  void save(const std::string& path) const;
  void validate() const;  // throws stereoloc::Error naming the field
};

// A left-image feature with its stereo match.
struct StereoFeature {
  PointFeature feature;
  StereoPixels pixels;
  double slide_gain = 0.0;  // Observation::slide_gain
  // An X-intersection located on the right image as on the left (crossingInRightImage), not
  // matched by patch correlation (bench_pixel_noise reports the two apart).
  bool located_in_both_images = false;
};

struct FrontendResult {
  std::vector<Segment> segments;          // left image
  std::vector<LineFeature> lines;         // marking centre lines and other edges
  std::vector<PointFeature> features;     // left image: corners, junctions, intersections, goal corners
  std::vector<StereoFeature> matched;     // features with a unique stereo match
  std::vector<Observation> observations;  // one per matched feature
};

class Frontend {
 public:
  Frontend(const StereoRig& rig, const FieldMap& map, const FrontendParams& params = FrontendParams());

  // Runs the whole pipeline. Both images: CV_8UC3 BGR of the rig's size (raw images when the rig
  // carries a calibration that needs rectification). Throws
  // stereoloc::Error with a one-line reason for anything else. The result is reused between
  // calls (no allocation once warmed up).
  const FrontendResult& process(const cv::Mat& left_bgr, const cv::Mat& right_bgr, double head_pan = 0.0);

  // Stages 1-6 on one image (monocular use): segments, lines, corners / junctions /
  // intersections; no goal corners, stereo match or observations (those are cleared).
  const FrontendResult& detectFeatures(const cv::Mat& bgr);
  // The same on a raw image of the left camera: rectified first when the rig's calibration needs
  // it (see rectifier()), so the features are in rectified pixels as process() gives them.
  const FrontendResult& detectFeaturesRaw(const cv::Mat& raw_bgr);

  // Stages 1-5 only, on one image (the benchmark and tests use it). Returns result().segments.
  const std::vector<Segment>& detectSegments(const cv::Mat& bgr);

  const FrontendResult& result() const { return result_; }
  const FrontendParams& params() const { return params_; }
  const StereoRig& rig() const { return rig_; }
  // The rectification of raw pairs; null when the rig's images are used as they are. After
  // process() its colour images hold only the pixels the frontend read (rectify.h); use
  // rectifiedCopy() for a whole rectified image.
  const Rectifier* rectifier() const { return rectifier_ ? &*rectifier_ : nullptr; }
  const GradientStage& gradient() const { return grad_; }
  // The region of interest of the last image (whole image unless params().field.enabled).
  const FieldRegion& fieldRegion() const { return region_; }
  // W'(v) of Algorithm 3 for each image row (see classify.h).
  const std::vector<float>& markingWidthPerRow() const { return width_per_row_; }

  // The goal-corner landmark of a colour and image side (-1 colour right of white, +1 colour
  // left of white), seen from inside the field; -1 if the map has none.
  int goalCornerLandmark(GoalColor color, int side) const;

 private:
  void checkImage(const cv::Mat& img, const char* which) const;
  // Stages 1-5 on left_luma_; bgr (the same image in colour) serves the field region only.
  const std::vector<Segment>& segmentsFromLuma(const cv::Mat& bgr);
  void featuresFromSegments();  // stage 6 on result_.segments
  // Raw pairs: rectifies the right luma on the rows the stereo match of result_.features reads.
  void rectifyRightLumaAroundFeatures();
  // process(), after the features of the left image: their right-image matches, the goal
  // corners' (detected and matched), and the matches as observations.
  void matchFloorFeatures(const cv::Mat& right, const DisparityRange& range);
  void matchGoalCorners(const cv::Mat& left, const cv::Mat& right, const DisparityRange& range);
  void observationsFromMatches(double head_pan);
  StereoRig rig_;
  FieldMap map_;
  FrontendParams params_;
  std::optional<Rectifier> rectifier_;
  std::vector<float> width_per_row_;
  int goal_ids_[2][2] = {{-1, -1}, {-1, -1}};  // [blue/yellow][side -1/+1]
  FieldRegion region_;
  GradientStage grad_;
  HoughAccumulator acc_;
  SegmentExtractor extractor_;
  std::vector<HoughPeak> peaks_;
  std::vector<uint8_t> used_;
  std::vector<float> scratch_;
  std::vector<Transition> scratch_tr_;
  StripeEndScratch ends_scratch_;
  std::vector<GoalEdge> goal_edges_;
  cv::Mat left_luma_, right_luma_;
  std::vector<std::pair<int, int>> row_spans_;
  FrontendResult result_;
};

}  // namespace stereoloc::frontend
