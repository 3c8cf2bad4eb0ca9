#pragma once
// Rendered stereo image pairs of the simulated MiroSot world, with exact ground truth.
//
// Each pixel is ray-cast against the analytic floor (markings as strips and rings) and the convex
// objects of src/sim/simulator_scene.h, averaging a grid of sample rays, re-sampled more finely on
// edges (a pixel integrates light over its area). Pixel (u, v) is the point u, v of
// StereoRig::project, so a projected landmark lands exactly on the rendered feature.
// Ground truth per image: the visible pieces of every straight edge (image end points) and the
// image position of every visible landmark with its id. Images are identical whatever the thread
// count (noise is drawn afterwards from RenderOptions::seed). Sampling, tile shortcuts and the
// truth's rules: docs/frontend.md, "Renderer".
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "src/core/field_map.h"
#include "src/core/pose2.h"
#include "src/sim/simulator_scene.h"
#include "src/core/stereo_rig.h"

namespace stereoloc {

struct Dataset;
struct SimulationTrace;

struct RenderOptions {
  int samples_per_axis = 2;     // samples per pixel = samples_per_axis^2 (>= 2 for anti-aliasing)
  int edge_samples_per_axis = 4;  // finer grid on edge pixels (0 = off, else > samples_per_axis, <= 16)
  bool shading = true;          // dim surfaces by a fixed light direction (walls vs tops)
  double noise_sigma = 0.0;     // Gaussian sensor noise, grey levels (0..255), per channel
  double blur_sigma = 0.0;      // Gaussian blur, px (0 = none)
  double brightness = 0.0;      // added to every channel, grey levels ("bad illumination", Fig. 6.2)
  double contrast = 1.0;        // multiplies (value - 128) before the brightness is added
  uint64_t seed = 0;            // noise engine seed
  bool compute_truth = true;    // fill StereoImages::truth (costs a few ms per pair)
  int threads = 2;              // worker threads (result independent of it)
  // true: every sample ray is Scene::trace against every object, without the renderer's
  // shortcuts (object culling by image box and by height, tiles settled from their corner rays,
  // slab tests with hoisted terms). The same images (tested), 24x the work.
  bool reference_tracing = false;
  SceneColours colours;

  void validate() const;  // throws stereoloc::Error naming the field
};

struct ImageSegment {
  std::string kind;   // marking, wall_foot, wall_top, goal_post, goal_foot, goal_top, triangle, top_outline
  std::string name;
  Eigen::Vector2d a = Eigen::Vector2d::Zero(), b = Eigen::Vector2d::Zero();  // px
};

struct ImageLandmark {
  int id = -1;
  std::string type;                           // toString(LandmarkType)
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero();  // px
};

struct ImageTruth {
  std::vector<ImageSegment> segments;
  std::vector<ImageLandmark> landmarks;
};

struct StereoTruth {
  Pose2 robot;
  double head_pan = 0.0;
  ImageTruth left, right;
};

struct StereoImages {
  cv::Mat left, right;  // CV_8UC3, BGR
  StereoTruth truth;
};

// Holds the precomputed per-pixel rays of a rig; reuse it for many pairs.
class StereoRenderer {
 public:
  StereoRenderer(const FieldMap& map, const StereoRig& rig, const RenderOptions& options = RenderOptions());
  StereoImages render(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles) const;
  // The same with an explicit noise seed (instead of options().seed).
  StereoImages render(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles,
                      uint64_t noise_seed) const;
  // Only the ground truth (no pixels).
  StereoTruth truth(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles) const;
  // Per image row v, the half-open column range [first, last) (empty when first >= last).
  using ColumnRanges = std::vector<std::pair<int, int>>;
  // One camera's image (0 left, 1 right): render()'s pixels of that camera before sensor noise.
  // With `needed` (one range per image row) only those pixels are render()'s, the others 0, and
  // only what they depend on is ray-cast (the pixels themselves and their 4-neighbours' base
  // samples); with blur_sigma > 0 the whole image.
  cv::Mat renderCamera(const Pose2& robot, double head_pan, const std::vector<Obstacle>& obstacles, int camera,
                       const ColumnRanges* needed = nullptr) const;
  const RenderOptions& options() const { return options_; }

 private:
  StereoTruth computeTruth(const Scene& scene, const Pose2& robot, double head_pan) const;
  // One camera's image before sensor noise; the work, phase by phase: ViewRender in renderer.cpp.
  cv::Mat renderView(const Scene& scene, const Pose2& robot, double head_pan, int camera,
                     const ColumnRanges* needed) const;
  // Offset in the pixel (0..1) of base sample i (0..samples_per_axis-1). Centred (i + 0.5) / n,
  // except when the edge grid nests the base grid (edge_samples_per_axis a multiple of n): then
  // the base samples are edge-grid points, still 1/n apart across the whole image, and a refined
  // pixel reuses them. Uniform pixels, the only ones keeping the base samples, do not depend on
  // where in the pixel they are sampled.
  double baseSampleOffset(int i) const;

  FieldMap map_;
  StereoRig rig_;
  RenderOptions options_;
  Scene static_scene_;
  std::vector<SceneEdge> outline_edges_;  // top outline of walls and goals (truth only)
  // Sample ray directions in C2 (x forward) are (1, y, z): y depends only on the image column
  // and the sample's column offset, z only on the row, so they are stored per column and per
  // row (base grid: index u * samples_per_axis + i; edge grid: u * edge_samples_per_axis + k).
  std::vector<float> base_y_, base_z_, fine_y_, fine_z_;
};

// One-off convenience wrapper around StereoRenderer.
StereoImages renderStereoPair(const FieldMap& map, const StereoRig& rig, const Pose2& robot, double head_pan,
                              const std::vector<Obstacle>& obstacles, const RenderOptions& options);

// The ground truth as JSON (units px; documented in docs/dataset_format.md).
std::string truthToJson(const StereoTruth& truth, long step, int image_width, int image_height);

// Renders every step of a simulated dataset into DIR/images/{left,right}_NNNNNN.png and
// truth_NNNNNN.json. The noise of step s uses seed + s.
void writeDatasetImages(const Dataset& d, const SimulationTrace& trace, const RenderOptions& options, uint64_t seed,
                        const std::string& dir);

}  // namespace stereoloc
