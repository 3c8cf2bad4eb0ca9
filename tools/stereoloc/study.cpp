#include "tools/stereoloc/study.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "solvers/ekf.h"
#include "src/core/atomic_file.h"
#include "src/io/csv.h"
#include "src/core/error.h"
#include "src/eval/evaluation.h"
#include "src/core/gaussian.h"
#include "src/eval/plot.h"
#include "src/sim/simulator.h"
#include "src/core/yaml_util.h"
#include "tools/stereoloc/cli_common.h"
#include "src/pipeline/frontend_source.h"

namespace stereoloc::cli {
namespace fs = std::filesystem;
namespace {

// ---------------------------------------------------------------------------------------------
// Rows

// Statistics of the distance error over a step window, kept as sums so trials pool exactly.
struct WindowSums {
  long n = 0;
  double sum = 0, sum_sq = 0, min = 0, max = 0;
  void add(double v) {
    min = n == 0 ? v : std::min(min, v);
    max = n == 0 ? v : std::max(max, v);
    ++n;
    sum += v;
    sum_sq += v * v;
  }
  void merge(const WindowSums& o) {
    if (o.n == 0) return;
    min = n == 0 ? o.min : std::min(min, o.min);
    max = n == 0 ? o.max : std::max(max, o.max);
    n += o.n;
    sum += o.sum;
    sum_sq += o.sum_sq;
  }
  double mean() const { return n ? sum / n : 0; }
  double std() const { return n ? std::sqrt(std::max(0.0, sum_sq / n - mean() * mean())) : 0; }
};

// One row of trials.csv: one method on one trial.
struct TrialRow {
  std::string scenario, method;
  int trial = 0;
  long steps = 0;          // steps in the dataset
  long estimates = 0;      // estimates compared with the truth
  double sse_position = 0; // sum of squared position errors, mm^2
  double sse_theta = 0;    // rad^2
  WindowSums distance;     // all compared estimates, mm
  WindowSums window1;      // thesis window: first sighting + 1 .. 79
  WindowSums window2;      // thesis window: 80 .. 100
  long nees_count = 0;
  double nees_sum = 0;
  long nees_in_band = 0;   // per-estimate NEES inside the 95 % chi-square(3) band
  double ms_per_step = 0;
  long attempted = 0, fixed = 0;  // global fixes: steps with observations, steps with a fix
};

const char* kTrialHeader =
    "scenario,trial,method,steps,estimates,sse_position,sse_theta,"
    "dist_n,dist_sum,dist_sum_sq,dist_min,dist_max,"
    "w1_n,w1_sum,w1_sum_sq,w1_min,w1_max,w2_n,w2_sum,w2_sum_sq,w2_min,w2_max,"
    "nees_count,nees_sum,nees_in_band,ms_per_step,attempted,fixed";

std::string g17(double v) {
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

std::string toCsv(const TrialRow& r) {
  std::ostringstream o;
  o << r.scenario << ',' << r.trial << ',' << r.method << ',' << r.steps << ',' << r.estimates << ',' << g17(r.sse_position)
    << ',' << g17(r.sse_theta);
  for (const WindowSums* w : {&r.distance, &r.window1, &r.window2})
    o << ',' << w->n << ',' << g17(w->sum) << ',' << g17(w->sum_sq) << ',' << g17(w->min) << ',' << g17(w->max);
  o << ',' << r.nees_count << ',' << g17(r.nees_sum) << ',' << r.nees_in_band << ',' << g17(r.ms_per_step) << ','
    << r.attempted << ',' << r.fixed;
  return o.str();
}

// One row of steps.csv: the error of one estimate.
struct StepRow {
  std::string scenario, method;
  int trial = 0;
  long step = 0;
  double dx = 0, dy = 0, dtheta = 0;
  double sx = 0, sy = 0, stheta = 0;  // sqrt of the covariance diagonal
  std::optional<double> nees;
};

const char* kStepHeader = "scenario,trial,method,step,dx,dy,dtheta,sigma_x,sigma_y,sigma_theta,nees";

std::string toCsv(const StepRow& r) {
  std::ostringstream o;
  o << r.scenario << ',' << r.trial << ',' << r.method << ',' << r.step << ',' << g17(r.dx) << ',' << g17(r.dy) << ','
    << g17(r.dtheta) << ',' << g17(r.sx) << ',' << g17(r.sy) << ',' << g17(r.stheta) << ',' << (r.nees ? g17(*r.nees) : "");
  return o.str();
}

// ---------------------------------------------------------------------------------------------
// Config persistence (study.yaml), so that merge can check the shards belong together.

std::string joinList(const std::vector<std::string>& v) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? "," : "") + v[i];
  return s;
}

void writeStudyYaml(const StudyConfig& c, const std::string& path) {
  YamlWriter w;
  w.comment("stereoloc study configuration (written by `stereoloc study`; read by `study merge`)");
  w.put("scenarios", joinList(c.scenarios));
  w.put("methods", joinList(c.methods));
  w.put("trials", c.trials);
  w.put("seed", std::to_string(c.seed));
  w.put("frontend", c.frontend);
  w.put("frontend_landmarks", c.frontend_landmarks);
  w.put("image_noise", c.image_noise);
  w.put("shard_index", c.shard_index);
  w.put("shard_count", c.shard_count);
  w.put("particles", c.method_options.particles);
  w.put("window", c.method_options.window);
  w.put("init", toString(c.method_options.init));
  w.put("observation_model", toString(c.method_options.observation_model));
  w.writeAtomically(path);
}

StudyConfig readStudyYaml(const std::string& path) {
  YamlReader in(path);
  StudyConfig c;
  c.scenarios = splitCommaList(in.getString("scenarios"));
  c.methods = splitCommaList(in.getString("methods"));
  c.trials = in.getInt("trials");
  try {
    c.seed = std::stoull(in.getString("seed"));
  } catch (const std::exception&) {
    in.fail("seed", "not an unsigned integer");
  }
  c.frontend = in.getString("frontend");
  c.frontend_landmarks = in.getString("frontend_landmarks", "all");
  c.image_noise = in.getDouble("image_noise", StudyConfig().image_noise);
  c.shard_index = in.getInt("shard_index");
  c.shard_count = in.getInt("shard_count");
  c.method_options.particles = in.getInt("particles");
  c.method_options.window = in.getInt("window");
  c.method_options.init = initModeFromString(in.getString("init"));
  const std::string model = in.getString("observation_model", "range_bearing");  // before it was an option
  try {
    c.method_options.observation_model = observationModelFromString(model);
  } catch (const Error& e) {
    in.fail("observation_model", e.what());
  }
  return c;
}

// ---------------------------------------------------------------------------------------------
// One trial

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

struct TrialOutput {
  std::vector<TrialRow> rows;
  std::vector<StepRow> steps;
  ImageFrontendStats frontend;  // images: what rendering and the frontend did (timings: stderr only)
};

// Noise-free renders of the scenarios whose true path does not depend on the seed, by
// "scenario#thesis trial" (see CleanRenders in frontend_source.h).
using RenderCache = std::map<std::string, std::shared_ptr<const CleanRenders>>;

// A study trial is a Monte Carlo run; scenarios with several thesis trials cycle through them.
int thesisTrial(const std::string& scenario, int trial) { return trial % std::max(1, scenarioTrialCount(scenario)); }

std::string cacheKey(const std::string& scenario, int trial) {
  return scenario + "#" + std::to_string(thesisTrial(scenario, trial));
}

// Simulates one trial. With the image frontend, every step's pair is rendered from the true pose
// (or taken from `cache`) with sensor noise seeded from the trial seed and run through the
// frontend, so the trial's data do not depend on the thread count or on the cache.
// `render_threads` only splits the rendering of a pair.
Dataset simulateTrial(const StudyConfig& c, const std::string& scenario, int trial, const RenderCache* cache,
                      int render_threads = 1, ImageFrontendStats* stats = nullptr) {
  SimulationConfig sim;
  const uint64_t seed = trialSeed(c.seed, scenario, trial);
  if (c.frontend != "images") return simulate(scenario, thesisTrial(scenario, trial), sim, seed);
  SimulationTrace trace;
  Dataset d = simulate(scenario, thesisTrial(scenario, trial), sim, seed, &trace);
  ImageFrontendOptions fo;
  fo.landmarks = frontendLandmarksFromString(c.frontend_landmarks);
  const uint64_t noise_seed = splitmix64(seed ^ hashString("images"));
  ImageFrontendStats st;
  const auto hit = cache ? cache->find(cacheKey(scenario, trial)) : RenderCache::const_iterator();
  if (cache && hit != cache->end()) {
    st = observeCleanRenders(d, trace, *hit->second, c.image_noise, noise_seed, fo);
  } else {
    RenderOptions ro;
    ro.compute_truth = false;
    ro.threads = render_threads;
    const StereoRenderer renderer(d.map, d.rig, ro);
    st = observeRenderedImages(d, trace, renderer, c.image_noise, noise_seed, fo);
  }
  if (stats) *stats = st;
  return d;
}

// Renders once, noise-free, every scenario of the study whose true path and head pans are the
// same for any seed (all thesis scenarios; not random-walk).
RenderCache buildRenderCache(const StudyConfig& c, int threads) {
  RenderCache cache;
  if (c.frontend != "images") return cache;
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

long firstSightingStep(const Dataset& d) {
  for (const Step& s : d.steps)
    if (!s.observations.empty()) return s.step;
  return -1;
}

TrialOutput runTrial(const StudyConfig& c, const std::string& scenario, int trial, const RenderCache* cache) {
  TrialOutput out;
  const Dataset d = simulateTrial(c, scenario, trial, cache, 1, &out.frontend);
  const TruthByStep truth = truthByStep(d.steps, d.groundtruth);
  const long first = firstSightingStep(d);
  const double band_lo = chi2Quantile(0.025, 3), band_hi = chi2Quantile(0.975, 3);
  for (const std::string& method : c.methods) {
    const uint64_t method_seed = splitmix64(trialSeed(c.seed, scenario, trial) ^ hashString(method));
    const MethodRun run = runMethod(method, d, method_seed, c.method_options);
    TrialRow row;
    row.scenario = scenario;
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
        row.nees_in_band += (*e.nees >= band_lo && *e.nees <= band_hi) ? 1 : 0;
      }
    }
    for (const Estimate& est : run.estimates) {
      const auto it = truth.find(est.step);
      if (it == truth.end() || est.status == EstimateStatus::Uninitialised) continue;
      StepRow s;
      s.scenario = scenario;
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
      out.steps.push_back(s);
    }
    out.rows.push_back(row);
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// Summary

struct SummaryRow {
  std::string scenario, method;
  int trials = 0;
  long estimates = 0, steps = 0;
  double sse_position = 0, sse_theta = 0;
  WindowSums distance, window1, window2;
  long nees_count = 0, nees_in_band = 0;
  double nees_sum = 0, ms_sum = 0;
  long attempted = 0, fixed = 0;
  double rmse() const { return estimates ? std::sqrt(sse_position / estimates) : 0; }
  double theta_rmse() const { return estimates ? std::sqrt(sse_theta / estimates) : 0; }
  double meanNees() const { return nees_count ? nees_sum / nees_count : 0; }
  double inBand() const { return nees_count ? static_cast<double>(nees_in_band) / nees_count : 0; }
  double msPerStep() const { return trials ? ms_sum / trials : 0; }
  // Global fixes: steps with a fix over steps with observations; trackers: steps with an estimate.
  double fixRate() const {
    if (attempted > 0) return static_cast<double>(fixed) / attempted;
    return steps ? static_cast<double>(estimates) / steps : 0;
  }
};

std::vector<SummaryRow> summarise(const StudyConfig& c, const std::vector<TrialRow>& rows) {
  std::vector<SummaryRow> out;
  for (const std::string& sc : c.scenarios) {
    for (const std::string& m : c.methods) {
      SummaryRow s;
      s.scenario = sc;
      s.method = m;
      for (const TrialRow& r : rows) {
        if (r.scenario != sc || r.method != m) continue;
        ++s.trials;
        s.steps += r.steps;
        s.estimates += r.estimates;
        s.sse_position += r.sse_position;
        s.sse_theta += r.sse_theta;
        s.distance.merge(r.distance);
        s.window1.merge(r.window1);
        s.window2.merge(r.window2);
        s.nees_count += r.nees_count;
        s.nees_sum += r.nees_sum;
        s.nees_in_band += r.nees_in_band;
        s.ms_sum += r.ms_per_step;
        s.attempted += r.attempted;
        s.fixed += r.fixed;
      }
      out.push_back(s);
    }
  }
  return out;
}

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), f, v);
  return buf;
}

void writeSummaryCsv(const std::vector<SummaryRow>& rows, const std::string& path) {
  AtomicOutputFile out(path);
  out.stream() << "scenario,method,trials,position_rmse_mm,dist_mean_mm,dist_std_mm,dist_min_mm,dist_max_mm,"
                  "theta_rmse_rad,nees_mean,nees_in_band,ms_per_step,fix_rate\n";
  for (const SummaryRow& s : rows) {
    out.stream() << s.scenario << ',' << s.method << ',' << s.trials << ',' << g17(s.rmse()) << ',' << g17(s.distance.mean())
                 << ',' << g17(s.distance.std()) << ',' << g17(s.distance.min) << ',' << g17(s.distance.max) << ','
                 << g17(s.theta_rmse()) << ',' << g17(s.meanNees()) << ',' << g17(s.inBand()) << ',' << g17(s.msPerStep())
                 << ',' << g17(s.fixRate()) << '\n';
  }
  out.commit();
}

std::string summaryTable(const std::vector<SummaryRow>& rows, const std::string& scenario) {
  std::ostringstream o;
  o << "| method | trials | position RMSE [mm] | mean [mm] | std [mm] | min [mm] | max [mm] | theta RMSE [deg] | mean NEES | NEES in 95% band | ms/step | fix/estimate rate |\n";
  o << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const SummaryRow& s : rows) {
    if (s.scenario != scenario) continue;
    o << "| " << s.method << " | " << s.trials << " | " << fmt("%.1f", s.rmse()) << " | " << fmt("%.1f", s.distance.mean())
      << " | " << fmt("%.1f", s.distance.std()) << " | " << fmt("%.1f", s.distance.min) << " | " << fmt("%.1f", s.distance.max)
      << " | " << fmt("%.2f", rad2deg(s.theta_rmse())) << " | " << (s.nees_count ? fmt("%.2f", s.meanNees()) : "-") << " | "
      << (s.nees_count ? fmt("%.0f %%", 100 * s.inBand()) : "-") << " | " << fmt("%.3f", s.msPerStep()) << " | "
      << fmt("%.0f %%", 100 * s.fixRate()) << " |\n";
  }
  return o.str();
}

// The console summary printed at the end.
void printSummary(const std::vector<SummaryRow>& rows) {
  std::printf("%-8s %-12s %6s %10s %9s %9s %9s %9s %8s %6s\n", "scenario", "method", "trials", "RMSE[mm]", "mean[mm]",
              "std[mm]", "max[mm]", "th[deg]", "NEES", "ms/st");
  for (const SummaryRow& s : rows)
    std::printf("%-8s %-12s %6d %10.1f %9.1f %9.1f %9.1f %9.2f %8.2f %6.3f\n", s.scenario.c_str(), s.method.c_str(),
                s.trials, s.rmse(), s.distance.mean(), s.distance.std(), s.distance.max, rad2deg(s.theta_rmse()),
                s.meanNees(), s.msPerStep());
}

// ---------------------------------------------------------------------------------------------
// Thesis comparison (Tables 6.14-6.16) and figures

// A file of data/: $STEREOLOC_DATA_DIR, the source tree's data/, or the installed share/stereoloc.
std::string dataFilePath(const std::string& name) {
  std::vector<std::string> dirs;
  if (const char* env = std::getenv("STEREOLOC_DATA_DIR")) dirs.push_back(env);
  dirs.push_back(STEREOLOC_SOURCE_DATA_DIR);
  dirs.push_back(STEREOLOC_INSTALL_DATA_DIR);
  for (const std::string& d : dirs)
    if (fs::exists(d + "/" + name)) return d + "/" + name;
  return "";
}

struct ThesisRow {
  std::string init, method;
  int first = 0, last = 0;
  double mean = 0, std = 0, min = 0, max = 0;
};

std::vector<ThesisRow> thesisTrackingRows(const std::string& table_id) {
  std::vector<ThesisRow> out;
  const std::string path = dataFilePath("thesis_tables.yaml");
  if (path.empty()) return out;
  YamlReader in(path);
  const YamlNode tables = in.child("tables");
  for (size_t i = 0; i < tables.size(); ++i) {
    const YamlNode t = tables.at(i);
    if (t.getString("id") != table_id) continue;
    const YamlNode rows = t.child("rows");
    for (size_t j = 0; j < rows.size(); ++j) {
      const YamlNode r = rows.at(j);
      ThesisRow tr;
      tr.init = r.getString("init", "");
      tr.method = r.getString("method", "");
      tr.first = r.getInt("step_first", 0);
      tr.last = r.getInt("step_last", 0);
      const cv::FileNode v = r.node()["values"];
      if (v.size() >= 4) {
        tr.mean = static_cast<double>(v[0]);
        tr.std = static_cast<double>(v[1]);
        tr.min = static_cast<double>(v[2]);
        tr.max = static_cast<double>(v[3]);
      }
      out.push_back(tr);
    }
  }
  return out;
}

std::string lower(std::string s) {
  for (char& ch : s) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return s;
}

// The thesis's EKF/MCL with known/random/global start beside our methods.
std::string thesisComparison(const std::vector<SummaryRow>& rows, const std::string& scenario) {
  const std::map<std::string, std::string> table_of = {{"circle", "6.14"}, {"line", "6.15"}, {"spin", "6.16"}};
  const auto it = table_of.find(scenario);
  if (it == table_of.end()) return "";
  const std::vector<ThesisRow> thesis = thesisTrackingRows(it->second);
  std::ostringstream o;
  o << "Distance to the true position [mm] over the thesis's step windows (Table " << it->second
    << "): ours pooled over all trials, the thesis's beside.\n\n";
  o << "| start | method | steps | ours mean | ours std | ours min | ours max | thesis method | thesis mean | thesis std | thesis min | thesis max |\n";
  o << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const SummaryRow& s : rows) {
    if (s.scenario != scenario) continue;
    const auto [name, init] = parseMethodSpec(s.method, InitMode::Known);
    if (name == "fix1" || name == "fix2" || name == "deadreckoning") continue;
    const std::string init_name = toString(init);
    for (int w = 0; w < 2; ++w) {
      const WindowSums& ws = w == 0 ? s.window1 : s.window2;
      const std::string thesis_method = name == "pf" ? "mcl" : "ekf";
      const ThesisRow* match = nullptr;
      for (const ThesisRow& t : thesis)
        if (lower(t.init) == init_name && lower(t.method) == thesis_method && ((w == 0) == (t.last < 80))) match = &t;
      o << "| " << init_name << " | " << s.method << " | " << (w == 0 ? "first sighting+1..79" : "80..100") << " | "
        << (ws.n ? fmt("%.1f", ws.mean()) : "-") << " | " << (ws.n ? fmt("%.1f", ws.std()) : "-") << " | "
        << (ws.n ? fmt("%.1f", ws.min) : "-") << " | " << (ws.n ? fmt("%.1f", ws.max) : "-") << " | ";
      if (match)
        o << (thesis_method == "mcl" ? "MCL" : "EKF") << " | " << fmt("%.2f", match->mean) << " | " << fmt("%.2f", match->std)
          << " | " << fmt("%.2f", match->min) << " | " << fmt("%.2f", match->max) << " |\n";
      else
        o << "- | - | - | - | - |\n";
    }
  }
  return o.str() + "\n";
}

// Figures for one scenario; returns the markdown that embeds them.
std::string scenarioFigures(const StudyConfig& c, const std::string& scenario, const std::vector<StepRow>& steps,
                            const RenderCache* cache,
                            const std::string& dir) {
  std::ostringstream md;
  // Trajectories of trial 0 with 3-sigma ellipses (Figs. 6.26-6.28): re-simulated (deterministic).
  const Dataset d = simulateTrial(c, scenario, 0, cache, 2);  // the workers are done: both cores render
  Plot traj(scenario + ": trajectories of trial 0 with 3-sigma ellipses", "x [mm]", "y [mm]", 1000, 820);
  traj.setEqualAspect(true);
  drawField(traj, d.map);
  std::vector<double> tx, ty;
  for (const auto& g : d.groundtruth)
    if (g) tx.push_back(g->x), ty.push_back(g->y);
  traj.line(tx, ty, "truth", cv::Scalar(0, 0, 0), LineStyle::Solid, 2);
  size_t color = 0;
  std::map<std::string, MethodRun> runs;
  for (const std::string& m : c.methods) {
    const uint64_t method_seed = splitmix64(trialSeed(c.seed, scenario, 0) ^ hashString(m));
    runs[m] = runMethod(m, d, method_seed, c.method_options);
    const MethodRun& run = runs[m];
    std::vector<double> x, y;
    for (const Estimate& e : run.estimates)
      if (e.status != EstimateStatus::Uninitialised) x.push_back(e.pose.x), y.push_back(e.pose.y);
    const auto [name, init] = parseMethodSpec(m, InitMode::Known);
    const bool fixes = name == "fix1" || name == "fix2";
    const cv::Scalar col = plotColor(color++);
    traj.line(x, y, m, col, fixes ? LineStyle::Points : LineStyle::Solid, 1);
    for (size_t i = 0; i < run.estimates.size(); i += 10) {
      const Estimate& e = run.estimates[i];
      if (e.status != EstimateStatus::Uninitialised && e.covariance.topLeftCorner<2, 2>().trace() < 1e6)
        traj.ellipse(e.pose.translation(), e.covariance.topLeftCorner<2, 2>(), 3.0, col);
    }
  }
  traj.savePng(dir + "/" + scenario + "_trajectories.png");
  md << "![" << scenario << " trajectories](" << scenario << "_trajectories.png)\n\n";

  // Error against step with +-3 sigma for x, y, theta (Fig. 5.3), trial 0, first tracker.
  std::string tracker;
  for (const std::string& m : c.methods) {
    const auto [name, init] = parseMethodSpec(m, InitMode::Known);
    if (name == "ekf" || name == "window" || name == "batch" || name == "pf") {
      tracker = m;
      break;
    }
  }
  if (!tracker.empty()) {
    const char* comp[3] = {"x [mm]", "y [mm]", "theta [deg]"};
    for (int k = 0; k < 3; ++k) {
      std::vector<double> st, err, lo, hi;
      for (const StepRow& s : steps) {
        if (s.scenario != scenario || s.trial != 0 || s.method != tracker) continue;
        const double scale = k == 2 ? rad2deg(1.0) : 1.0;
        const double e = (k == 0 ? s.dx : k == 1 ? s.dy : s.dtheta) * scale;
        const double sg = (k == 0 ? s.sx : k == 1 ? s.sy : s.stheta) * scale;
        if (sg > 1e5) continue;
        st.push_back(s.step);
        err.push_back(e);
        lo.push_back(-3 * sg);
        hi.push_back(3 * sg);
      }
      if (st.empty()) continue;
      Plot p(scenario + ": " + tracker + " error in " + comp[k] + " (trial 0)", "step", std::string("error ") + comp[k], 900, 420);
      p.band(st, lo, hi, "+-3 sigma", plotColor(1));
      p.line(st, err, "error", plotColor(0));
      p.hline(0, "", cv::Scalar(80, 80, 80));
      const std::string name = scenario + "_" + tracker + "_error_" + std::string("xyt").substr(k, 1) + ".png";
      std::string safe = name;
      std::replace(safe.begin(), safe.end(), ':', '_');
      p.savePng(dir + "/" + safe);
      md << "![" << safe << "](" << safe << ")\n";
    }
    md << "\n";
  }

  // NEES per step, averaged over trials, with the chi-square band for that many trials.
  Plot np(scenario + ": mean NEES per step over trials (3 dof)", "step", "NEES", 900, 480);
  color = 0;
  int max_trials = 0;
  for (const std::string& m : c.methods) {
    std::map<long, std::pair<double, int>> acc;
    std::set<int> trials_seen;
    for (const StepRow& s : steps)
      if (s.scenario == scenario && s.method == m && s.nees) {
        acc[s.step].first += *s.nees;
        ++acc[s.step].second;
        trials_seen.insert(s.trial);
      }
    const cv::Scalar col = plotColor(color++);
    if (acc.empty()) continue;
    max_trials = std::max(max_trials, static_cast<int>(trials_seen.size()));
    std::vector<double> st, v;
    for (const auto& [step, sn] : acc) {
      st.push_back(step);
      v.push_back(std::min(sn.first / sn.second, 100.0));  // clipped for readability
    }
    np.line(st, v, m, col, LineStyle::Solid, 1);
  }
  if (max_trials > 0) {
    const NeesBand band = neesBand(3, max_trials);
    np.hline(band.lo, "95% band, " + std::to_string(max_trials) + " trials", cv::Scalar(0, 0, 200));
    np.hline(band.hi, "", cv::Scalar(0, 0, 200));
    np.savePng(dir + "/" + scenario + "_nees.png");
    md << "![" << scenario << " NEES](" << scenario << "_nees.png)\n\n";
  }

  // Kidnap: innovation and e^2 of the EKF (Figs. 5.4, 5.5).
  if (scenario == "kidnap") {
    EkfConfig ec;
    std::mt19937_64 rng(splitmix64(trialSeed(c.seed, scenario, 0)));
    std::optional<Pose2> truth = d.initial_pose ? d.initial_pose : d.groundtruth.front();
    ec.init = makeInitialBelief(InitMode::Known, truth, d.map, c.method_options.init_config, rng);
    Ekf ekf(d.map, d.odometry, ec);
    std::vector<EkfUpdateRecord> records;
    for (const Step& s : d.steps) {
      ekf.process(s);
      records.insert(records.end(), ekf.lastUpdates().begin(), ekf.lastUpdates().end());
    }
    std::vector<double> st, nu_r, nu_b, e2;
    for (const EkfUpdateRecord& r : records) {
      if (r.compass) continue;
      st.push_back(r.step);
      nu_r.push_back(r.innovation.x());
      nu_b.push_back(rad2deg(r.innovation.y()));
      e2.push_back(std::min(r.mahalanobis_squared, 200.0));
    }
    Plot pi("kidnap: EKF range innovation (trial 0)", "step", "innovation [mm]", 900, 420);
    pi.line(st, nu_r, "range innovation", plotColor(0), LineStyle::Points);
    pi.savePng(dir + "/kidnap_innovation.png");
    Plot pe("kidnap: EKF squared Mahalanobis distance e^2 (trial 0, clipped at 200)", "step", "e^2", 900, 420);
    pe.line(st, e2, "e^2", plotColor(3), LineStyle::Points);
    pe.hline(chi2Quantile(ec.gate.probability, 2), "gate (99 %, 2 dof)", cv::Scalar(0, 0, 200));
    pe.savePng(dir + "/kidnap_e2.png");
    md << "![kidnap innovation](kidnap_innovation.png)\n![kidnap e2](kidnap_e2.png)\n\n";
  }
  return md.str();
}

void writeReport(const StudyConfig& c, const std::vector<TrialRow>& rows, const std::vector<StepRow>& steps,
                 const RenderCache* cache,
                 const std::string& dir) {
  const std::vector<SummaryRow> summary = summarise(c, rows);
  writeSummaryCsv(summary, dir + "/summary.csv");
  std::ostringstream md;
  md << "# stereoloc accuracy study\n\n";
  md << "Scenarios: " << joinList(c.scenarios) << ". Methods: " << joinList(c.methods) << ". Trials per scenario: "
     << c.trials << ". Seed: " << c.seed << ". Observations: " << c.frontend;
  if (c.frontend == "images")
    md << " (every step's stereo pair rendered with " << fmt("%.1f", c.image_noise)
       << " grey levels of sensor noise and run through the vision frontend; landmarks: " << c.frontend_landmarks
       << ", unidentified corners associated by each estimator at its current belief; see README).\n\n";
  else
    md << " (simulated stereo pixels of the goal corners, 0.5 px noise; see README).\n\n";
  md << "Batch and window use the observations as " << toString(c.method_options.observation_model)
     << " (solvers/smoother_common.h: range_bearing is the thesis's form; pixel_columns compares u_l, u_r in the images; "
        "pixels also the rows); the EKF and PF use range-bearing.\n\n";
  md << "Position RMSE pools every compared estimate of every trial; mean/std/min/max are the thesis's statistics of the "
        "distance to the true position. NEES is e^T P^-1 e (3 dof): a consistent estimator has mean 3 and about 95 % "
        "of its values inside the two-sided 95 % chi-square band. ms/step is wall-clock on this machine.\n\n";
  for (const std::string& sc : c.scenarios) {
    md << "## " << sc << "\n\n" << summaryTable(summary, sc) << "\n" << thesisComparison(summary, sc);
    md << scenarioFigures(c, sc, steps, cache, dir);
  }
  // RMSE per method, per scenario.
  for (const std::string& sc : c.scenarios) {
    std::vector<std::string> names;
    std::vector<double> values;
    for (const SummaryRow& s : summary)
      if (s.scenario == sc && s.estimates > 0) names.push_back(s.method), values.push_back(s.rmse());
    Plot bars(sc + ": position RMSE per method", "method", "RMSE [mm]", 1000, 480);
    bars.bars(names, values, plotColor(0));
    bars.savePng(dir + "/" + sc + "_rmse.png");
  }
  md << "## Position RMSE per method\n\n";
  for (const std::string& sc : c.scenarios) md << "![" << sc << " RMSE](" << sc << "_rmse.png)\n";
  writeFileAtomically(dir + "/report.md", md.str());
  printSummary(summary);
}

// ---------------------------------------------------------------------------------------------
// Reading rows back (merge)

std::vector<TrialRow> readTrialRows(const std::string& path) {
  CsvReader in(path);
  in.expectHeader({splitCommaList(kTrialHeader)});
  std::vector<TrialRow> out;
  while (in.next()) {
    TrialRow r;
    r.scenario = in.field(0);
    r.trial = static_cast<int>(in.getLong(1));
    r.method = in.field(2);
    r.steps = in.getLong(3);
    r.estimates = in.getLong(4);
    r.sse_position = in.getDouble(5);
    r.sse_theta = in.getDouble(6);
    int k = 7;
    for (WindowSums* w : {&r.distance, &r.window1, &r.window2}) {
      w->n = in.getLong(k++);
      w->sum = in.getDouble(k++);
      w->sum_sq = in.getDouble(k++);
      w->min = in.getDouble(k++);
      w->max = in.getDouble(k++);
    }
    r.nees_count = in.getLong(k++);
    r.nees_sum = in.getDouble(k++);
    r.nees_in_band = in.getLong(k++);
    r.ms_per_step = in.getDouble(k++);
    r.attempted = in.getLong(k++);
    r.fixed = in.getLong(k++);
    out.push_back(r);
  }
  return out;
}

std::vector<StepRow> readStepRows(const std::string& path) {
  CsvReader in(path);
  in.expectHeader({splitCommaList(kStepHeader)});
  std::vector<StepRow> out;
  while (in.next()) {
    StepRow r;
    r.scenario = in.field(0);
    r.trial = static_cast<int>(in.getLong(1));
    r.method = in.field(2);
    r.step = in.getLong(3);
    r.dx = in.getDouble(4);
    r.dy = in.getDouble(5);
    r.dtheta = in.getDouble(6);
    r.sx = in.getDouble(7);
    r.sy = in.getDouble(8);
    r.stheta = in.getDouble(9);
    if (!in.field(10).empty()) r.nees = in.getDouble(10);
    out.push_back(r);
  }
  return out;
}

void prepareOutDir(const std::string& dir, bool force) {
  if (dir.empty()) throw UsageError("--out DIR is required");
  if (fs::exists(dir) && !fs::is_directory(dir)) throw Error(dir + ": exists and is not a directory");
  if (fs::exists(dir) && !fs::is_empty(dir)) {
    if (!force) throw UsageError(dir + ": directory is not empty (use --force to overwrite)");
    for (const auto& e : fs::directory_iterator(dir)) fs::remove_all(e.path());
  }
  fs::create_directories(dir);
}

// Sorts rows into the canonical order (scenario order of the config, trial, method order).
template <typename Row>
void canonicalOrder(const StudyConfig& c, std::vector<Row>& rows) {
  auto index = [](const std::vector<std::string>& v, const std::string& s) {
    return static_cast<int>(std::find(v.begin(), v.end(), s) - v.begin());
  };
  std::stable_sort(rows.begin(), rows.end(), [&](const Row& a, const Row& b) {
    const int sa = index(c.scenarios, a.scenario), sb = index(c.scenarios, b.scenario);
    if (sa != sb) return sa < sb;
    if (a.trial != b.trial) return a.trial < b.trial;
    return index(c.methods, a.method) < index(c.methods, b.method);
  });
}

}  // namespace

uint64_t trialSeed(uint64_t study_seed, const std::string& scenario, int trial) {
  return splitmix64(splitmix64(study_seed) ^ hashString(scenario) ^ splitmix64(static_cast<uint64_t>(trial) + 0x51ED));
}

void runStudy(const StudyConfig& c) {
  if (c.trials < 1) throw UsageError("--trials must be at least 1");
  if (c.shard_count < 1 || c.shard_index < 0 || c.shard_index >= c.shard_count)
    throw UsageError("--shard I/N needs 0 <= I < N");
  if (c.frontend != "pixels" && c.frontend != "images") throw UsageError("--frontend must be pixels or images");
  frontendLandmarksFromString(c.frontend_landmarks);
  if (!(c.image_noise >= 0) || !std::isfinite(c.image_noise)) throw UsageError("--image-noise must be >= 0");
  const std::vector<std::string> known = scenarioNames();
  for (const std::string& s : c.scenarios)
    if (std::find(known.begin(), known.end(), s) == known.end()) throw UsageError("unknown scenario '" + s + "'");
  for (const std::string& m : c.methods) parseMethodSpec(m, c.method_options.init);
  prepareOutDir(c.out_dir, c.force);
  writeStudyYaml(c, c.out_dir + "/study.yaml");

  struct Task {
    std::string scenario;
    int trial;
  };
  std::vector<Task> tasks;
  for (const std::string& s : c.scenarios)
    for (int t = c.shard_index; t < c.trials; t += c.shard_count) tasks.push_back({s, t});

  std::ofstream trials_csv(c.out_dir + "/trials.csv"), steps_csv(c.out_dir + "/steps.csv");
  if (!trials_csv || !steps_csv) throw Error(c.out_dir + ": cannot create trials.csv / steps.csv");
  trials_csv << kTrialHeader << "\n" << std::flush;
  steps_csv << kStepHeader << "\n" << std::flush;

  std::vector<std::optional<TrialOutput>> results(tasks.size());
  std::vector<std::string> errors(tasks.size());
  std::mutex mu;
  std::condition_variable cv;
  std::atomic<size_t> next{0};
  const int threads = c.threads > 0 ? c.threads : std::max(1u, std::thread::hardware_concurrency());
  const auto cache_start = std::chrono::steady_clock::now();
  const RenderCache cache = buildRenderCache(c, threads);
  if (!cache.empty())
    std::fprintf(stderr, "study: rendered the noise-free pairs of %zu scenario(s) in %.1f s; each trial adds its own sensor noise\n",
                 cache.size(), std::chrono::duration<double>(std::chrono::steady_clock::now() - cache_start).count());
  std::vector<std::thread> pool;
  for (int i = 0; i < threads; ++i) {
    pool.emplace_back([&] {
      for (size_t k = next++; k < tasks.size(); k = next++) {
        TrialOutput out;
        std::string err;
        try {
          out = runTrial(c, tasks[k].scenario, tasks[k].trial, &cache);
        } catch (const std::exception& e) {
          err = tasks[k].scenario + " trial " + std::to_string(tasks[k].trial) + ": " + e.what();
        }
        std::lock_guard<std::mutex> lock(mu);
        results[k] = std::move(out);
        errors[k] = err;
        cv.notify_all();
      }
    });
  }
  // Rows are written in task order as soon as they are complete: the files do not depend on the
  // thread count, and an interrupted study keeps every trial it finished.
  const bool bar = c.progress && ::isatty(2);
  const auto start = std::chrono::steady_clock::now();
  std::vector<TrialRow> all_rows;
  std::vector<StepRow> all_steps;
  ImageFrontendStats frontend_stats;
  std::string first_error;
  for (size_t k = 0; k < tasks.size(); ++k) {
    std::unique_lock<std::mutex> lock(mu);
    cv.wait(lock, [&] { return results[k].has_value(); });
    TrialOutput out = std::move(*results[k]);
    const std::string err = errors[k];
    lock.unlock();
    if (!err.empty()) {
      if (first_error.empty()) first_error = err;
      continue;
    }
    for (const TrialRow& r : out.rows) trials_csv << toCsv(r) << "\n";
    for (const StepRow& s : out.steps) steps_csv << toCsv(s) << "\n";
    trials_csv.flush();
    steps_csv.flush();
    all_rows.insert(all_rows.end(), out.rows.begin(), out.rows.end());
    all_steps.insert(all_steps.end(), out.steps.begin(), out.steps.end());
    frontend_stats.merge(out.frontend);
    if (bar) {
      const double el = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const double eta = el / (k + 1) * (tasks.size() - k - 1);
      const int width = 30, filled = static_cast<int>(width * (k + 1) / tasks.size());
      std::fprintf(stderr, "\r[%s%s] %zu/%zu trials, %.0f s elapsed, ETA %.0f s ", std::string(filled, '#').c_str(),
                   std::string(width - filled, '.').c_str(), k + 1, tasks.size(), el, eta);
    }
  }
  for (std::thread& t : pool) t.join();
  if (bar) std::fprintf(stderr, "\n");
  if (!first_error.empty()) throw Error(first_error);
  if (frontend_stats.pairs > 0) {
    const double n = static_cast<double>(frontend_stats.pairs);
    std::fprintf(stderr,
                 "image frontend: %ld stereo pairs, %.2f observations per pair (%.2f goal corners), rendering %.1f ms/pair, "
                 "frontend %.2f ms/pair; trials done in %.1f s\n",
                 frontend_stats.pairs, frontend_stats.observations / n, frontend_stats.identified / n,
                 frontend_stats.ms_render / n, frontend_stats.ms_frontend / n,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  writeReport(c, all_rows, all_steps, &cache, c.out_dir);
  std::printf("report: %s/report.md\n", c.out_dir.c_str());
}

void mergeStudies(const std::vector<std::string>& dirs, const std::string& out_dir, bool force) {
  if (dirs.empty()) throw UsageError("study merge needs at least one study directory");
  StudyConfig c = readStudyYaml(dirs.front() + "/study.yaml");
  std::vector<TrialRow> rows;
  std::vector<StepRow> steps;
  std::set<std::pair<std::string, int>> seen;
  for (const std::string& d : dirs) {
    const StudyConfig o = readStudyYaml(d + "/study.yaml");
    if (o.scenarios != c.scenarios || o.methods != c.methods || o.trials != c.trials || o.seed != c.seed ||
        o.frontend != c.frontend || o.frontend_landmarks != c.frontend_landmarks || o.image_noise != c.image_noise ||
        o.method_options.particles != c.method_options.particles ||
        o.method_options.window != c.method_options.window || o.method_options.init != c.method_options.init ||
        o.method_options.observation_model != c.method_options.observation_model)
      throw Error(d + "/study.yaml: configuration differs from " + dirs.front() + "/study.yaml");
    std::set<std::pair<std::string, int>> here;
    for (const TrialRow& r : readTrialRows(d + "/trials.csv")) {
      if (seen.count({r.scenario, r.trial}) && !here.count({r.scenario, r.trial}))
        throw Error(d + "/trials.csv: trial " + std::to_string(r.trial) + " of " + r.scenario + " appears in two studies");
      here.insert({r.scenario, r.trial});
      rows.push_back(r);
    }
    seen.insert(here.begin(), here.end());
    for (const StepRow& s : readStepRows(d + "/steps.csv")) steps.push_back(s);
  }
  canonicalOrder(c, rows);
  canonicalOrder(c, steps);
  c.shard_index = 0;
  c.shard_count = 1;
  prepareOutDir(out_dir, force);
  writeStudyYaml(c, out_dir + "/study.yaml");
  {
    AtomicOutputFile t(out_dir + "/trials.csv"), s(out_dir + "/steps.csv");
    t.stream() << kTrialHeader << "\n";
    for (const TrialRow& r : rows) t.stream() << toCsv(r) << "\n";
    s.stream() << kStepHeader << "\n";
    for (const StepRow& r : steps) s.stream() << toCsv(r) << "\n";
    t.commit();
    s.commit();
  }
  writeReport(c, rows, steps, nullptr, out_dir);
  std::printf("merged %zu trial rows from %zu studies; report: %s/report.md\n", rows.size(), dirs.size(), out_dir.c_str());
}

}  // namespace stereoloc::cli
