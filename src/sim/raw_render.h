#pragma once
// Raw stereo pairs of a simulated world with an error profile (src/sim/error_profile.h): what
// two real, imperfect cameras deliver, rendered from the exact ray-cast images of renderer.h.
//
// Per step: the ideal pinhole pair of the TRUE head geometry (baseline, height, tilt plus the
// step's pitch) is ray-cast with a margin of `kMarginPx` around the nominal image, so that
// barrel distortion and camera rotation pull in no pixel from outside it. Motion blur averages
// `exposure_samples` renders at poses spread over the exposure time (on the arc between steps,
// poseAtStep; between a scenario's independent poses, the straight line at a constant turn
// rate, continuous at each step); the right camera's exposure starts `exposure_offset_s` after
// the left's. Each raw pixel then takes the ideal image's value where its ray lands: its ray is
// its pixel undistorted with the true camera matrix and distortion, turned by the camera's true
// rotation (relative rotation, roll). Sensor noise is added once at the end, from the pair's seed.
// Cost: each sub-exposure ray-casts only the camera whose image it feeds, and only the pixels
// of the margin image that cv::remap reads (StereoRenderer::renderCamera with per-row column
// ranges); the images are those of rendering whole pairs (tested). Truth only with
// RenderOptions::compute_truth.
// Ground truth (landmark pixels, segment end points) goes through the same camera model; a
// straight segment's image is curved under distortion, so only its end points are exact.
#include <opencv2/core.hpp>
#include <vector>

#include "src/core/field_map.h"
#include "src/sim/error_profile.h"
#include "src/sim/renderer.h"
#include "src/sim/scenario.h"

namespace stereoloc {

// `map` is the given map; the world is built on trueFieldMap(map, errors).
class RawPairRenderer {
 public:
  static constexpr int kMarginPx = 32;

  RawPairRenderer(const FieldMap& map, const StereoRigParams& nominal, const ErrorProfile& profile,
                  const DrawnErrors& errors, const RenderOptions& options, double dt);
  StereoImages render(const Scenario& scenario, size_t step, const std::vector<Obstacle>& obstacles,
                      uint64_t noise_seed) const;

 private:
  FieldMap map_;
  StereoRigParams nominal_;
  StereoRig nominal_rig_;
  ErrorProfile profile_;
  DrawnErrors errors_;
  RenderOptions options_;
  double dt_;
  cv::Mat rays_[2];  // CV_32FC2: undistorted normalised ray (x/z, y/z) of every raw pixel
};

}  // namespace stereoloc
