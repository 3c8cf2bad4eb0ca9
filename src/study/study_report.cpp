#include "src/study/study_report.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <filesystem>
#include <map>
#include <set>
#include <sstream>

#include "solvers/ekf.h"
#include "src/core/angles.h"
#include "src/core/atomic_file.h"
#include "src/core/gaussian.h"
#include "src/core/yaml_util.h"
#include "src/eval/evaluation.h"
#include "src/eval/plot.h"
#include "src/pipeline/methods.h"
#include "src/study/data_files.h"

namespace stereoloc::study {
namespace {

// ---------------------------------------------------------------------------------------------
// Thesis comparison (Tables 6.14-6.16) and figures

struct ThesisRow {
  std::string init, method;
  int first = 0, last = 0;
  double mean = 0, std = 0, min = 0, max = 0;
};

std::vector<ThesisRow> thesisTrackingRows(const std::string& table_id) {
  std::vector<ThesisRow> out;
  const std::string path = findDataFile("thesis_tables.yaml");
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
std::string thesisComparison(const std::vector<SummaryRow>& rows, const std::string& scenario, const std::string& profile) {
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
    if (s.scenario != scenario || s.profile != profile) continue;
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

// The part of a figure's file name and title that names a profile: nothing for the ideal world
// (the files of a single-world study keep their names), else "_NAME" / " (NAME)" with NAME the
// profile or the stem of its file.
std::string profileStem(const std::string& profile) {
  std::string stem = std::filesystem::path(profile).stem().string();
  for (char& ch : stem)
    if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '-') ch = '_';
  return stem;
}
std::string profileFileTag(const std::string& profile) { return profile == "ideal" ? "" : "_" + profileStem(profile); }
std::string profileTitleTag(const std::string& profile) { return profile == "ideal" ? "" : " (" + profileStem(profile) + ")"; }

// Self-calibrating methods: the calibration estimate of trial 0 on the first n steps for growing
// n, with its 3-sigma band, against the world's true calibration. One figure per method.
std::string calibrationFigures(const StudyConfig& c, const std::string& scenario, const std::string& profile,
                               const Dataset& d, const SimulationTrace& trace, const std::string& dir) {
  std::ostringstream md;
  constexpr int K = kCalibrationParameterCount;
  const std::array<double, K> truth = trueCalibration(d, trace);
  std::array<std::string, K> names = {"wheel scale left", "wheel scale right", "wheel base [mm]",
                                      "tilt correction [deg]", "baseline scale", "focal scale", "exposure offset [ms]"};
  // Figures in the names' units: the tilt in degrees, the exposure offset in ms.
  std::array<double, K> scales = {1, 1, 1, rad2deg(1.0), 1, 1, 1e3};
  for (int k = 0; k < kFieldDimensionCount; ++k) {
    names[kFirstFieldCalibrationParameter + k] = std::string("field ") + kFieldDimensions[k].name + " [mm]";
    scales[kFirstFieldCalibrationParameter + k] = 1.0;
  }
  for (const std::string& m : c.methods) {
    if (!hasCalibrationSuffix(m) || d.steps.size() < 10) continue;
    std::vector<double> n_steps;
    std::array<std::vector<double>, K> est, lo, hi;
    std::array<bool, K> estimated{};
    const size_t N = d.steps.size();
    for (int k = 1; k <= 10; ++k) {
      const size_t n = std::max<size_t>(5, N * static_cast<size_t>(k) / 10);
      Dataset part = d;
      part.steps.resize(n);
      part.groundtruth.resize(std::min(part.groundtruth.size(), n));
      MethodRun run;
      try {
        run = runMethod(m, part, methodSeed(c, scenario, 0, m), methodOptionsFor(c, profile, d));
      } catch (const Error&) {
        continue;  // too few observations on a short prefix to fix the problem
      }
      if (!run.calibration) continue;
      const CalibrationValues cv = calibrationValues(*run.calibration, d.rig);
      n_steps.push_back(static_cast<double>(n));
      for (size_t i = 0; i < K; ++i) {
        const double sd = std::sqrt(std::max(0.0, cv.variance[i]));
        est[i].push_back(cv.value[i] * scales[i]);
        lo[i].push_back((cv.value[i] - 3 * sd) * scales[i]);
        hi[i].push_back((cv.value[i] + 3 * sd) * scales[i]);
        estimated[i] = estimated[i] || cv.estimated[i];
      }
    }
    if (n_steps.empty()) continue;
    std::string safe = scenario + profileFileTag(profile) + "_" + m + "_calibration";
    std::replace(safe.begin(), safe.end(), ':', '_');
    for (size_t i = 0; i < K; ++i) {
      if (!estimated[i]) continue;
      const double scale = scales[i];
      Plot p(scenario + profileTitleTag(profile) + ": " + m + " " + names[i] + " on the first n steps (trial 0)",
             "steps used", names[i], 900, 360);
      p.band(n_steps, lo[i], hi[i], "+-3 sigma", plotColor(1));
      p.line(n_steps, est[i], "estimate", plotColor(0), LineStyle::Solid, 2);
      p.hline(truth[i] * scale, "truth (the world's draw)", cv::Scalar(0, 0, 0));
      const std::string file = safe + "_" + std::to_string(i) + ".png";
      p.savePng(dir + "/" + file);
      md << "![" << file << "](" << file << ")\n";
    }
    md << "\n";
  }
  return md.str();
}

// Trajectories of trial 0 with 3-sigma ellipses (Figs. 6.26-6.28), every method run again on
// the re-simulated trial; returns the markdown that embeds the figure.
std::string trajectoryFigure(const StudyConfig& c, const std::string& scenario, const std::string& profile,
                             const Dataset& d, const std::string& dir) {
  std::ostringstream md;
  const std::string ttag = profileTitleTag(profile), base = scenario + profileFileTag(profile);
  Plot traj(scenario + ttag + ": trajectories of trial 0 with 3-sigma ellipses", "x [mm]", "y [mm]", 1000, 820);
  traj.setEqualAspect(true);
  drawField(traj, d.map);
  std::vector<double> tx, ty;
  for (const auto& g : d.groundtruth)
    if (g) tx.push_back(g->x), ty.push_back(g->y);
  traj.line(tx, ty, "truth", cv::Scalar(0, 0, 0), LineStyle::Solid, 2);
  size_t color = 0;
  std::map<std::string, MethodRun> runs;
  for (const std::string& m : c.methods) {
    runs[m] = runMethod(m, d, methodSeed(c, scenario, 0, m), methodOptionsFor(c, profile, d));
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
  traj.savePng(dir + "/" + base + "_trajectories.png");
  md << "![" << base << " trajectories](" << base << "_trajectories.png)\n\n";
  return md.str();
}

// Error against step with +-3 sigma for x, y, theta (Fig. 5.3), trial 0, the first tracker.
std::string errorFigures(const StudyConfig& c, const std::string& scenario, const std::string& profile,
                         const std::vector<StepRow>& steps, const std::string& dir) {
  std::ostringstream md;
  const std::string ttag = profileTitleTag(profile), base = scenario + profileFileTag(profile);
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
        if (s.scenario != scenario || s.profile != profile || s.trial != 0 || s.method != tracker) continue;
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
      Plot p(scenario + ttag + ": " + tracker + " error in " + comp[k] + " (trial 0)", "step", std::string("error ") + comp[k], 900, 420);
      p.band(st, lo, hi, "+-3 sigma", plotColor(1));
      p.line(st, err, "error", plotColor(0));
      p.hline(0, "", cv::Scalar(80, 80, 80));
      const std::string name = base + "_" + tracker + "_error_" + std::string("xyt").substr(k, 1) + ".png";
      std::string safe = name;
      std::replace(safe.begin(), safe.end(), ':', '_');
      p.savePng(dir + "/" + safe);
      md << "![" << safe << "](" << safe << ")\n";
    }
    md << "\n";
  }
  return md.str();
}

// NEES per step, averaged over trials, with the chi-square band for that many trials.
std::string neesFigure(const StudyConfig& c, const std::string& scenario, const std::string& profile,
                       const std::vector<StepRow>& steps, const std::string& dir) {
  std::ostringstream md;
  const std::string ttag = profileTitleTag(profile), base = scenario + profileFileTag(profile);
  Plot np(scenario + ttag + ": mean NEES per step over trials (3 dof)", "step", "NEES", 900, 480);
  size_t color = 0;
  int max_trials = 0;
  for (const std::string& m : c.methods) {
    std::map<long, std::pair<double, int>> acc;
    std::set<int> trials_seen;
    for (const StepRow& s : steps)
      if (s.scenario == scenario && s.profile == profile && s.method == m && s.nees) {
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
    np.savePng(dir + "/" + base + "_nees.png");
    md << "![" << base << " NEES](" << base << "_nees.png)\n\n";
  }
  return md.str();
}

// The kidnap's EKF innovation and e^2 (Figs. 5.4, 5.5), trial 0.
std::string kidnapFigures(const StudyConfig& c, const std::string& scenario, const Dataset& d, const std::string& dir) {
  std::ostringstream md;
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
  std::vector<double> st, nu_r, e2;
  for (const EkfUpdateRecord& r : records) {
    if (r.compass) continue;
    st.push_back(r.step);
    nu_r.push_back(r.innovation.x());
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
  return md.str();
}

// Figures for one scenario in one world; returns the markdown that embeds them.
std::string scenarioFigures(const StudyConfig& c, const std::string& scenario, const std::string& profile,
                            const std::vector<StepRow>& steps, const RenderCache* cache, const std::string& dir) {
  // Trial 0 re-simulated (deterministic); the workers are done, so both cores render.
  SimulationTrace trace;
  const Dataset d = simulateTrial(c, profile, scenario, 0, cache, 2, nullptr, &trace);
  std::string md = trajectoryFigure(c, scenario, profile, d, dir);
  md += errorFigures(c, scenario, profile, steps, dir);
  md += neesFigure(c, scenario, profile, steps, dir);
  md += calibrationFigures(c, scenario, profile, d, trace, dir);
  if (scenario == "kidnap" && profile == c.profiles.front()) md += kidnapFigures(c, scenario, d, dir);
  return md;
}

}  // namespace

std::vector<SummaryRow> writeReport(const StudyConfig& c, const std::vector<TrialRow>& rows, const std::vector<StepRow>& steps,
                                    const std::vector<CalibrationRow>& calibration, const RenderCache* cache,
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
  const bool several = c.profiles.size() > 1 || c.profiles.front() != "ideal";
  if (several)
    md << "Worlds (error profiles, src/sim/error_profile.h): " << joinList(c.profiles)
       << ". Every trial runs in each world with the same seeds. A non-ideal world hands the estimators the "
          "nominal rig and odometry and a calibration with a slightly wrong distortion estimate; its images are raw "
          "pairs of the true cameras, rectified by the frontend. RMSE columns of the side-by-side table: mean of the "
          "per-trial position RMSE +- the half width of its 95 % interval.\n\n";
  for (const std::string& sc : c.scenarios) {
    md << "## " << sc << "\n\n";
    if (several) md << profileComparisonTable(summary, sc, c.profiles) << "\n";
    md << summaryTable(summary, sc) << "\n" << thesisComparison(summary, sc, c.profiles.front());
    for (const std::string& pr : c.profiles) {
      if (several) md << "### " << sc << ", " << pr << "\n\n";
      md << scenarioFigures(c, sc, pr, steps, cache, dir);
    }
  }
  // RMSE per method, per scenario.
  for (const std::string& sc : c.scenarios) {
    std::vector<std::string> names;
    std::vector<double> values;
    for (const SummaryRow& s : summary)
      if (s.scenario == sc && s.estimates > 0)
        names.push_back(s.method + profileTitleTag(s.profile)), values.push_back(s.rmse());
    Plot bars(sc + ": position RMSE per method", "method", "RMSE [mm]", 1000, 480);
    bars.bars(names, values, plotColor(0));
    bars.savePng(dir + "/" + sc + "_rmse.png");
  }
  if (!calibration.empty())
    md << "## Self-calibration against the drawn truth\n\n"
       << "Every trial's final calibration estimate of the self-calibrating methods (solvers/self_calibration.h) "
          "against the value the world drew (errors.yaml of a simulated dataset; nominal in the ideal world). Other "
          "errors of a realistic world (focal length, principal point, distortion estimate, slip) are not parameters, "
          "so the tilt and baseline absorb part of them.\n\n"
       << calibrationTable(calibration) << "\n";
  md << "## Position RMSE per method\n\n";
  for (const std::string& sc : c.scenarios) md << "![" << sc << " RMSE](" << sc << "_rmse.png)\n";
  writeFileAtomically(dir + "/report.md", md.str());
  return summary;
}

}  // namespace stereoloc::study
