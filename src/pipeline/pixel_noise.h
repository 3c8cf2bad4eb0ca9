#pragma once
// The frontend's pixel errors measured against the renderer's truth: stereo pairs are rendered
// at random poses on the field, the studies' sensor noise is added (addSensorNoise), the frontend
// runs, and each of its stereo features is compared with the exact projection (StereoRig::project,
// which the renderer shares) of the map landmark it shows. The result calibrates the per-type
// pixel covariance of the frontend (frontend/stereo_match.h, docs/estimators.md "Observation covariance").
//
// Matching: a goal corner by its identity; a corner, junction or intersection with the landmark
// of its type whose left projection is nearest, when that one lies within `match_px` and every
// other landmark of the type at least 2 match_px away (unambiguous); its right projection must
// also lie within match_px. Errors are measured minus true, px, in the order
// (u_left, v_left, u_right, v_right).
#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"

namespace stereoloc::frontend {
struct FrontendParams;
}

namespace stereoloc {

struct PixelNoiseOptions {
  int pairs = 400;            // rendered pairs
  uint64_t seed = 1;          // poses and sensor noise
  double image_noise = 1.5;   // grey levels, as the studies' --image-noise
  double margin_mm = 100.0;   // poses at least this far inside the field's outer landmarks
  double match_px = 2.0;      // see the header comment
  // Given poses (with their head pans, rad; empty = 0) replace the random ones: e.g. a
  // scenario's path, whose repeated views show the errors of its particular geometry. `pairs`
  // passes over them, each with its own sensor noise.
  std::vector<Pose2> poses;
  std::vector<double> head_pans;
};

struct PixelErrorSample {
  LandmarkType type = LandmarkType::Point;
  int landmark_id = -1;
  Eigen::Vector4d error = Eigen::Vector4d::Zero();  // px: (u_l, v_l, u_r, v_r) measured - true
  Eigen::Vector4d truth = Eigen::Vector4d::Zero();  // px: the true pixels
  double range_mm = 0;                              // true horizontal distance from the robot
  bool located_in_both_images = false;              // frontend::StereoFeature's
};

// Renders `options.pairs` pairs and returns one sample per matched stereo feature. Deterministic
// per seed.
std::vector<PixelErrorSample> measurePixelErrors(const FieldMap& map, const StereoRig& rig,
                                                 const frontend::FrontendParams& params,
                                                 const PixelNoiseOptions& options);

struct PixelErrorMoments {
  long n = 0;
  Eigen::Vector4d mean = Eigen::Vector4d::Zero();         // px
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();   // px^2, about the mean
  Eigen::Matrix4d second = Eigen::Matrix4d::Zero();       // px^2, E[e e^T] (bias included)
};
PixelErrorMoments pixelErrorMoments(const std::vector<PixelErrorSample>& samples);

// The samples of one feature type (or one landmark), by type / landmark id.
std::map<LandmarkType, std::vector<PixelErrorSample>> samplesByType(const std::vector<PixelErrorSample>& samples);
std::map<int, std::vector<PixelErrorSample>> samplesByLandmark(const std::vector<PixelErrorSample>& samples);

}  // namespace stereoloc
