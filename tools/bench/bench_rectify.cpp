// bench_rectify: cost of rectifying a raw 320x240 stereo pair (frontend/rectify.h) and of the
// whole frontend on raw pairs of a distorted, unrectified calibration, on rendered MiroSot views.
//
//   bench_rectify [benchmark flags]   (e.g. --benchmark_repetitions=5 --benchmark_report_aggregates_only)
//
// The argument of the raw-pair benchmarks is OpenCV's thread count (cv::setNumThreads): the
// rectifier runs two tasks of OpenCV's pool (the two cameras, or the two halves of the left luma).
//
//   BM_Rectify            whole-image colour rectification of a pair (Rectifier::rectify)
//   BM_RectifyLuma        the luma path's rectification of a pair: the whole left luma, and the
//                         whole right luma as an upper bound of what the frontend asks for
//   BM_RectifyLumaScalar  the same with the scalar remap loop instead of the vector kernel
//   BM_RemapPairSerial    reference: two cv::remap calls of the colour pair on one thread
//   BM_FrontendRawPair    the frontend on a raw pair (luma path)
//   BM_FrontendRawPairColourRectified  the same pair rectified whole in colour, then the frontend
//                         on the rectified pair (the reference for the luma path)
//   BM_FrontendRectifiedPair  the frontend on the same views rendered rectified (no rectification)
// Times are wall clock ("Time") and the CPU time of the whole process over all threads ("CPU"),
// so that a second thread's work is counted.
//
// The raw images are rendered ideal pinhole pairs (the rectified rig of the calibration) warped
// into the raw cameras by the calibration's own model (cv::undistortPoints of every raw pixel),
// so the frontend sees the lens distortion and camera rotation a real pair would have.
#include <benchmark/benchmark.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <vector>

#include "frontend/frontend.h"
#include "frontend/rectify.h"
#include "src/core/error.h"
#include "src/core/field_map.h"
#include "src/core/measurement_model.h"
#include "src/core/stereo_rig.h"
#include "src/sim/renderer.h"
#include "src/study/data_files.h"

using namespace stereoloc;

namespace {

// A 60 deg small CMOS pair (data/stereo_calibration_example.yml): barrel distortion, slightly
// different cameras, a rotated right camera.
StereoCalibration benchCalibration() {
  const std::string path = findDataFile("stereo_calibration_example.yml");
  if (path.empty()) throw Error("bench_rectify: data file stereo_calibration_example.yml not found");
  return StereoCalibration::load(path);
}

// Raw image of camera i from the rectified one: each raw pixel looks up where the calibration
// says its ray lands in the rectified image.
cv::Mat toRaw(const cv::Mat& rectified, const StereoCalibration& c, int i) {
  std::vector<cv::Point2f> raw, rect;
  for (int v = 0; v < c.image_size.height; ++v)
    for (int u = 0; u < c.image_size.width; ++u) raw.emplace_back(static_cast<float>(u), static_cast<float>(v));
  cv::undistortPoints(raw, rect, i == 0 ? c.K1 : c.K2, i == 0 ? c.D1 : c.D2, i == 0 ? c.R1 : c.R2, i == 0 ? c.P1 : c.P2);
  cv::Mat mx(c.image_size, CV_32FC1), my(c.image_size, CV_32FC1);
  for (size_t k = 0; k < rect.size(); ++k) {
    mx.at<float>(static_cast<int>(k / c.image_size.width), static_cast<int>(k % c.image_size.width)) = rect[k].x;
    my.at<float>(static_cast<int>(k / c.image_size.width), static_cast<int>(k % c.image_size.width)) = rect[k].y;
  }
  cv::Mat out;
  cv::remap(rectified, out, mx, my, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return out;
}

struct RawPairs {
  StereoRig rig;
  std::vector<std::pair<cv::Mat, cv::Mat>> pairs;
  std::vector<Pose2> poses;
};

const RawPairs& rawPairs() {
  static const RawPairs data = [] {
    RawPairs d{StereoRig(StereoRigParams(), benchCalibration()), {}, {}};
    StereoRig pinhole(d.rig.params());  // the rectified rig without the calibration
    const FieldMap map = FieldMap::miroSot();
    StereoRenderer renderer(map, pinhole);
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> ux(150, 1350), uy(150, 1150), ua(-3.14159, 3.14159);
    for (int k = 0; k < 16; ++k) {
      d.poses.emplace_back(ux(rng), uy(rng), ua(rng));
      const StereoImages img = renderer.render(d.poses.back(), 0.0, {}, 100 + k);
      d.pairs.emplace_back(toRaw(img.left, *d.rig.calibration(), 0), toRaw(img.right, *d.rig.calibration(), 1));
    }
    return d;
  }();
  return data;
}

// Accuracy of a frontend path on the 16 raw pairs against the rendered truth: observations per
// pair, the share of them within 100 mm of a map landmark of their type (goal corners: of their
// identified landmark), and the mean normalised range error |r - r_true| / r_true of those.
struct Accuracy {
  double obs_per_pair = 0, associated = 0, mean_range_error = 0;
};

template <typename Process>
Accuracy accuracy(const RawPairs& d, Process process) {
  const FieldMap map = FieldMap::miroSot();
  Accuracy a;
  size_t n = 0, m = 0;
  for (size_t k = 0; k < d.pairs.size(); ++k)
    for (const Observation& o : process(d.pairs[k].first, d.pairs[k].second)) {
      ++n;
      const Eigen::Vector2d at = landmarkFromRangeBearing(d.poses[k], o.range, o.bearing);
      const Landmark* best = nullptr;
      for (const Landmark& l : map.landmarks())
        if (l.type == o.type && (o.landmark_id < 0 || o.landmark_id == l.id) &&
            (!best || (l.xy() - at).norm() < (best->xy() - at).norm()))
          best = &l;
      if (!best || (best->xy() - at).norm() > 100.0) continue;
      ++m;
      const double r_true = (best->xy() - Eigen::Vector2d(d.poses[k].x, d.poses[k].y)).norm();
      a.mean_range_error += std::fabs(o.range - r_true) / r_true;
    }
  a.obs_per_pair = static_cast<double>(n) / static_cast<double>(d.pairs.size());
  a.associated = n ? static_cast<double>(m) / static_cast<double>(n) : 0.0;
  a.mean_range_error = m ? a.mean_range_error / static_cast<double>(m) : 0.0;
  return a;
}

void setCounters(benchmark::State& state, const Accuracy& a) {
  state.counters["obs_per_pair"] = a.obs_per_pair;
  state.counters["associated"] = a.associated;
  state.counters["range_err"] = a.mean_range_error;
}

// Sets OpenCV's thread count for one benchmark and restores it.
class OpenCvThreads {
 public:
  explicit OpenCvThreads(int n) : saved_(cv::getNumThreads()) { cv::setNumThreads(n); }
  ~OpenCvThreads() { cv::setNumThreads(saved_); }
  OpenCvThreads(const OpenCvThreads&) = delete;
  OpenCvThreads& operator=(const OpenCvThreads&) = delete;

 private:
  int saved_;
};

void BM_Rectify(benchmark::State& state) {
  const RawPairs& d = rawPairs();
  const OpenCvThreads threads(static_cast<int>(state.range(0)));
  frontend::Rectifier rect(*d.rig.calibration());
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = d.pairs[k++ % d.pairs.size()];
    rect.rectify(p.first, p.second);
    benchmark::DoNotOptimize(rect.left().data);
  }
}
BENCHMARK(BM_Rectify)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

// The luma path: the left image whole, the right on every row (an upper bound of what the
// matcher reads), with the given remap kernel.
void rectifyLumaPairs(benchmark::State& state, int threads, frontend::Rectifier::Kernel kernel) {
  const RawPairs& d = rawPairs();
  const OpenCvThreads opencv_threads(threads);
  frontend::Rectifier rect(*d.rig.calibration());
  rect.setKernel(kernel);
  cv::Mat left, right;
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = d.pairs[k++ % d.pairs.size()];
    rect.beginPair(p.first, p.second, left);
    rect.rightLumaRows(0, left.rows, right);
    benchmark::DoNotOptimize(right.data);
  }
}

void BM_RectifyLuma(benchmark::State& state) {
  rectifyLumaPairs(state, static_cast<int>(state.range(0)), frontend::Rectifier::Kernel::Auto);
}
BENCHMARK(BM_RectifyLuma)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

// The same with the portable scalar loop instead of the vector kernel (same pixels).
void BM_RectifyLumaScalar(benchmark::State& state) {
  rectifyLumaPairs(state, 1, frontend::Rectifier::Kernel::Scalar);
}
BENCHMARK(BM_RectifyLumaScalar)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

// Reference in the same run: the pair as two cv::remap calls one after the other on the
// calling thread (the same fixed-point maps and interpolation as the Rectifier).
void BM_RemapPairSerial(benchmark::State& state) {
  const RawPairs& d = rawPairs();
  const StereoCalibration& c = *d.rig.calibration();
  cv::Mat fixed[2], frac[2], out[2];
  for (int i = 0; i < 2; ++i) {
    cv::Mat mx, my;
    cv::initUndistortRectifyMap(i == 0 ? c.K1 : c.K2, i == 0 ? c.D1 : c.D2, i == 0 ? c.R1 : c.R2, i == 0 ? c.P1 : c.P2,
                                c.image_size, CV_32FC1, mx, my);
    cv::convertMaps(mx, my, fixed[i], frac[i], CV_16SC2, false);
  }
  const OpenCvThreads threads(1);
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = d.pairs[k++ % d.pairs.size()];
    cv::remap(p.first, out[0], fixed[0], frac[0], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    cv::remap(p.second, out[1], fixed[1], frac[1], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    benchmark::DoNotOptimize(out[1].data);
  }
}
BENCHMARK(BM_RemapPairSerial)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

void BM_FrontendRawPair(benchmark::State& state) {
  const RawPairs& d = rawPairs();
  const OpenCvThreads threads(static_cast<int>(state.range(0)));
  frontend::Frontend fe(d.rig, FieldMap::miroSot());
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = d.pairs[k++ % d.pairs.size()];
    benchmark::DoNotOptimize(fe.process(p.first, p.second).observations.size());
  }
  setCounters(state, accuracy(d, [&](const cv::Mat& l, const cv::Mat& r) { return fe.process(l, r).observations; }));
}
BENCHMARK(BM_FrontendRawPair)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

void BM_FrontendRawPairColourRectified(benchmark::State& state) {
  const RawPairs& d = rawPairs();
  const OpenCvThreads threads(static_cast<int>(state.range(0)));
  frontend::Rectifier rect(*d.rig.calibration());
  frontend::Frontend fe(StereoRig(d.rig.params()), FieldMap::miroSot());
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = d.pairs[k++ % d.pairs.size()];
    rect.rectify(p.first, p.second);
    benchmark::DoNotOptimize(fe.process(rect.left(), rect.right()).observations.size());
  }
  setCounters(state, accuracy(d, [&](const cv::Mat& l, const cv::Mat& r) {
    rect.rectify(l, r);
    return fe.process(rect.left(), rect.right()).observations;
  }));
}
BENCHMARK(BM_FrontendRawPairColourRectified)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

void BM_FrontendRectifiedPair(benchmark::State& state) {
  const RawPairs& d = rawPairs();
  // Reference: the same views rendered straight into the rectified rig, no rectification.
  static const std::vector<std::pair<cv::Mat, cv::Mat>> ideal = [&] {
    std::vector<std::pair<cv::Mat, cv::Mat>> v;
    StereoRenderer renderer(FieldMap::miroSot(), StereoRig(d.rig.params()));
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> ux(150, 1350), uy(150, 1150), ua(-3.14159, 3.14159);
    for (int k = 0; k < 16; ++k) {
      const StereoImages img = renderer.render(Pose2(ux(rng), uy(rng), ua(rng)), 0.0, {}, 100 + k);
      v.emplace_back(img.left, img.right);
    }
    return v;
  }();
  frontend::Frontend fe(StereoRig(d.rig.params()), FieldMap::miroSot());
  size_t k = 0;
  for (auto _ : state) {
    const auto& p = ideal[k++ % ideal.size()];
    benchmark::DoNotOptimize(fe.process(p.first, p.second).observations.size());
  }
}
BENCHMARK(BM_FrontendRectifiedPair)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
