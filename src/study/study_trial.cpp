#include "src/study/study_trial.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "src/core/gaussian.h"
#include "src/eval/evaluation.h"
#include "src/pipeline/methods.h"
#include "src/pipeline/usage_error.h"
#include "src/core/error.h"
#include "src/sim/raw_render.h"
#include "src/sim/renderer.h"
#include "src/sim/scenario.h"
#include "src/sim/simulator.h"

namespace stereoloc::study {

uint64_t splitmix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

uint64_t hashString(const std::string& s) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a
  for (unsigned char ch : s) h = (h ^ ch) * 1099511628211ull;
  return h;
}

uint64_t methodSeed(const StudyConfig& c, const std::string& scenario, int trial, const std::string& method) {
  return splitmix64(trialSeed(c.seed, scenario, trial) ^ hashString(withoutCalibrationSuffix(method)));
}

int thesisTrial(const std::string& scenario, int trial) { return trial % std::max(1, scenarioTrialCount(scenario)); }

namespace {

std::string cacheKey(const std::string& scenario, int trial) {
  return scenario + "#" + std::to_string(thesisTrial(scenario, trial));
}

}  // namespace

Dataset simulateTrial(const StudyConfig& c, const std::string& profile, const std::string& scenario, int trial,
                      const RenderCache* cache, int render_threads, ImageFrontendStats* stats, SimulationTrace* trace_out) {
  SimulationConfig sim;
  sim.profile = ErrorProfile::named(profile);
  const bool ideal = sim.profile.isIdeal();
  const uint64_t seed = trialSeed(c.seed, scenario, trial);
  SimulationTrace trace;
  Dataset d = simulate(scenario, thesisTrial(scenario, trial), sim, seed, &trace);
  if (c.frontend == "images") {
    ImageFrontendOptions fo;
    fo.landmarks = frontendLandmarksFromString(c.frontend_landmarks);
    const uint64_t noise_seed = splitmix64(seed ^ hashString("images"));
    ImageFrontendStats st;
    const auto hit = cache && ideal ? cache->find(cacheKey(scenario, trial)) : RenderCache::const_iterator();
    if (cache && ideal && hit != cache->end()) {
      st = observeCleanRenders(d, trace, *hit->second, c.image_noise, noise_seed, fo);
    } else if (ideal) {
      RenderOptions ro;
      ro.compute_truth = false;
      ro.threads = render_threads;
      const StereoRenderer renderer(d.map, d.rig, ro);
      st = observeRenderedImages(d, trace, renderer, c.image_noise, noise_seed, fo);
    } else {
      st = observeRawImages(d, trace, c.image_noise, noise_seed, fo, render_threads);
    }
    if (stats) *stats = st;
  }
  if (trace_out) *trace_out = std::move(trace);
  return d;
}

ImageFrontendStats observeRawImages(Dataset& d, const SimulationTrace& trace, double image_noise, uint64_t noise_seed,
                                    const ImageFrontendOptions& options, int render_threads) {
  RenderOptions ro;
  ro.compute_truth = false;
  ro.threads = render_threads;
  ro.noise_sigma = image_noise;
  const RawPairRenderer raw(d.map, trace.nominal_rig, trace.profile, trace.errors, ro, trace.scenario.dt);
  // The dataset's rig carries the given calibration, so the frontend rectifies the raw pairs.
  ImageObserver observer(d.rig, d.map, options);
  double ms_render = 0;
  for (size_t k = 0; k < d.steps.size(); ++k) {
    const auto start = std::chrono::steady_clock::now();
    const StereoImages im = raw.render(trace.scenario, k, trace.obstacles[k], noise_seed + k);
    ms_render += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    d.steps[k].observations = observer.observe(im.left, im.right, d.steps[k].head_pan);
  }
  ImageFrontendStats st = observer.stats();
  st.ms_render = ms_render;
  return st;
}

// Renders once, noise-free, every scenario of the study whose true path and head pans are the
// same for any seed (all thesis scenarios; not random-walk).
RenderCache buildRenderCache(const StudyConfig& c, int threads) {
  RenderCache cache;
  // Only the ideal world is cached: another profile draws its true rig per trial.
  if (c.frontend != "images" || std::find(c.profiles.begin(), c.profiles.end(), "ideal") == c.profiles.end()) return cache;
  SimulationConfig sim;
  for (const std::string& sc : c.scenarios) {
    for (int t = c.shard_index; t < c.trials; t += c.shard_count) {
      const std::string key = cacheKey(sc, t);
      if (cache.count(key)) continue;
      SimulationTrace a, b;
      const Dataset da = simulate(sc, thesisTrial(sc, t), sim, trialSeed(c.seed, sc, t), &a);
      simulate(sc, thesisTrial(sc, t), sim, splitmix64(trialSeed(c.seed, sc, t) + 1), &b);
      bool fixed_path = a.scenario.poses.size() == b.scenario.poses.size() && a.scenario.head_pan == b.scenario.head_pan;
      for (size_t k = 0; fixed_path && k < a.scenario.poses.size(); ++k)
        fixed_path = a.scenario.poses[k].x == b.scenario.poses[k].x && a.scenario.poses[k].y == b.scenario.poses[k].y &&
                     a.scenario.poses[k].theta == b.scenario.poses[k].theta && a.obstacles[k].empty() && b.obstacles[k].empty();
      if (!fixed_path || a.scenario.poses.empty()) continue;
      RenderOptions clean;
      clean.compute_truth = false;
      clean.threads = 1;
      cache[key] = renderClean(a, StereoRenderer(da.map, da.rig, clean), threads);
    }
  }
  return cache;
}

namespace {

long firstSightingStep(const Dataset& d) {
  for (const Step& s : d.steps)
    if (!s.observations.empty()) return s.step;
  return -1;
}

}  // namespace

std::array<double, kCalibrationParameterCount> trueCalibration(const Dataset& d, const SimulationTrace& trace) {
  const DrawnErrors& e = trace.errors;
  std::array<double, kCalibrationParameterCount> truth{
      1 + e.wheel_radius_rel[0], 1 + e.wheel_radius_rel[1], d.odometry.wheel_base_mm * (1 + e.wheel_base_rel),
      e.tilt_rad, 1 + e.baseline_rel, e.focal_rel[0], e.exposure_offset_s};
  // A world without a field error has the map's dimensions: 0.
  for (size_t k = 0; k < e.field_dimension_mm.size() && k < static_cast<size_t>(kFieldDimensionCount); ++k)
    truth[kFirstFieldCalibrationParameter + k] = e.field_dimension_mm[k];
  return truth;
}

CalibrationValues calibrationValues(const CalibrationEstimate& ce, const StereoRig& rig) {
  constexpr int kExposure = stereo_pixel_calibration::kExposureOffsetEntry;
  const bool exposure = ce.image && ce.image_covariance(kExposure, kExposure) > 0;
  CalibrationValues c;
  c.value = {ce.wheels[0], ce.wheels[1], ce.wheels[2], ce.head[0], ce.head[1], ce.head[5],
             rig.params().exposure_offset_s + (ce.image ? ce.image_errors[kExposure] : 0.0)};
  c.variance = {ce.wheels_covariance(0, 0), ce.wheels_covariance(1, 1), ce.wheels_covariance(2, 2),
                ce.head_covariance(0, 0),   ce.head_covariance(1, 1),   ce.head_covariance(5, 5),
                exposure ? ce.image_covariance(kExposure, kExposure) : 0.0};
  c.estimated = {ce.odometry, ce.odometry, ce.odometry, ce.stereo, ce.stereo, ce.stereo, exposure};
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    c.value[kFirstFieldCalibrationParameter + k] = ce.field_dimensions_mm[k];
    c.variance[kFirstFieldCalibrationParameter + k] = ce.field_covariance(k, k);
    c.estimated[kFirstFieldCalibrationParameter + k] = ce.field;
  }
  return c;
}

MethodOptions methodOptionsFor(const StudyConfig& c, const std::string& profile, const Dataset& d) {
  MethodOptions o = c.method_options;
  applyErrorProfile(ErrorProfile::named(profile), d.rig.focal(), o);
  return o;
}

TrialOutput runTrial(const StudyConfig& c, const std::string& profile, const std::string& scenario, int trial,
                     const RenderCache* cache) {
  TrialOutput out;
  SimulationTrace trace;
  const Dataset d = simulateTrial(c, profile, scenario, trial, cache, 1, &out.frontend, &trace);
  const std::array<double, kCalibrationParameterCount> truth_calibration = trueCalibration(d, trace);
  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  const long first = firstSightingStep(d);
  const double band_lo = chi2Quantile(0.025, 3), band_hi = chi2Quantile(0.975, 3);
  const MethodOptions options = methodOptionsFor(c, profile, d);
  for (const std::string& method : c.methods) {
    MethodRun run;
    bool failed = false;
    try {
      run = runMethod(method, d, methodSeed(c, scenario, trial, method), options);
    } catch (const UsageError&) {
      throw;
    } catch (const Error& e) {
      // A method that cannot run on a trial's data (e.g. its solver finds no valid start in a
      // realistic world) is a result of the study: a row without estimates, marked failed.
      failed = true;
      out.failures.push_back(method + ": " + e.what());
    }
    if (run.calibration) {
      const CalibrationValues cv = calibrationValues(*run.calibration, d.rig);
      for (size_t i = 0; i < kCalibrationParameterCount; ++i) {
        if (!cv.estimated[i]) continue;
        CalibrationRow cr;
        cr.scenario = scenario;
        cr.profile = profile;
        cr.trial = trial;
        cr.method = method;
        cr.parameter = kCalibrationParameters[i];
        cr.truth = truth_calibration[i];
        cr.estimate = cv.value[i];
        cr.sigma = std::sqrt(std::max(0.0, cv.variance[i]));
        out.calibration.push_back(cr);
      }
    }
    TrialRow row;
    row.failed = failed ? 1 : 0;
    row.scenario = scenario;
    row.profile = profile;
    row.trial = trial;
    row.method = method;
    row.steps = static_cast<long>(d.steps.size());
    row.ms_per_step = run.ms_per_step;
    row.attempted = run.attempted_steps;
    row.fixed = run.fixed_steps;
    for (const PoseError& e : poseErrors(run.estimates, truth)) {
      ++row.estimates;
      row.sse_position += e.distance * e.distance;
      row.sse_theta += e.dtheta * e.dtheta;
      row.distance.add(e.distance);
      // Thesis Tables 6.14-6.16: steps after the first sighting up to 79, and 80 to 100.
      if (first >= 0 && e.step > first && e.step <= 79) row.window1.add(e.distance);
      if (e.step >= 80 && e.step <= 100) row.window2.add(e.distance);
      if (e.nees) {
        ++row.nees_count;
        row.nees_sum += *e.nees;
        row.nees_position_sum += e.position_nees.value_or(0.0);
        row.nees_heading_sum += e.heading_nees.value_or(0.0);
        row.nees_in_band += (*e.nees >= band_lo && *e.nees <= band_hi) ? 1 : 0;
      }
    }
    for (const Estimate& est : run.estimates) {
      const auto it = truth.find(est.step);
      if (it == truth.end() || est.status == EstimateStatus::Uninitialised) continue;
      StepRow s;
      s.scenario = scenario;
      s.profile = profile;
      s.trial = trial;
      s.method = method;
      s.step = est.step;
      const Eigen::Vector3d e = minus(est.pose, it->second);
      s.dx = e.x();
      s.dy = e.y();
      s.dtheta = e.z();
      const Eigen::Vector3d var = est.covariance.diagonal().cwiseMax(0.0);
      s.sx = std::sqrt(var.x());
      s.sy = std::sqrt(var.y());
      s.stheta = std::sqrt(var.z());
      s.nees = nees(est.pose, est.covariance, it->second);
      s.particles = est.particles;
      out.steps.push_back(s);
    }
    out.rows.push_back(row);
  }
  return out;
}

}  // namespace stereoloc::study
