#pragma once
// `--frontend images|pixels`: where the commands get their per-step observations from.
//
//   pixels  the observations as the dataset / simulator gives them (observations.csv, or the
//           simulator's noisy projections of the visible landmarks);
//   images  the vision frontend (frontend/frontend.h, thesis chapter 3) run on the stereo pair of
//           every step: the dataset's images/left_NNNNNN.png and right_NNNNNN.png, or, in the
//           studies, pairs rendered in memory by the renderer (src/renderer.h) from the true
//           pose of each step. The result replaces Step::observations; odometry and compass stay.
//
// Landmark identity. The frontend identifies goal corners (globally unique by colour and side,
// section 3.6); corners, junctions and intersections of the markings are not unique and come
// out with landmark_id -1. They are associated with map landmarks by each ESTIMATOR against its
// own current belief (src/data_association.h, the chi-square gate of (5.20)): the EKF and the
// sliding window at their prior of the step, the particle filter at its predicted estimate, the
// batch smoother at the dead-reckoned initial guess. The global fixes use only identified
// observations, i.e. goal corners, as in the thesis (6.3, 6.4). With `landmarks = GoalCorners`
// the unidentified observations are dropped here, which gives the thesis's landmark set
// (the same set the pixel simulator reports by default).
#include <opencv2/core/mat.hpp>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "frontend/frontend.h"
#include "src/dataset.h"
#include "src/renderer.h"
#include "src/simulator.h"

namespace stereoloc::cli {

enum class FrontendMode { Pixels, Images };
std::string toString(FrontendMode mode);
FrontendMode frontendModeFromString(const std::string& name);  // "pixels" | "images"; UsageError otherwise

// Which frontend observations are kept (see the header comment).
enum class FrontendLandmarks {
  All,          // goal corners plus unidentified corners/junctions (associated by the estimators)
  GoalCorners,  // only the identified goal corners (the thesis's landmarks)
};
std::string toString(FrontendLandmarks set);
FrontendLandmarks frontendLandmarksFromString(const std::string& name);  // "all" | "goal_corners"; UsageError otherwise

struct ImageFrontendOptions {
  frontend::FrontendParams params;                     // the frontend's defaults unless loaded
  FrontendLandmarks landmarks = FrontendLandmarks::All;
};

// What happened to the images of one run (for the commands' one-line summaries).
struct ImageFrontendStats {
  long pairs = 0;               // stereo pairs processed
  long observations = 0;        // observations kept
  long identified = 0;          // of those, with a landmark id (goal corners)
  long dropped = 0;             // unidentified observations dropped (landmarks = GoalCorners)
  double ms_render = 0;         // total wall time rendering (studies only), ms
  double ms_frontend = 0;       // total wall time in the frontend, ms
  void merge(const ImageFrontendStats& o);
};

// The frontend of one rig and map, reused for every pair of a run (the frontend keeps its
// buffers between calls). Not thread-safe: one per thread.
class ImageObserver {
 public:
  ImageObserver(const StereoRig& rig, const FieldMap& map, const ImageFrontendOptions& options = ImageFrontendOptions());
  // Observations of one rectified 8-bit BGR pair of the rig's size (throws stereoloc::Error).
  std::vector<Observation> observe(const cv::Mat& left_bgr, const cv::Mat& right_bgr, double head_pan);
  const ImageFrontendStats& stats() const { return stats_; }
  ImageFrontendStats& stats() { return stats_; }

 private:
  frontend::Frontend frontend_;
  FrontendLandmarks landmarks_;
  ImageFrontendStats stats_;
};

// Reads one image of a stereo pair for the frontend: 8-bit, 3 channels (4 are converted), the
// rig's size. Anything else throws stereoloc::Error, one line naming the file.
cv::Mat readStereoImage(const std::string& path, const StereoRig& rig);

// Replaces the observations of every step of a dataset by the frontend's observations on its
// images (DIR/images/left_NNNNNN.png, right_NNNNNN.png). Throws stereoloc::Error naming the
// dataset when it has no images, or naming the file when an image is missing or unusable.
ImageFrontendStats observeDatasetImages(Dataset& dataset, const std::string& dir,
                                        const ImageFrontendOptions& options = ImageFrontendOptions());

// Studies: renders the stereo pair of every step of a simulated dataset from the true poses,
// head pans and obstacles of its trace and replaces the observations by the frontend's. The
// image noise of step s is seeded with noise_seed + s (as `simulate --images` does), so the
// observations depend only on the arguments. `renderer` must be built for the dataset's map and
// rig (it is const and may be shared between threads).
ImageFrontendStats observeRenderedImages(Dataset& dataset, const SimulationTrace& trace, const StereoRenderer& renderer,
                                         uint64_t noise_seed, const ImageFrontendOptions& options = ImageFrontendOptions());

}  // namespace stereoloc::cli
