// bench_pipeline: the cost per step of the embeddable real-time pipeline (src/pipeline/
// localizer.h) at the thesis's 5 Hz frame rate with odometry at 100 Hz: a stereo pair every
// 20th step. A simulated `circle` run (seed 1) gives the true path and the wheel increments per
// frame; each frame interval's increments are split into 20 equal odometry steps (its arc cut
// in 20). The pairs are rendered beforehand (1.5 grey levels of sensor noise, as `make demo`),
// so the timing holds only the robot's work: the Localizer (frontend + sliding window W = 20
// with pixel_columns factors, known start) fed in real-time order, one thread.
//   BM_Pipeline   one pass over the run per iteration, a fresh Localizer each time; counters
//                 over all steps after the first W frames: camera_median_ms, camera_p99_ms
//                 (addOdometry + addImages + estimate() of a frame step), odometry_median_us,
//                 odometry_p99_us (addOdometry + estimate() of the others), each as wall time
//                 and as this thread's CPU time (cpu_*: not inflated by other processes);
//                 tracking_fraction (tracking or predicting, not lost) and rmse_mm (the steps
//                 pairs are taken at, against the truth) as a sanity check.
//   BM_PipelineSelfCalibrating   the same with the window self-calibrating odometry and stereo
//                 head (`stream --calibrate odometry,stereo`): 20 odometry steps between frames
//                 are one composed calibrated odometry factor.
//   BM_PipelineEkfSelfCalibrating   the same with the self-calibrating EKF as the tracker
//                 (`stream --method ekf --calibrate odometry,stereo`); the first W frames are
//                 left out too.
//   BM_PipelineEkf, BM_PipelineEkfConsidering   the EKF on the given calibration (`stream --method
//                 ekf`) and considering it (`--consider odometry,stereo`).
//   BM_PipelineParticleFilter   the same with the particle filter (3000 particles, `stream
//                 --method pf`).
//   ...Late10     each pair handed over 10 odometry steps (100 ms) after its own step, as a
//                 frontend on another thread would: the window inserts it at its pose, the
//                 filters replay the 10 steps since (Localizer::replay_steps). The camera step
//                 is then the odometry step the pair arrives with.
//   bench_pipeline [--frames=N] [benchmark flags]     (N frames, default 100)
// At the end a table prints the figures, BM_Pipeline's against the targets (1.5 ms / 4 ms / 50 us).
#include <benchmark/benchmark.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include "solvers/self_calibration.h"
#include "src/pipeline/localizer.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"
#include "tools/bench/bench_util.h"

namespace stereoloc {
namespace {

constexpr int kOdometryPerFrame = 20;  // 100 Hz odometry, 5 Hz frames

using bench::percentile;
using bench::threadCpuMs;

struct Recording {
  Dataset dataset;                   // wheel increments and compass per frame
  std::vector<cv::Mat> left, right;  // per frame
  std::vector<double> head_pan;      // per frame
};

Recording record(int frames) {
  Recording out;
  SimulationConfig cfg;
  cfg.scenario.steps = frames;
  SimulationTrace trace;
  out.dataset = simulate("circle", 0, cfg, 1, &trace);
  RenderOptions ro;
  ro.noise_sigma = 1.5;
  ro.seed = 1;
  ro.compute_truth = false;
  const StereoRenderer renderer(out.dataset.map, out.dataset.rig, ro);
  for (size_t k = 0; k < out.dataset.steps.size(); ++k) {
    const StereoImages img = renderer.render(trace.scenario.poses[k], trace.scenario.head_pan[k], {}, 1 + k);
    out.left.push_back(img.left);
    out.right.push_back(img.right);
    out.head_pan.push_back(trace.scenario.head_pan[k]);
  }
  return out;
}

void BM_Pipeline(benchmark::State& state, const Recording& r, LocalizerMethod method, const std::string& calibrate,
                 int late = 0, bool consider = false) {
  const Dataset& d = r.dataset;
  LocalizerConfig config;
  config.map = d.map;
  config.rig = d.rig;
  config.odometry = d.odometry;
  config.init = knownBelief(*d.initial_pose, Eigen::Vector3d(30.0, 30.0, 0.0872664626).cwiseAbs2().asDiagonal());
  config.window.window = 20;
  config.window.keep_history = false;
  config.window.calibration = SelfCalibrationConfig::parse(calibrate);
  config.method = method;
  config.ekf.calibration = config.window.calibration;
  config.ekf.calibration.consider = consider;
  config.ekf.observation_model.model = ObservationModel::PixelColumns;  // as `stream`
  config.ekf.keep_history = false;
  config.particle_filter.keep_history = false;
  std::vector<double> cam_ms, cam_cpu, odo_us, odo_cpu;
  long tracking = 0, camera_steps = 0;
  double sq_error = 0;  // mm^2, camera steps against the truth
  for (auto _ : state) {
    Localizer loc(config);
    long step = 0;
    std::map<long, size_t> frames;  // step a pair is handed over at -> its frame index
    for (size_t k = 0; k < d.steps.size(); ++k) {
      const Step& s = d.steps[k];
      const int sub = k == 0 ? 1 : kOdometryPerFrame;
      for (int i = 1; i <= sub; ++i) {
        if (i == sub) frames[step + late] = k;
        const auto arriving = frames.find(step);
        const bool frame = arriving != frames.end();
        const double t = k == 0 ? s.t : d.steps[k - 1].t + (s.t - d.steps[k - 1].t) * i / sub;
        const double c0 = threadCpuMs();
        const auto t0 = std::chrono::steady_clock::now();
        loc.addOdometry(step, t, s.d_left / sub, s.d_right / sub);
        if (frame) {
          const size_t f = arriving->second;
          loc.addImages(step - late, r.left[f], r.right[f], r.head_pan[f]);
          frames.erase(arriving);
        }
        const Estimate e = loc.estimate();
        const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        const double cpu = threadCpuMs() - c0;
        benchmark::DoNotOptimize(e);
        if (static_cast<int>(k) > config.window.window) {  // the window is full (the EKF: as long)
          (frame ? cam_ms : odo_us).push_back(frame ? ms : 1e3 * ms);
          (frame ? cam_cpu : odo_cpu).push_back(frame ? cpu : 1e3 * cpu);
          if (i == sub) {  // the step a pair is taken at (with late pairs: the estimate before it is in)
            ++camera_steps;
            tracking += e.status == EstimateStatus::Tracking || e.status == EstimateStatus::Predicted;
            if (d.groundtruth[k]) sq_error += (e.pose.translation() - d.groundtruth[k]->translation()).squaredNorm();
          }
        }
        ++step;
      }
    }
  }
  state.counters["camera_median_ms"] = percentile(cam_ms, 0.5);
  state.counters["camera_p99_ms"] = percentile(cam_ms, 0.99);
  state.counters["odometry_median_us"] = percentile(odo_us, 0.5);
  state.counters["odometry_p99_us"] = percentile(odo_us, 0.99);
  state.counters["cpu_camera_median_ms"] = percentile(cam_cpu, 0.5);
  state.counters["cpu_camera_p99_ms"] = percentile(cam_cpu, 0.99);
  state.counters["cpu_odometry_median_us"] = percentile(odo_cpu, 0.5);
  state.counters["cpu_odometry_p99_us"] = percentile(odo_cpu, 0.99);
  state.counters["tracking_fraction"] = camera_steps ? static_cast<double>(tracking) / camera_steps : 0.0;
  state.counters["rmse_mm"] = camera_steps ? std::sqrt(sq_error / static_cast<double>(camera_steps)) : 0.0;
}

class SummaryReporter : public benchmark::ConsoleReporter {
 public:
  void ReportRuns(const std::vector<Run>& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (const Run& r : runs)
      if (r.run_type == Run::RT_Iteration)
        for (const auto& [name, counter] : r.counters) counters_[r.benchmark_name()][name] = counter.value;
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    for (auto& [bench, c] : counters_) {
      // The targets are the sliding window's with in-time pairs (BM_Pipeline); the other runs
      // are measured beside it.
      const bool targeted = bench.rfind("BM_Pipeline/", 0) == 0;
      std::printf("\n%s\n%-28s %12s %12s %12s %12s %14s\n", bench.c_str(), "step (5 Hz frames, 100 Hz)", "median",
                  "p99", "cpu median", "cpu p99", "target");
      std::printf("%-28s %9.3f ms %9.3f ms %9.3f ms %9.3f ms %14s\n", "camera (frontend + tracker)", c["camera_median_ms"],
                  c["camera_p99_ms"], c["cpu_camera_median_ms"], c["cpu_camera_p99_ms"], targeted ? "1.5 / 4 ms" : "-");
      std::printf("%-28s %9.2f us %9.2f us %9.2f us %9.2f us %14s\n", "odometry only", c["odometry_median_us"],
                  c["odometry_p99_us"], c["cpu_odometry_median_us"], c["cpu_odometry_p99_us"],
                  targeted ? "50 us median" : "-");
      std::printf("steps pairs are taken at: %.1f %% tracking or predicting, position RMSE %.1f mm\n",
                  100.0 * c["tracking_fraction"], c["rmse_mm"]);
    }
  }

 private:
  std::map<std::string, std::map<std::string, double>> counters_;
};

}  // namespace
}  // namespace stereoloc

int main(int argc, char** argv) {
  int frames = 100;
  for (int i = 1; i < argc; ++i)
    if (std::strncmp(argv[i], "--frames=", 9) == 0) {
      frames = std::max(30, std::atoi(argv[i] + 9));
      for (int j = i; j + 1 < argc; ++j) argv[j] = argv[j + 1];
      --argc;
      --i;
    }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  const stereoloc::Recording recording = stereoloc::record(frames);
  benchmark::RegisterBenchmark("BM_Pipeline", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::Window, "");
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  benchmark::RegisterBenchmark("BM_PipelineSelfCalibrating", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::Window, "odometry,stereo");
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  benchmark::RegisterBenchmark("BM_PipelineEkfSelfCalibrating", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::Ekf, "odometry,stereo");
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  benchmark::RegisterBenchmark("BM_PipelineEkf", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::Ekf, "");
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  benchmark::RegisterBenchmark("BM_PipelineEkfConsidering", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::Ekf, "odometry,stereo", 0, true);
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  benchmark::RegisterBenchmark("BM_PipelineParticleFilter", [&recording](benchmark::State& state) {
    stereoloc::BM_Pipeline(state, recording, stereoloc::LocalizerMethod::ParticleFilter, "");
  })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  for (const auto& [name, method, calibrate] :
       {std::tuple{"BM_PipelineLate10", stereoloc::LocalizerMethod::Window, ""},
        std::tuple{"BM_PipelineEkfSelfCalibratingLate10", stereoloc::LocalizerMethod::Ekf, "odometry,stereo"},
        std::tuple{"BM_PipelineParticleFilterLate10", stereoloc::LocalizerMethod::ParticleFilter, ""}}) {
    benchmark::RegisterBenchmark(name, [&recording, method = method, calibrate = std::string(calibrate)](
                                           benchmark::State& state) {
      stereoloc::BM_Pipeline(state, recording, method, calibrate, 10);
    })->Unit(benchmark::kMillisecond)->MinTime(2.0);
  }
  stereoloc::SummaryReporter reporter;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  return 0;
}
