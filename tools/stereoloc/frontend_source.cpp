#include "tools/stereoloc/frontend_source.h"

#include <chrono>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "src/error.h"
#include "tools/stereoloc/cli_common.h"

namespace stereoloc::cli {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

std::string sizeText(int w, int h) { return std::to_string(w) + "x" + std::to_string(h); }

}  // namespace

std::string toString(FrontendMode mode) { return mode == FrontendMode::Images ? "images" : "pixels"; }

FrontendMode frontendModeFromString(const std::string& name) {
  if (name == "pixels") return FrontendMode::Pixels;
  if (name == "images") return FrontendMode::Images;
  throw UsageError("--frontend: unknown frontend '" + name + "' (expected pixels or images)");
}

std::string toString(FrontendLandmarks set) { return set == FrontendLandmarks::GoalCorners ? "goal_corners" : "all"; }

FrontendLandmarks frontendLandmarksFromString(const std::string& name) {
  if (name == "all") return FrontendLandmarks::All;
  if (name == "goal_corners") return FrontendLandmarks::GoalCorners;
  throw UsageError("--frontend-landmarks: unknown set '" + name + "' (expected all or goal_corners)");
}

void ImageFrontendStats::merge(const ImageFrontendStats& o) {
  pairs += o.pairs;
  observations += o.observations;
  identified += o.identified;
  dropped += o.dropped;
  ms_render += o.ms_render;
  ms_frontend += o.ms_frontend;
}

ImageObserver::ImageObserver(const StereoRig& rig, const FieldMap& map, const ImageFrontendOptions& options)
    : frontend_(rig, map, options.params), landmarks_(options.landmarks) {}

std::vector<Observation> ImageObserver::observe(const cv::Mat& left_bgr, const cv::Mat& right_bgr, double head_pan) {
  const auto start = Clock::now();
  const frontend::FrontendResult& r = frontend_.process(left_bgr, right_bgr, head_pan);
  std::vector<Observation> out;
  out.reserve(r.observations.size());
  for (const Observation& o : r.observations) {
    if (o.landmark_id < 0 && landmarks_ == FrontendLandmarks::GoalCorners) {
      ++stats_.dropped;
      continue;
    }
    out.push_back(o);
    ++stats_.observations;
    stats_.identified += o.landmark_id >= 0 ? 1 : 0;
  }
  ++stats_.pairs;
  stats_.ms_frontend += msSince(start);
  return out;
}

cv::Mat readStereoImage(const std::string& path, const StereoRig& rig) {
  // Checked first: OpenCV would print its own warning for a missing file.
  if (!std::filesystem::is_regular_file(path)) throw Error(path + ": cannot read the image (no such file)");
  const cv::Mat img = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (img.empty()) throw Error(path + ": cannot read the image (unreadable or not an image)");
  if (img.depth() != CV_8U) throw Error(path + ": the image must have 8-bit channels (8-bit BGR)");
  const int W = rig.params().image_width, H = rig.params().image_height;
  if (img.cols != W || img.rows != H)
    throw Error(path + ": image size " + sizeText(img.cols, img.rows) + " differs from the rig's " + sizeText(W, H));
  if (img.channels() == 4) {
    cv::Mat bgr;
    cv::cvtColor(img, bgr, cv::COLOR_BGRA2BGR);
    return bgr;
  }
  if (img.channels() != 3)
    throw Error(path + ": the image has " + std::to_string(img.channels()) +
                " channel(s); a colour (BGR) image is needed for the goal colours");
  return img;
}

ImageFrontendStats observeDatasetImages(Dataset& d, const std::string& dir, const ImageFrontendOptions& options) {
  if (!d.has_images)
    throw Error(dir + ": dataset has no images (dataset.yaml has_images is 0; write them with `stereoloc simulate --images`)");
  ImageObserver observer(d.rig, d.map, options);
  for (Step& s : d.steps) {
    const std::string left = (std::filesystem::path(dir) / imageFileName("left", s.step)).string();
    const std::string right = (std::filesystem::path(dir) / imageFileName("right", s.step)).string();
    const cv::Mat l = readStereoImage(left, d.rig), r = readStereoImage(right, d.rig);
    try {
      s.observations = observer.observe(l, r, s.head_pan);
    } catch (const Error& e) {
      throw Error(left + ": frontend: " + e.what());
    }
  }
  return observer.stats();
}

ImageFrontendStats observeRenderedImages(Dataset& d, const SimulationTrace& trace, const StereoRenderer& renderer,
                                         uint64_t noise_seed, const ImageFrontendOptions& options) {
  if (trace.scenario.poses.size() != d.steps.size() || trace.obstacles.size() != d.steps.size())
    throw Error("observeRenderedImages: the simulation trace does not match the dataset");
  ImageObserver observer(d.rig, d.map, options);
  double ms_render = 0;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    Step& s = d.steps[k];
    const auto start = Clock::now();
    const StereoImages im = renderer.render(trace.scenario.poses[k], s.head_pan, trace.obstacles[k], noise_seed + k);
    ms_render += msSince(start);
    s.observations = observer.observe(im.left, im.right, s.head_pan);
  }
  ImageFrontendStats stats = observer.stats();
  stats.ms_render = ms_render;
  return stats;
}

}  // namespace stereoloc::cli
