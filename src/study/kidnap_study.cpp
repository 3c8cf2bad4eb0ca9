#include "src/study/kidnap_study.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "solvers/ekf.h"
#include "src/core/atomic_file.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/simulator.h"
#include "src/study/text_format.h"

namespace stereoloc {
namespace {

struct SeedResult {
  uint64_t seed = 0;
  long kidnap_step = -1;
  long detected_step = -1;       // first step at or after the kidnap that is Lost or Reinitialised
  int detection_obs_steps = -1;  // observation steps from the kidnap to detection, inclusive
  long reinit_step = -1;         // first Reinitialised step at or after the kidnap
  long recovered_step = -1;      // first step at or after reinit_step with error < recover_mm
  double error_at_kidnap = 0.0;
  double final_error = 0.0;
  long false_alarms = 0;         // Lost/Reinitialised steps before the kidnap
};

struct RunTrace {
  std::vector<Estimate> estimates;
  std::vector<std::vector<EkfUpdateRecord>> updates;  // per step
};

RunTrace runEkf(const Dataset& d, const EkfConfig& config) {
  Ekf ekf(d.map, d.odometry, config);
  RunTrace t;
  for (const Step& s : d.steps) {
    t.estimates.push_back(ekf.process(s));
    t.updates.push_back(ekf.lastUpdates());
  }
  return t;
}

double positionError(const Estimate& e, const Pose2& truth) {
  return (e.pose.translation() - truth.translation()).norm();
}

void appendTrace(std::string& csv, const char* run, const Dataset& d, const RunTrace& t, double threshold) {
  for (size_t k = 0; k < t.estimates.size(); ++k) {
    const Estimate& e = t.estimates[k];
    if (!d.groundtruth[k]) continue;
    const Pose2& g = *d.groundtruth[k];
    const bool has = e.status != EstimateStatus::Uninitialised;
    double e2max = 0.0;
    int n = 0, accepted = 0;
    for (const EkfUpdateRecord& r : t.updates[k]) {
      if (r.compass) continue;
      ++n;
      accepted += r.accepted;
      if (std::isfinite(r.mahalanobis_squared)) e2max = std::max(e2max, r.mahalanobis_squared);
    }
    csv += formatText("%s,%ld,%.3f,%s,%.3f,%.3f,%.6f", run, e.step, e.t, toString(e.status).c_str(), g.x, g.y, g.theta);
    if (has) {
      csv += formatText(",%.3f,%.3f,%.6f,%.3f,%.3f,%.6f,%.3f,%.3f,%.6f", e.pose.x, e.pose.y, e.pose.theta, e.pose.x - g.x,
                 e.pose.y - g.y, angleDiff(e.pose.theta, g.theta), 3 * std::sqrt(std::max(0.0, e.covariance(0, 0))),
                 3 * std::sqrt(std::max(0.0, e.covariance(1, 1))), 3 * std::sqrt(std::max(0.0, e.covariance(2, 2))));
    } else {
      csv += ",,,,,,,,,";
    }
    csv += formatText(",%d,%d,%.6g,%.6g\n", n, accepted, e2max, threshold);
  }
}

void appendInnovations(std::string& csv, const char* run, const RunTrace& t, double threshold) {
  for (size_t k = 0; k < t.updates.size(); ++k)
    for (const EkfUpdateRecord& r : t.updates[k]) {
      if (r.compass) continue;
      if (!r.associated || !std::isfinite(r.mahalanobis_squared)) {
        csv += formatText("%s,%ld,%d,,,,,,%.6g,0\n", run, r.step, r.landmark_id, threshold);
        continue;
      }
      csv += formatText("%s,%ld,%d,%.4f,%.6f,%.4f,%.6f,%.6g,%.6g,%d\n", run, r.step, r.landmark_id, r.innovation.x(),
                 r.innovation.y(), std::sqrt(r.innovation_covariance(0, 0)), std::sqrt(r.innovation_covariance(1, 1)),
                 r.mahalanobis_squared, threshold, r.accepted ? 1 : 0);
    }
}

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

SimulationConfig kidnapSimulation(const KidnapStudyOptions& o) {
  if (o.seeds < 1) throw UsageError("--seeds must be at least 1");
  if (!(o.gate_probability > 0 && o.gate_probability < 1)) throw UsageError("--gate-probability must be in (0, 1)");
  if (o.lost_after < 1) throw UsageError("--lost-after must be at least 1");
  const uint64_t last_seed = o.first_seed + static_cast<uint64_t>(o.seeds) - 1;
  if (o.plot_seed != -1 && (o.plot_seed < 0 || static_cast<uint64_t>(o.plot_seed) < o.first_seed ||
                            static_cast<uint64_t>(o.plot_seed) > last_seed))
    throw UsageError("--plot-seed: " + std::to_string(o.plot_seed) + " is not one of the seeds " +
                     std::to_string(o.first_seed) + ".." + std::to_string(last_seed));
  SimulationConfig sim;
  try {
    sim.landmarks = landmarkSetFromString(o.landmarks);
  } catch (const Error&) {
    throw UsageError("--landmarks must be goal_corners or all, not '" + o.landmarks + "'");
  }
  sim.scenario.steps = o.steps;
  return sim;
}

// The first step the scenario carries the robot (the kidnap).
long kidnapStep(const Dataset& d, const SimulationTrace& trace) {
  for (size_t k = 0; k < trace.scenario.carried.size(); ++k)
    if (trace.scenario.carried[k]) return d.steps[k].step;
  throw Error("kidnap: the scenario has no kidnap (too few steps?)");
}

// Detection, re-initialisation and recovery of one run with the gate (SeedResult's fields).
void scoreRun(const Dataset& d, const RunTrace& t, double recover_mm, SeedResult& r) {
  const size_t kidnap_index = static_cast<size_t>(
      std::find_if(d.steps.begin(), d.steps.end(), [&](const Step& s) { return s.step == r.kidnap_step; }) -
      d.steps.begin());
  int obs_steps = 0;
  for (size_t k = 0; k < t.estimates.size(); ++k) {
    const Estimate& e = t.estimates[k];
    const bool alarm = e.status == EstimateStatus::Lost || e.status == EstimateStatus::Reinitialised;
    if (k < kidnap_index) {
      r.false_alarms += alarm && k > 0;
      continue;
    }
    if (!d.groundtruth[k]) continue;
    const double err = positionError(e, *d.groundtruth[k]);
    if (k == kidnap_index) r.error_at_kidnap = err;
    if (r.detected_step < 0) {
      obs_steps += d.steps[k].observations.empty() ? 0 : 1;
      if (alarm) {
        r.detected_step = e.step;
        r.detection_obs_steps = obs_steps;
      }
    }
    if (r.reinit_step < 0 && e.status == EstimateStatus::Reinitialised) r.reinit_step = e.step;
    if (r.reinit_step >= 0 && r.recovered_step < 0 && err < recover_mm) r.recovered_step = e.step;
    r.final_error = err;
  }
}

// The plot seed's traces (kidnap_trace.csv, kidnap_innovations.csv): the run without the gate
// (Figs. 5.3-5.5) beside the one with it (Fig. 5.6).
struct PlotTraces {
  std::string trace_csv =
      "run,step,t,status,x_true,y_true,theta_true,x,y,theta,err_x,err_y,err_theta,sigma3_x,sigma3_y,sigma3_theta,"
      "observations,accepted,e2_max,gate_threshold\n";
  std::string innovations_csv =
      "run,step,landmark_id,innov_range,innov_bearing,sigma_range,sigma_bearing,e2,gate_threshold,accepted\n";
  void add(const Dataset& d, const RunTrace& nogate, const RunTrace& recovery, double threshold) {
    appendTrace(trace_csv, "nogate", d, nogate, threshold);
    appendTrace(trace_csv, "recovery", d, recovery, threshold);
    appendInnovations(innovations_csv, "nogate", nogate, threshold);
    appendInnovations(innovations_csv, "recovery", recovery, threshold);
  }
};

// The figures over all seeds against the study's targets, and kidnap_seeds.csv.
struct KidnapSummary {
  int detected = 0, recovered = 0, reinit = 0;
  long false_alarms = 0;
  std::vector<double> errors_at_kidnap, delays, recover_steps, final_errors;
  std::string seeds_csv =
      "seed,kidnap_step,error_at_kidnap,detected_step,detection_obs_steps,reinit_step,recovered_step,"
      "steps_to_recover,final_error,false_alarms\n";
};

KidnapSummary summarise(const std::vector<SeedResult>& results, const KidnapStudyOptions& o) {
  KidnapSummary s;
  for (const SeedResult& r : results) {
    const bool det = r.detection_obs_steps >= 1 && r.detection_obs_steps <= o.detect_within;
    const long to_recover = r.recovered_step >= 0 ? r.recovered_step - r.reinit_step : -1;
    const bool rec = to_recover >= 0 && to_recover <= o.recover_within;
    s.detected += det;
    s.reinit += r.reinit_step >= 0;
    s.recovered += rec;
    s.false_alarms += r.false_alarms;
    s.errors_at_kidnap.push_back(r.error_at_kidnap);
    if (r.detection_obs_steps >= 0) s.delays.push_back(r.detection_obs_steps);
    if (to_recover >= 0) s.recover_steps.push_back(static_cast<double>(to_recover));
    s.final_errors.push_back(r.final_error);
    s.seeds_csv += formatText("%llu,%ld,%.3f,%ld,%d,%ld,%ld,%ld,%.3f,%ld\n", static_cast<unsigned long long>(r.seed),
                              r.kidnap_step, r.error_at_kidnap, r.detected_step, r.detection_obs_steps, r.reinit_step,
                              r.recovered_step, to_recover, r.final_error, r.false_alarms);
  }
  return s;
}

void printSummary(const KidnapStudyOptions& o, const KidnapSummary& s, double threshold) {
  const double n = static_cast<double>(o.seeds);
  std::fprintf(o.console, "kidnap study (thesis 5.1.3): %d seeds from %llu, scenario kidnap (%s), landmarks %s\n", o.seeds,
              static_cast<unsigned long long>(o.first_seed), "line A->B, carried back to A", o.landmarks.c_str());
  std::fprintf(o.console, "EKF, known start, gate %.0f %% (e2 <= %.2f, 2 dof), lost after %d consecutive gated observations, "
              "re-initialised by global fixes\n",
              100 * o.gate_probability, threshold, o.lost_after);
  std::fprintf(o.console, "  position error at the kidnap step:          median %.0f mm\n", median(s.errors_at_kidnap));
  std::fprintf(o.console, "  detected within %d observation steps:        %d / %d (%.1f %%)   target >= 95 %%   %s\n",
              o.detect_within, s.detected, o.seeds, 100 * s.detected / n, s.detected >= 0.95 * n ? "ok" : "MISSED");
  std::fprintf(o.console, "  detection delay (observation steps):        median %.1f, max %.0f\n", median(s.delays),
              s.delays.empty() ? std::nan("") : *std::max_element(s.delays.begin(), s.delays.end()));
  std::fprintf(o.console, "  re-initialised by a global fix:             %d / %d\n", s.reinit, o.seeds);
  std::fprintf(o.console, "  error < %.0f mm within %d steps of re-init:  %d / %d (%.1f %%)   target >= 95 %%   %s\n",
              o.recover_mm, o.recover_within, s.recovered, o.seeds, 100 * s.recovered / n,
              s.recovered >= 0.95 * n ? "ok" : "MISSED");
  std::fprintf(o.console, "  steps from re-init to error < %.0f mm:        median %.1f\n", o.recover_mm,
              median(s.recover_steps));
  std::fprintf(o.console, "  final position error:                       median %.1f mm\n", median(s.final_errors));
  std::fprintf(o.console, "  false alarms before the kidnap:             %ld steps over all seeds\n", s.false_alarms);
}

void writeOutputs(const KidnapStudyOptions& o, const KidnapSummary& s, const PlotTraces& plot) {
  std::error_code ec;
  std::filesystem::create_directories(o.out_dir, ec);
  if (ec) throw Error(o.out_dir + ": cannot create directory: " + ec.message());
  const std::filesystem::path dir(o.out_dir);
  writeFileAtomically((dir / "kidnap_seeds.csv").string(), s.seeds_csv);
  writeFileAtomically((dir / "kidnap_trace.csv").string(), plot.trace_csv);
  writeFileAtomically((dir / "kidnap_innovations.csv").string(), plot.innovations_csv);
  std::fprintf(o.console, "wrote %s/kidnap_seeds.csv, kidnap_trace.csv, kidnap_innovations.csv (plot seed)\n",
               o.out_dir.c_str());
}

}  // namespace

void runKidnapStudy(const KidnapStudyOptions& o) {
  const SimulationConfig sim = kidnapSimulation(o);
  const uint64_t plot_seed = o.plot_seed < 0 ? o.first_seed : static_cast<uint64_t>(o.plot_seed);
  EkfConfig recovery;
  recovery.gate.probability = o.gate_probability;
  recovery.gate.lost_after = o.lost_after;
  EkfConfig nogate = recovery;
  nogate.gate_enabled = false;
  nogate.reinitialise_when_lost = false;
  const double threshold = ValidationGate(recovery.gate).threshold();
  const InitConfig init_config;

  std::vector<SeedResult> results;
  PlotTraces plot;
  for (int i = 0; i < o.seeds; ++i) {
    SeedResult r;
    r.seed = o.first_seed + static_cast<uint64_t>(i);
    std::mt19937_64 rng(r.seed);  // one engine per trial: the simulation seed, then the start noise
    SimulationTrace trace;
    const Dataset d = simulate("kidnap", 0, sim, rng(), &trace);
    if (!d.initial_pose) throw Error("kidnap: the simulated dataset has no initial pose");
    r.kidnap_step = kidnapStep(d, trace);
    EkfConfig c = recovery;
    c.init = knownBeliefWithNoise(*d.initial_pose, init_config, rng);
    const RunTrace t = runEkf(d, c);
    scoreRun(d, t, o.recover_mm, r);
    results.push_back(r);
    if (!o.out_dir.empty() && r.seed == plot_seed) {
      EkfConfig c0 = nogate;
      c0.init = c.init;
      plot.add(d, runEkf(d, c0), t, threshold);
    }
  }
  const KidnapSummary summary = summarise(results, o);
  printSummary(o, summary, threshold);
  if (!o.out_dir.empty()) writeOutputs(o, summary, plot);
}

}  // namespace stereoloc
