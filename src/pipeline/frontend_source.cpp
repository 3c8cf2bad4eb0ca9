#include "src/pipeline/frontend_source.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <thread>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "frontend/frontend.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/io/image_file.h"
#include "src/pipeline/usage_error.h"

namespace stereoloc {
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
    : frontend_(std::make_unique<frontend::Frontend>(rig, map, options.params ? *options.params : frontend::FrontendParams())),
      landmarks_(options.landmarks) {}

ImageObserver::~ImageObserver() = default;

std::vector<Observation> ImageObserver::observe(const cv::Mat& left_bgr, const cv::Mat& right_bgr, double head_pan) {
  const auto start = Clock::now();
  const frontend::FrontendResult& r = frontend_->process(left_bgr, right_bgr, head_pan);
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

ImageFrontendOptions imageFrontendOptions(const std::string& landmarks, const std::string& params_path) {
  ImageFrontendOptions o;
  o.landmarks = frontendLandmarksFromString(landmarks);
  if (!params_path.empty())
    o.params = std::make_shared<const frontend::FrontendParams>(frontend::FrontendParams::load(params_path));
  return o;
}

std::string frontendSummary(const ImageFrontendStats& st) {
  char line[256];
  std::snprintf(line, sizeof line, "frontend on %ld image pairs: %ld observations (%ld goal corners)%s, %.2f ms/pair",
                st.pairs, st.observations, st.identified,
                st.dropped ? (", " + std::to_string(st.dropped) + " unidentified dropped").c_str() : "",
                st.pairs ? st.ms_frontend / st.pairs : 0.0);
  return line;
}

cv::Mat readColourImage(const std::string& path, const std::string& what) {
  const ImageRead read = readImageFile(path, ImageColour::AsStored);
  if (!read.problem.empty()) throw Error(path + ": cannot read the " + what + " (" + read.problem + ")");
  const cv::Mat& img = read.image;
  if (img.depth() != CV_8U)
    throw Error(path + ": the " + what + " has " + (img.depth() == CV_16U ? "16" : "non-8") +
                "-bit channels; 8-bit BGR is required");
  if (img.channels() == 4) {
    cv::Mat bgr;
    cv::cvtColor(img, bgr, cv::COLOR_BGRA2BGR);
    return bgr;
  }
  if (img.channels() != 3)
    throw Error(path + ": the " + what + " has " + std::to_string(img.channels()) +
                " channel(s); a colour (BGR) image is needed for the goal colours");
  return img;
}

cv::Mat readStereoImage(const std::string& path, const StereoRig& rig, const std::string& what) {
  cv::Mat img = readColourImage(path, what);
  const int W = rig.params().image_width, H = rig.params().image_height;
  if (img.cols != W || img.rows != H)
    throw Error(path + ": " + what + " size " + sizeText(img.cols, img.rows) + " differs from the rig's " + sizeText(W, H));
  return img;
}

size_t checkDatasetImages(const Dataset& d, const std::string& dir) {
  if (!d.has_images) return 0;
  for (const Step& s : d.steps)
    for (const char* side : {"left", "right"})
      readStereoImage((std::filesystem::path(dir) / imageFileName(side, s.step)).string(), d.rig,
                      std::string(side) + " image");
  return d.steps.size();
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

Dataset loadDatasetWithFrontend(const std::string& dir, FrontendMode mode, const ImageFrontendOptions& options,
                                ImageFrontendStats* stats) {
  Dataset d = loadDataset(dir);
  ImageFrontendStats st;
  if (mode == FrontendMode::Images) st = observeDatasetImages(d, dir, options);
  if (stats) *stats = st;
  return d;
}

ImageFrontendStats observeRenderedImages(Dataset& d, const SimulationTrace& trace, const StereoRenderer& renderer,
                                         double noise_sigma, uint64_t noise_seed, const ImageFrontendOptions& options) {
  if (trace.scenario.poses.size() != d.steps.size() || trace.obstacles.size() != d.steps.size())
    throw Error("observeRenderedImages: the simulation trace does not match the dataset");
  if (renderer.options().noise_sigma != 0) throw Error("observeRenderedImages: the renderer must have no sensor noise");
  ImageObserver observer(d.rig, d.map, options);
  double ms_render = 0;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    Step& s = d.steps[k];
    const auto start = Clock::now();
    StereoImages im = renderer.render(trace.scenario.poses[k], s.head_pan, trace.obstacles[k], 0);
    addSensorNoise(im.left, im.right, noise_sigma, noise_seed + k);
    ms_render += msSince(start);
    s.observations = observer.observe(im.left, im.right, s.head_pan);
  }
  ImageFrontendStats stats = observer.stats();
  stats.ms_render = ms_render;
  return stats;
}

std::shared_ptr<const CleanRenders> renderClean(const SimulationTrace& trace, const StereoRenderer& renderer, int threads) {
  const RenderOptions& ro = renderer.options();
  if (ro.noise_sigma != 0 || ro.blur_sigma != 0 || ro.brightness != 0 || ro.contrast != 1.0)
    throw Error("renderClean: the renderer must have no noise, blur or illumination change");
  auto out = std::make_shared<CleanRenders>();
  const size_t n = trace.scenario.poses.size();
  out->poses = trace.scenario.poses;
  out->head_pans = trace.scenario.head_pan;
  out->left.resize(n);
  out->right.resize(n);
  for (size_t k = 0; k < n; ++k)
    if (k < trace.obstacles.size() && !trace.obstacles[k].empty())
      throw Error("renderClean: scenes with obstacles change per trial and cannot be cached");
  std::vector<std::string> errors(static_cast<size_t>(std::max(1, threads)));
  auto work = [&](int t, int stride) {
    try {
      for (size_t k = static_cast<size_t>(t); k < n; k += static_cast<size_t>(stride)) {
        StereoImages im = renderer.render(out->poses[k], k < out->head_pans.size() ? out->head_pans[k] : 0.0, {}, 0);
        out->left[k] = im.left;
        out->right[k] = im.right;
      }
    } catch (const std::exception& e) {
      errors[static_cast<size_t>(t)] = e.what();
    }
  };
  const int stride = std::max(1, threads);
  std::vector<std::thread> pool;
  for (int t = 1; t < stride; ++t) pool.emplace_back(work, t, stride);
  work(0, stride);
  for (std::thread& th : pool) th.join();
  for (const std::string& e : errors)
    if (!e.empty()) throw Error(e);
  return out;
}

void addSensorNoise(cv::Mat& left, cv::Mat& right, double sigma, uint64_t seed) {
  if (!(sigma > 0)) return;
  // Phi^-1(p) = sign(p - 1/2) sqrt(chi2_1^-1(|2p - 1|)), since z^2 ~ chi2(1).
  static const std::vector<float> quantiles = [] {
    std::vector<float> q(65536);
    for (size_t i = 0; i < q.size(); ++i) {
      const double p = (static_cast<double>(i) + 0.5) / static_cast<double>(q.size());
      const double z = std::sqrt(chi2Quantile(std::fabs(2.0 * p - 1.0), 1));
      q[i] = static_cast<float>(p < 0.5 ? -z : z);
    }
    return q;
  }();
  uint64_t state = seed;
  uint64_t bits = 0;
  int left_in_bits = 0;
  const float s = static_cast<float>(sigma);
  for (cv::Mat* m : {&left, &right}) {
    if (m->type() != CV_8UC3) throw Error("addSensorNoise: images must be CV_8UC3");
    for (int v = 0; v < m->rows; ++v) {
      uchar* p = m->ptr<uchar>(v);
      for (int k = 0; k < m->cols * 3; ++k) {
        if (left_in_bits == 0) {
          // splitmix64
          uint64_t z = (state += 0x9E3779B97F4A7C15ull);
          z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
          z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
          bits = z ^ (z >> 31);
          left_in_bits = 4;
        }
        const float n = quantiles[bits & 0xFFFF];
        bits >>= 16;
        --left_in_bits;
        p[k] = cv::saturate_cast<uchar>(static_cast<float>(p[k]) + s * n);
      }
    }
  }
}

ImageFrontendStats observeCleanRenders(Dataset& d, const SimulationTrace& trace, const CleanRenders& clean,
                                       double noise_sigma, uint64_t noise_seed, const ImageFrontendOptions& options) {
  if (trace.scenario.poses.size() != d.steps.size() || clean.poses.size() != d.steps.size())
    throw Error("observeCleanRenders: the cached renders do not match the dataset");
  ImageObserver observer(d.rig, d.map, options);
  double ms_render = 0;
  cv::Mat left, right;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    const Pose2& p = trace.scenario.poses[k];
    if (p.x != clean.poses[k].x || p.y != clean.poses[k].y || p.theta != clean.poses[k].theta ||
        d.steps[k].head_pan != clean.head_pans[k] || (k < trace.obstacles.size() && !trace.obstacles[k].empty()))
      throw Error("observeCleanRenders: step " + std::to_string(d.steps[k].step) + " differs from the cached render");
    const auto start = Clock::now();
    clean.left[k].copyTo(left);
    clean.right[k].copyTo(right);
    addSensorNoise(left, right, noise_sigma, noise_seed + k);
    ms_render += msSince(start);
    d.steps[k].observations = observer.observe(left, right, d.steps[k].head_pan);
  }
  ImageFrontendStats stats = observer.stats();
  stats.ms_render = ms_render;
  return stats;
}

}  // namespace stereoloc
