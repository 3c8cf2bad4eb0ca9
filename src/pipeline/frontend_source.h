#pragma once
// `--frontend images|pixels`: where the commands get their per-step observations from.
//
//   pixels  the observations as the dataset / simulator gives them (observations.csv, or the
//           simulator's noisy projections of the visible landmarks);
//   images  the vision frontend (frontend/frontend.h, thesis chapter 3) run on the stereo pair of
//           every step: the dataset's images/left_NNNNNN.png and right_NNNNNN.png, or, in the
//           studies, pairs rendered in memory by the renderer (src/sim/renderer.h) from the true
//           pose of each step. The result replaces Step::observations; odometry and compass stay.
//
// Landmark identity. The frontend identifies goal corners (globally unique by colour and side,
// section 3.6); corners, junctions and intersections of the markings are not unique and come
// out with landmark_id -1. They are associated with map landmarks by each ESTIMATOR against its
// own current belief (solvers/data_association.h, the chi-square gate of (5.20)): the EKF and the
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

#include "src/io/dataset.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"

namespace stereoloc::frontend {
class Frontend;
struct FrontendParams;
}  // namespace stereoloc::frontend

namespace stereoloc {

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
  // Frontend parameters (frontend/frontend.h); null = the frontend's defaults. Held by pointer
  // so that this header does not depend on the frontend's internals.
  std::shared_ptr<const frontend::FrontendParams> params;
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
  ~ImageObserver();
  ImageObserver(const ImageObserver&) = delete;
  ImageObserver& operator=(const ImageObserver&) = delete;
  // Observations of one rectified 8-bit BGR pair of the rig's size (throws stereoloc::Error).
  std::vector<Observation> observe(const cv::Mat& left_bgr, const cv::Mat& right_bgr, double head_pan);
  const ImageFrontendStats& stats() const { return stats_; }
  ImageFrontendStats& stats() { return stats_; }

 private:
  std::unique_ptr<frontend::Frontend> frontend_;
  FrontendLandmarks landmarks_;
  ImageFrontendStats stats_;
};

// The options from their names: `landmarks` "all" | "goal_corners" (UsageError otherwise), and
// the frontend parameters YAML at `params_path` ("" = the defaults; a bad file throws Error).
ImageFrontendOptions imageFrontendOptions(const std::string& landmarks, const std::string& params_path);

// One line for a log: "frontend on N image pairs: M observations (K goal corners), X ms/pair".
std::string frontendSummary(const ImageFrontendStats& stats);

// Reads a colour image for the frontend: 8-bit channels, 3 of them (4 are converted to BGR; a
// grey image cannot show the goal colours). Anything else throws stereoloc::Error, one line
// naming the file; `what` names the image in it ("left image").
cv::Mat readColourImage(const std::string& path, const std::string& what = "image");
// The same, of the rig's size (raw images when the rig's calibration rectifies them).
cv::Mat readStereoImage(const std::string& path, const StereoRig& rig, const std::string& what = "image");

// Reads every stereo pair of a dataset with images (readStereoImage: decodable, colour, the rig's
// size) and returns how many; the first unusable one throws stereoloc::Error naming its file.
// A dataset without images has none (0).
size_t checkDatasetImages(const Dataset& dataset, const std::string& dir);

// Replaces the observations of every step of a dataset by the frontend's observations on its
// images (DIR/images/left_NNNNNN.png, right_NNNNNN.png). Throws stereoloc::Error naming the
// dataset when it has no images, or naming the file when an image is missing or unusable.
ImageFrontendStats observeDatasetImages(Dataset& dataset, const std::string& dir,
                                        const ImageFrontendOptions& options = ImageFrontendOptions());

// Loads the dataset at `dir` and, in Images mode, replaces its observations by the frontend's on
// its images (observeDatasetImages); `stats`, when given, receives what the frontend did (all
// zero in Pixels mode).
Dataset loadDatasetWithFrontend(const std::string& dir, FrontendMode mode, const ImageFrontendOptions& options,
                                ImageFrontendStats* stats = nullptr);

// Studies: renders the stereo pair of every step of a simulated dataset from the true poses,
// head pans and obstacles of its trace, adds addSensorNoise(noise_sigma, noise_seed + step
// index) and replaces the observations by the frontend's, so the observations depend only on
// the arguments. `renderer` must be built for the dataset's map and rig without sensor noise
// (RenderOptions::noise_sigma 0); it is const and may be shared between threads.
ImageFrontendStats observeRenderedImages(Dataset& dataset, const SimulationTrace& trace, const StereoRenderer& renderer,
                                         double noise_sigma, uint64_t noise_seed,
                                         const ImageFrontendOptions& options = ImageFrontendOptions());

// Studies render the same true path in every Monte Carlo trial (the ground truth is the
// scenario's nominal path; only the sensors are noisy), so the noise-free pairs are rendered
// once per scenario and each trial adds its own sensor noise (addSensorNoise): far cheaper than
// rendering again, and identical to rendering each trial (observeRenderedImages).
struct CleanRenders {
  std::vector<Pose2> poses;       // the trace's true poses these pairs were rendered from
  std::vector<double> head_pans;  // rad
  std::vector<cv::Mat> left, right;  // CV_8UC3, no sensor noise
};

// Renders every step of a trace (no obstacles allowed) with `renderer` (which must have no
// noise, blur or illumination change), `threads` workers striped over the steps; the result
// does not depend on the thread count.
std::shared_ptr<const CleanRenders> renderClean(const SimulationTrace& trace, const StereoRenderer& renderer, int threads);

// The studies' sensor noise: independent N(0, sigma^2) grey levels added to every channel of
// both images, rounded and saturated to 8 bits -- the model of RenderOptions::noise_sigma, but
// drawn ~10x faster (std::normal_distribution costs as much as rendering the pair): each draw
// is one of 2^16 equiprobable normal quantiles Phi^-1((i + 0.5) / 2^16) (|z| <= 4.3), picked by
// 16 bits of a splitmix64 stream seeded with `seed`. Deterministic per seed.
void addSensorNoise(cv::Mat& left, cv::Mat& right, double sigma, uint64_t seed);

// observeRenderedImages with the pairs taken from `clean` plus addSensorNoise(noise_sigma,
// noise_seed + step index). Throws stereoloc::Error when the trace's poses differ from clean's.
ImageFrontendStats observeCleanRenders(Dataset& dataset, const SimulationTrace& trace, const CleanRenders& clean,
                                       double noise_sigma, uint64_t noise_seed,
                                       const ImageFrontendOptions& options = ImageFrontendOptions());

}  // namespace stereoloc
