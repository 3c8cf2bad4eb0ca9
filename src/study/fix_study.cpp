#include "src/study/fix_study.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <sstream>

#include "solvers/global_fix.h"
#include "src/core/atomic_file.h"
#include "src/eval/evaluation.h"
#include "src/core/gaussian.h"
#include "src/sim/raw_render.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"
#include "src/core/yaml_util.h"
#include "src/pipeline/usage_error.h"
#include "src/study/data_files.h"
#include "src/pipeline/frontend_source.h"
#include "src/sim/error_profile.h"
#include "solvers/self_calibrated_rig.h"
#include "src/study/study_trial.h"
#include "src/pipeline/methods.h"

namespace stereoloc {
namespace {

const std::vector<std::string> kCategories = {"rect", "spin-at", "rect-spin", "line-fixed", "line-turn"};
const std::vector<double> kCompassLevelsDeg = {0, 1, 2, 3, 3.5, 4, 5, 6, 7, 8, 9, 10};
const double kRangeBins[] = {600.0, 1000.0};  // mm: NEES by farthest landmark range <600, 600-1000, >1000
const double kMultiCompassDeg = 3.5;  // compass of the multi-landmark study (the thesis's "< 3 deg" standing still)


// The thesis's numbers of one table: rows keyed by name (and compass level for 6.9-6.13).
struct ThesisTable {
  bool found = false;
  std::map<std::string, std::array<double, 4>> rows;
  std::string note;
};

std::string rowKey(const std::string& name, double compass_deg) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%s@%.1f", name.c_str(), compass_deg);
  return buf;
}

std::string defaultTablesPath() {
  const std::string found = findDataFile("thesis_tables.yaml");
  if (!found.empty()) return found;
  return std::filesystem::exists("data/thesis_tables.yaml") ? "data/thesis_tables.yaml" : "";
}

ThesisTable loadThesisTable(const std::string& path, const std::string& id) {
  ThesisTable t;
  if (path.empty()) return t;
  YamlReader in(path);
  const YamlNode tables = in.child("tables");
  for (size_t i = 0; i < tables.size(); ++i) {
    const YamlNode tab = tables.at(i);
    if (tab.getString("id") != id) continue;
    t.found = true;
    t.note = tab.getString("note", "");
    const YamlNode rows = tab.child("rows");
    for (size_t j = 0; j < rows.size(); ++j) {
      const YamlNode r = rows.at(j);
      const cv::FileNode v = r.node()["values"];
      if (v.size() < 4) r.fail("values", "expected 4 numbers (Mean, Std, Min, Max)");
      std::array<double, 4> vals;
      for (int k = 0; k < 4; ++k) {
        vals[k] = static_cast<double>(v[k]);
        if (!std::isfinite(vals[k])) r.fail("values", "not a finite number");
      }
      t.rows[rowKey(r.getString("name"), r.getDouble("compass_noise_std_deg", 0.0))] = vals;
    }
  }
  return t;
}

struct Sample {
  double dx = 0, dy = 0, dtheta = 0;  // |error|: mm, mm, rad
  std::optional<double> nees3, nees2;
  double max_range = 0;     // mm, farthest landmark the fix used
  double separation = -1;   // rad, angle between the two landmarks seen from the robot (fix2; -1 otherwise)
  double nonlinearity = 0;       // GlobalFix::nonlinearity of the sigma-point fix (noisy measurements)
  double nonlinearity_true = 0;  // the same at the noise-free measurements (nonlinearityAtTruth)
  bool linear = false;           // nonlinearity_true <= linear_max_nonlinearity: the study's split
  bool linear_per_fix = false;   // nonlinearity <= linear_max_nonlinearity: the online rule
};

struct Bucket {
  int attempted = 0;
  std::vector<Sample> fixes;
  std::map<FixStatus, int> status_count;
};

uint64_t mixSeed(uint64_t seed, uint64_t a, uint64_t b, uint64_t c) {
  // splitmix64 over the tuple: independent, reproducible per-trial seeds.
  uint64_t z = seed;
  for (uint64_t v : {a, b, c}) {
    z += 0x9E3779B97F4A7C15ULL + v;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    z ^= z >> 31;
  }
  return z;
}

std::optional<double> neesOf(const Eigen::Vector3d& e, const Eigen::Matrix3d& P, int dof) {
  try {
    if (dof == 3) {
      const Eigen::Matrix3d S = sqrtInformationUpper<3>(P);
      return (S * e).squaredNorm();
    }
    const Eigen::Matrix2d S = sqrtInformationUpper<2>(Eigen::Matrix2d(P.topLeftCorner<2, 2>()));
    return (S * e.head<2>()).squaredNorm();
  } catch (const Error&) {
    return std::nullopt;
  }
}

// GlobalFix::nonlinearity of a fix computed with sigma points: from the fix's own (noisy)
// measurements, and from the noise-free measurements of the same landmarks at the true pose.
struct Nonlinearity {
  double per_fix = 0.0;
  double at_truth = 0.0;
};

// The same method with the same landmarks, observed without noise from the true pose (pixels
// projected by the rig, R at those pixels; for fix1 the compass reads the true heading with the
// step's declared sigma). Splitting the study by this value is unbiased; splitting by the per-fix
// value selects on the noise itself (fixes whose noise shortened the ranges look more linear and
// have smaller covariances), which biases each subset's NEES although the per-fix value is what a
// robot can use online.
double nonlinearityAtTruth(const GlobalFix& f, const Dataset& d, const Step& st, const Pose2& truth,
                           const GlobalFixOptions& sp) {
  std::vector<Observation> obs;
  for (int id : f.landmark_ids) {
    const Landmark* l = d.map.find(id);
    if (!l) return 1.0;
    const Eigen::Vector2d local = transformToLocal(truth, l->xy());
    const auto px = d.rig.project(Eigen::Vector3d(local.x(), local.y(), l->position.z()), st.head_pan);
    if (!px) return 1.0;
    try {
      obs.push_back(observationFromPixels(d.rig, id, l->type, *px, st.head_pan, d.rig.params().pixel_sigma));
    } catch (const GeometryError&) {
      return 1.0;
    }
  }
  if (obs.size() == 2)
    return fixFromTwoLandmarks(obs[0], obs[1], d.map.at(obs[0].landmark_id).xy(), d.map.at(obs[1].landmark_id).xy(), sp)
        .nonlinearity;
  if (obs.size() == 1 && st.compass)
    return fixFromOneLandmark(obs[0], d.map.at(obs[0].landmark_id).xy(), truth.theta, st.compass_sigma, sp).nonlinearity;
  return 1.0;
}

void record(Bucket& b, const GlobalFix& f, const Nonlinearity& nl, double max_nonlinearity, const Step& step,
            const Pose2& truth, std::ostream* csv, const std::string& prefix, const std::string& frontend) {
  ++b.attempted;
  ++b.status_count[f.status];
  if (!f.hasPose()) return;
  Sample s;
  const Eigen::Vector3d e = minus(f.pose, truth);
  s.dx = std::fabs(e(0));
  s.dy = std::fabs(e(1));
  s.dtheta = std::fabs(e(2));
  s.nees3 = neesOf(e, f.covariance, 3);
  s.nees2 = neesOf(e, f.covariance, 2);
  s.nonlinearity = nl.per_fix;
  s.nonlinearity_true = nl.at_truth;
  s.linear = nl.at_truth <= max_nonlinearity;
  s.linear_per_fix = nl.per_fix <= max_nonlinearity;
  for (const Observation& o : step.observations)
    for (int id : f.landmark_ids)
      if (o.landmark_id == id) s.max_range = std::max(s.max_range, o.range);
  if (f.landmark_ids.size() == 2) {
    // The circles meet at the inscribed angle between the landmarks: small angles are the
    // grazing, badly conditioned intersections (dp/dr ~ 1 / sin of this angle).
    const Observation *first = nullptr, *second = nullptr;
    for (const Observation& o : step.observations) {
      if (o.landmark_id == f.landmark_ids[0]) first = &o;
      if (o.landmark_id == f.landmark_ids[1]) second = &o;
    }
    if (first && second) s.separation = std::fabs(angleDiff(second->bearing, first->bearing));
  }
  b.fixes.push_back(s);
  if (csv) {
    char buf[512];
    std::snprintf(buf, sizeof(buf), "%s,%ld,%s,%.3f,%.3f,%.6f,%.3f,%.3f,%.6f,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g,%.4f,%.4f,%.1f,%.4f,%.4f,%s\n",
                  prefix.c_str(), step.step, toString(f.status).c_str(), truth.x, truth.y, truth.theta, f.pose.x,
                  f.pose.y, f.pose.theta, f.covariance(0, 0), f.covariance(0, 1), f.covariance(0, 2),
                  f.covariance(1, 1), f.covariance(1, 2), f.covariance(2, 2), s.nees3.value_or(NAN),
                  s.nees2.value_or(NAN), s.max_range, s.nonlinearity, s.nonlinearity_true, frontend.c_str());
    *csv << buf;
  }
}

std::string statsCells(const ErrorStats& s, double scale = 1.0) {
  char buf[128];
  std::snprintf(buf, sizeof(buf), "%8.2f %8.2f %8.3f %8.2f", s.mean * scale, s.std * scale, s.min * scale,
                s.max * scale);
  return buf;
}

std::string thesisCells(const ThesisTable& t, const std::string& key) {
  const auto it = t.rows.find(key);
  if (it == t.rows.end()) return "       -        -        -        -";
  char buf[128];
  std::snprintf(buf, sizeof(buf), "%8.2f %8.2f %8.3f %8.2f", it->second[0], it->second[1], it->second[2], it->second[3]);
  return buf;
}

ErrorStats statsOf(const std::vector<Sample>& v, double Sample::*field) {
  std::vector<double> x;
  x.reserve(v.size());
  for (const Sample& s : v) x.push_back(s.*field);
  return errorStats(x);
}

std::string fixRateLine(const Bucket& b) {
  std::ostringstream os;
  char buf[160];
  std::snprintf(buf, sizeof(buf), "fixes: %zu of %d attempted steps (%.1f %%);", b.fixes.size(), b.attempted,
                b.attempted ? 100.0 * b.fixes.size() / b.attempted : 0.0);
  os << buf;
  for (const auto& [status, count] : b.status_count) os << " " << toString(status) << " " << count;
  return os.str();
}

// One line of mean NEES: 3-dof and position-only (2-dof), each with the 95 % band of the mean of
// that many chi-square samples and whether it lies inside.
std::string neesMeanLine(const char* label, const std::vector<const Sample*>& v) {
  double s3 = 0, s2 = 0, ss3 = 0;
  int n3 = 0, n2 = 0, in3 = 0;
  const double q3 = chi2Quantile(0.95, 3);
  for (const Sample* s : v) {
    if (s->nees3) {
      s3 += *s->nees3;
      ss3 += *s->nees3 * *s->nees3;
      ++n3;
      in3 += *s->nees3 <= q3 ? 1 : 0;
    }
    if (s->nees2) {
      s2 += *s->nees2;
      ++n2;
    }
  }
  char buf[400];
  if (n3 == 0) {
    std::snprintf(buf, sizeof(buf), "  %-24s n=%5d  -\n", label, 0);
    return buf;
  }
  const NeesBand b3 = neesBand(3, n3), b2 = neesBand(2, std::max(n2, 1));
  const double m3 = s3 / n3, m2 = n2 ? s2 / n2 : NAN;
  // The band assumes chi-square samples (variance 2 dof = 6). The closed forms' errors are not
  // Gaussian and their 3-dof NEES has a heavier tail, so the sample variance is printed too: a
  // band of the mean is then about sqrt(var / 6) times wider than the one printed.
  const double var3 = std::max(0.0, ss3 / n3 - m3 * m3);
  auto verdict = [](double m, const NeesBand& b) { return m < b.lo ? "below" : (m > b.hi ? "ABOVE" : "inside"); };
  // The band of the mean from the sample variance (3 +- 1.96 sqrt(var / n)): where the
  // chi-square band says ABOVE or below but this one says inside, the excursion is within what
  // heavy-tailed errors give by chance (e.g. fix2, lines with fixed orientation, linear subset:
  // 3.37 with --seed 1 and 2.75-3.17 with seeds 2-10, n = 720 each).
  const NeesBand e3{3.0 - 1.96 * std::sqrt(var3 / n3), 3.0 + 1.96 * std::sqrt(var3 / n3)};
  std::snprintf(buf, sizeof(buf),
                "  %-24s n=%5d  3-dof %7.2f [%.2f, %.2f] %-6s  2-dof %7.2f [%.2f, %.2f] %-6s  %5.1f %% within "
                "chi2_0.95(3), 3-dof variance %.3g (chi-square 6): band from it [%.2f, %.2f] %s\n",
                label, n3, m3, b3.lo, b3.hi, verdict(m3, b3), m2, b2.lo, b2.hi, verdict(m2, b2), 100.0 * in3 / n3, var3,
                e3.lo, e3.hi, verdict(m3, e3));
  return buf;
}

// Mean NEES (3 dof and position-only 2 dof) with the 95 % band of such a mean: all fixes, split
// by the linearisation rule, and by farthest landmark range.
std::string neesLines(const std::vector<Sample>& v, double max_nonlinearity, bool split = true) {
  std::ostringstream os;
  std::vector<const Sample*> all, lin, nonlin, lin_fix, nonlin_fix;
  std::array<std::vector<const Sample*>, 3> by_range;
  for (const Sample& s : v) {
    all.push_back(&s);
    (s.linear ? lin : nonlin).push_back(&s);
    (s.linear_per_fix ? lin_fix : nonlin_fix).push_back(&s);
    by_range[s.max_range < kRangeBins[0] ? 0 : (s.max_range < kRangeBins[1] ? 1 : 2)].push_back(&s);
  }
  if (all.empty()) return "NEES: no fixes\n";
  char buf[200];
  if (split) {
    std::snprintf(buf, sizeof(buf),
                  "NEES: mean 3-dof and position 2-dof, [95%% band of the mean]; linearisation holds when the "
                  "nonlinearity <= %.3g at the true measurement (per fix: at the fix's own measurement)\n",
                  max_nonlinearity);
  } else {
    std::snprintf(buf, sizeof(buf), "NEES: mean 3-dof and position 2-dof, [95%% band of the mean]\n");
  }
  os << buf;
  os << neesMeanLine("all fixes", all);
  if (split) {
    os << neesMeanLine("linearisation holds", lin);
    os << neesMeanLine("linearisation does not", nonlin);
    os << neesMeanLine("holds per fix", lin_fix);
    os << neesMeanLine("does not per fix", nonlin_fix);
  }
  const char* names[] = {"range < 600 mm", "range 600-1000 mm", "range >= 1000 mm"};
  for (int i = 0; i < 3; ++i) os << neesMeanLine(names[i], by_range[i]);
  std::array<std::vector<const Sample*>, 3> by_sep;
  bool any_sep = false;
  for (const Sample& s : v) {
    if (s.separation < 0) continue;
    any_sep = true;
    by_sep[s.separation < deg2rad(20.0) ? 0 : (s.separation < deg2rad(40.0) ? 1 : 2)].push_back(&s);
  }
  if (any_sep) {
    const char* sep_names[] = {"separation < 20 deg", "separation 20-40 deg", "separation >= 40 deg"};
    for (int i = 0; i < 3; ++i) os << neesMeanLine(sep_names[i], by_sep[i]);
  }
  return os.str();
}

// Column groups: ours for each frontend, then the thesis.
std::string header(const char* first, const std::vector<std::string>& groups) {
  std::string top, sub;
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%-14s", "");
  top = buf;
  std::snprintf(buf, sizeof(buf), "%-14s", first);
  sub = buf;
  for (size_t g = 0; g <= groups.size(); ++g) {
    const std::string name = g < groups.size() ? groups[g] : "thesis";
    std::snprintf(buf, sizeof(buf), "%s%-35s", g ? " | " : " ", name.c_str());
    top += buf;
    std::snprintf(buf, sizeof(buf), "%s%8s %8s %8s %8s", g ? " | " : " ", "Mean", "Std", "Min", "Max");
    sub += buf;
  }
  while (!top.empty() && top.back() == ' ') top.pop_back();
  return top + "\n" + sub + "\n";
}

// A world's name in the column titles: ideal, realistic or the stem of a profile file.
std::string worldName(const std::string& profile) { return std::filesystem::path(profile).stem().string(); }

// Table 6.3 on the frontend's goal corners of one world, and their recall against the goal
// corners the simulator finds visible (in front of both cameras, inside both images, within the
// rig's range and disparity limits, line of sight free).
struct RangeStats {
  long visible = 0;    // visible goal corners (the simulator's observations)
  long detected = 0;   // of those, found by the frontend with the right id
  long unmatched = 0;  // frontend goal corners with no visible corner of that id within kMatchPx
  std::vector<double> abs_err, norm_err, signed_norm;  // mm; fractions of the true range
  std::vector<double> trial_bias;  // per trial (one calibration draw): mean signed normalised error
  std::vector<double> unbiased;    // |signed normalised error - its trial's bias|
};

// A detection is the visible corner of its id when its left column is within this of the
// simulator's (pixel noise, vibration and the calibration error move it by ~1-2 px).
constexpr double kMatchPx = 5.0;

// One trial's goal corners in one column: how many were matched, their mean signed normalised
// range error (the trial's bias) and mean absolute normalised error; NaN without a match.
struct TrialRange {
  long matched = 0;
  double bias = NAN, mean_abs = NAN;
};

// `true_map`: the field the world was built on (trueFieldMap), which the true ranges are to.
TrialRange addRanges(RangeStats& r, const Dataset& visible, const Dataset& images, const FieldMap& true_map) {
  const size_t first = r.signed_norm.size();
  for (size_t k = 0; k < images.steps.size() && k < visible.steps.size(); ++k) {
    if (k >= images.groundtruth.size() || !images.groundtruth[k]) continue;
    const Pose2& truth = *images.groundtruth[k];
    std::map<int, double> seen;  // id -> left column
    for (const Observation& o : visible.steps[k].observations)
      if (o.landmark_id >= 0 && o.type == LandmarkType::GoalCorner && o.pixels) seen[o.landmark_id] = o.pixels->u_left;
    r.visible += static_cast<long>(seen.size());
    std::set<int> found;
    for (const Observation& o : images.steps[k].observations) {
      if (o.landmark_id < 0 || o.type != LandmarkType::GoalCorner) continue;
      const auto it = seen.find(o.landmark_id);
      if (it == seen.end() || !o.pixels || std::fabs(o.pixels->u_left - it->second) > kMatchPx ||
          !found.insert(o.landmark_id).second) {
        ++r.unmatched;
        continue;
      }
      ++r.detected;
      const double range = (true_map.at(o.landmark_id).xy() - truth.translation()).norm();
      r.abs_err.push_back(std::fabs(o.range - range));
      r.norm_err.push_back(std::fabs(o.range - range) / range);
      r.signed_norm.push_back((o.range - range) / range);
    }
  }
  TrialRange t;
  t.matched = static_cast<long>(r.signed_norm.size() - first);
  if (t.matched == 0) return t;
  double bias = 0, mean_abs = 0;
  for (size_t i = first; i < r.signed_norm.size(); ++i) {
    bias += r.signed_norm[i];
    mean_abs += r.norm_err[i];
  }
  bias /= static_cast<double>(t.matched);
  r.trial_bias.push_back(bias);
  for (size_t i = first; i < r.signed_norm.size(); ++i) r.unbiased.push_back(std::fabs(r.signed_norm[i] - bias));
  t.bias = bias;
  t.mean_abs = mean_abs / static_cast<double>(t.matched);
  return t;
}

// range_trials.csv: per trial and image column of a non-ideal world, the goal corners' range bias
// beside the drawn errors that make a disparity offset or scale (true principal-point columns
// of both cameras in px, the right camera's relative rotation vector in rad, focal-length and
// baseline errors as fractions) and the self-calibration's estimate (empty for the given
// calibration or a failed batch; factors/stereo_pixel_calibration_factor.h) with the
// disparity offset's standard deviation.
const char* const kTrialRangeHeader =
    "category,trial,run,profile,column,goal_corners,range_bias_pct,mean_norm_error_pct,principal_u_left_px,"
    "principal_u_right_px,rotation_x_rad,rotation_y_rad,rotation_z_rad,focal_rel_left,focal_rel_right,baseline_rel,"
    "tilt_correction_rad,baseline_scale,disparity_offset_px,column_offset_px,focal_ratio,focal_scale,"
    "disparity_offset_sigma_px\n";

std::string trialRangeRow(const std::string& category, int trial, int run, const std::string& profile, bool calibrated,
                          const TrialRange& t, const DrawnErrors& e, const std::optional<CalibrationEstimate>& estimate) {
  char buf[800];
  std::snprintf(buf, sizeof(buf), "%s,%d,%d,%s,%s,%ld,", category.c_str(), trial, run, profile.c_str(),
                calibrated ? "self_calibrated" : "given", t.matched);
  std::string row = buf;
  if (t.matched > 0) {
    std::snprintf(buf, sizeof(buf), "%.4f,%.4f", 100.0 * t.bias, 100.0 * t.mean_abs);
    row += buf;
  } else {
    row += ",";
  }
  std::snprintf(buf, sizeof(buf), ",%.4f,%.4f,%.6g,%.6g,%.6g,%.6g,%.6g,%.6g", e.principal_px[0][0], e.principal_px[1][0],
                e.relative_rotation_rad[0], e.relative_rotation_rad[1], e.relative_rotation_rad[2], e.focal_rel[0],
                e.focal_rel[1], e.baseline_rel);
  row += buf;
  if (estimate && estimate->stereo) {
    const CalibrationEstimate::StereoVector& q = estimate->head;
    std::snprintf(buf, sizeof(buf), ",%.6g,%.6g,%.4f,%.4f,%.6g,%.6g,%.4f", q[0], q[1], q[2], q[3], q[4], q[5],
                  std::sqrt(std::max(0.0, estimate->head_covariance(2, 2))));
    row += buf;
  } else {
    row += ",,,,,,,";
  }
  return row + "\n";
}

// A non-ideal world's raw pairs of one trial, rendered once (as study::observeRawImages renders
// them: same options, noise seed noise_seed + step) and run through the frontend once per rig.
std::vector<StereoImages> renderRawPairs(const Dataset& d, const SimulationTrace& trace, double image_noise,
                                         uint64_t noise_seed, double* ms_render) {
  RenderOptions ro;
  ro.compute_truth = false;
  ro.threads = 1;
  ro.noise_sigma = image_noise;
  const RawPairRenderer raw(d.map, trace.nominal_rig, trace.profile, trace.errors, ro, trace.scenario.dt);
  std::vector<StereoImages> pairs;
  pairs.reserve(d.steps.size());
  const auto start = std::chrono::steady_clock::now();
  for (size_t k = 0; k < d.steps.size(); ++k) pairs.push_back(raw.render(trace.scenario, k, trace.obstacles[k], noise_seed + k));
  *ms_render = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return pairs;
}

// The frontend's observations of stored pairs with the dataset's rig (it rectifies them).
ImageFrontendStats observePairs(Dataset& d, const std::vector<StereoImages>& pairs, double ms_render,
                                const ImageFrontendOptions& options) {
  ImageObserver observer(d.rig, d.map, options);
  for (size_t k = 0; k < d.steps.size(); ++k)
    d.steps[k].observations = observer.observe(pairs[k].left, pairs[k].right, d.steps[k].head_pan);
  ImageFrontendStats st = observer.stats();
  st.ms_render = ms_render;
  return st;
}

// The self-calibrated column's rig for one trial: the batch smoother with `parts` run on the
// trial's own image observations (given calibration, known start), its estimate folded into
// the given rig. A batch that fails leaves the given rig (counted in `failures`). The Cauchy
// loss keeps misidentified goal corners and wrongly associated line features from dragging
// the calibration (seed 1, line-fixed, 50 poses: without it 3 of the 6 trials end with column
// offsets of 57-136 px).
struct SelfCalibrationSummary {
  int trials = 0, failures = 0;
  std::vector<double> disparity_offset, baseline_scale, tilt_deg;  // estimates per trial
};

// The fix scenarios' steps are independent poses (Scenario::independent_poses): rect, rect-spin,
// line-turn and the sideways line-fixed trial move the robot sideways with its heading fixed,
// which no differential drive does, so their odometry (the arc between the poses: forward by
// the chord) contradicts the true motion. The batch's odometry factors, whose lateral variance
// is 1e-2 mm^2, would force the poses onto that path and the stereo calibration would absorb
// the contradiction (seed 1, 100 poses: column offsets up to 14 px, focal scale up to 9 %,
// tilt corrections up to 2 deg, range biases of 12-18 % after calibration on rect). The
// self-calibration therefore links the steps only loosely: the control floor of the odometry
// model lets each step's position be off by about the longest step of the sequence (a sideways
// step of that length is within 1.4 sigma) and its heading by 0.05 rad, so the poses rest on the
// step's own observations and the calibration on all of them.
constexpr double kIndependentHeadingSigma = 0.05;  // rad

Dataset independentPoseLinks(const Dataset& images) {
  Dataset d = images;
  double longest = 1.0;  // mm
  for (const Step& st : d.steps) longest = std::max(longest, 0.5 * std::fabs(st.d_left + st.d_right));
  d.odometry.control_variance_floor =
      Eigen::Vector3d(longest * longest, longest * longest, kIndependentHeadingSigma * kIndependentHeadingSigma);
  return d;
}

StereoRig selfCalibratedRigFor(const Dataset& images, const ErrorProfile& profile, const SelfCalibrationConfig& parts,
                               uint64_t seed, SelfCalibrationSummary& summary,
                               std::optional<CalibrationEstimate>* estimate) {
  ++summary.trials;
  MethodOptions mo;
  mo.init = InitMode::Known;
  mo.calibration = parts;
  mo.loss = RobustLoss::Cauchy;
  // What the robot's user states (docs/realistic_world.md, "Noise model"), as study --profile
  // gives its calibrating methods: the profile's calibration spreads as the priors, its lens
  // estimate, vibration and slip as noise. With the wider defaults, the column offset, focal
  // scale and tilt drift to 5-9 sigma of the profile on the sequences whose odometry misleads
  // (independentPoseLinks) and the rig folded from them loses a third of the goal corners.
  applyErrorProfile(profile, images.rig.focal(), mo);
  try {
    const MethodRun run = runMethod("batch", independentPoseLinks(images), seed, mo);
    if (!run.calibration || !run.calibration->stereo) throw Error("no stereo calibration estimate");
    const CalibrationEstimate& e = *run.calibration;
    summary.disparity_offset.push_back(e.head[2]);
    summary.baseline_scale.push_back(e.head[1]);
    summary.tilt_deg.push_back(rad2deg(e.head[0]));
    *estimate = e;
    return selfCalibratedRig(images.rig, e);
  } catch (const Error&) {
    ++summary.failures;
    return images.rig;
  }
}

// A fix computed with options `o`, and its nonlinearity judged with sigma points (`sp`): on its
// own measurements and at the noise-free measurements from the truth.
GlobalFix fixWith(const Dataset& d, const Step& st, const Pose2& truth, const GlobalFixOptions& o,
                  const GlobalFixOptions& sp, Nonlinearity* nl) {
  const GlobalFix f = globalFix(st, d.map, o);
  nl->per_fix = o.covariance == FixCovariance::SigmaPoints ? f.nonlinearity : globalFix(st, d.map, sp).nonlinearity;
  nl->at_truth = f.hasPose() ? nonlinearityAtTruth(f, d, st, truth, sp) : 1.0;
  return f;
}

// One column of the tables: a world, a frontend and, for images in a non-ideal world, whether
// the frontend measures with the self-calibrated rig.
struct Group {
  size_t world;
  FrontendMode mode;
  bool calibrated = false;
};

// The fixes of one category, per column.
struct CategoryBuckets {
  std::vector<Bucket> fix2;
  std::vector<std::vector<Bucket>> fix1;        // per compass level (kCompassLevelsDeg)
  std::vector<std::array<Bucket, 2>> multi;     // [0] range-bearing, [1] pixels
  CategoryBuckets(size_t groups, size_t levels) : fix2(groups), fix1(groups, std::vector<Bucket>(levels)), multi(groups) {}
};

// The study: the options checked and the worlds, columns and outputs set up at construction;
// run() simulates every category and prints its tables in the thesis's order.
class FixStudy {
 public:
  explicit FixStudy(const FixStudyOptions& options);
  void run();

 private:
  void setUpWorlds();
  void setUpMethods();
  void setUpColumns();
  void writeHeader();
  CategoryBuckets runCategory(const std::string& cat, size_t ci, int trials);
  // Every fix of one step of column `mi` (`z`: the step's standard normal compass draw).
  void fixStep(const Dataset& d, size_t k, double z, const std::string& cat, int trial, int run, size_t mi,
               const std::string& mode_name, CategoryBuckets* b);
  void reportFix2(const std::string& cat, size_t ci, int trials, const CategoryBuckets& b);
  void reportMulti(const std::string& cat, const CategoryBuckets& b);
  void reportFix1(const std::string& cat, size_t ci, int trials, const CategoryBuckets& b);
  void reportRanges();
  void finish();

  const FixStudyOptions& a_;
  std::vector<std::string> cats_;
  bool do2_ = false, do1_ = false, doM_ = false;
  std::string tables_path_;
  SimulationConfig cfg_;
  std::vector<SimulationConfig> world_cfg_;
  bool ideal_only_ = false;  // the ideal world alone prints exactly the thesis's tables
  FixCovariance model_ = FixCovariance::SigmaPoints;
  GlobalFixOptions opt2_, opt1_, optM_rb_, sp2_, sp1_;
  double max_nl_ = 0;
  std::unique_ptr<AtomicOutputFile> csv_, trial_csv_;
  std::vector<FrontendMode> modes_;
  SelfCalibrationConfig self_calibration_;
  std::vector<Group> gs_;
  std::vector<std::string> groups_;  // the columns' names
  std::vector<SelfCalibrationSummary> calibration_summary_;
  std::vector<RangeStats> ranges_;
  bool images_ = false;
  ImageFrontendOptions fo_;
  std::unique_ptr<StereoRenderer> renderer_;
  ImageFrontendStats fstats_;
  std::ostringstream report_;
};

FixStudy::FixStudy(const FixStudyOptions& options) : a_(options) {
  if (a_.category == "all") {
    cats_ = kCategories;
  } else {
    cats_ = {a_.category};
  }
  do2_ = a_.method == "both" || a_.method == "all" || a_.method == "fix2";
  do1_ = a_.method == "both" || a_.method == "all" || a_.method == "fix1";
  doM_ = a_.method == "all" || a_.method == "multi";
  tables_path_ = a_.tables.empty() ? defaultTablesPath() : a_.tables;
  setUpWorlds();
  setUpMethods();
  if (!a_.out.empty()) {
    std::filesystem::create_directories(a_.out);
    csv_ = std::make_unique<AtomicOutputFile>(a_.out + "/fixes.csv");
    csv_->stream() << "category,trial,run,method,compass_sigma_deg,step,status,true_x,true_y,true_theta,x,y,theta,"
                      "cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta,nees3,nees2,max_range,nonlinearity,nonlinearity_true,frontend"
                   << (ideal_only_ ? "" : ",profile") << "\n";
  }
  setUpColumns();
  writeHeader();
}

void FixStudy::setUpWorlds() {
  cfg_.pixel_sigma = a_.pixel_sigma;
  cfg_.quantise = a_.quantise;
  cfg_.compass = false;  // fix1's compass is drawn here, per noise level
  cfg_.scenario.steps = a_.steps;
  if (a_.steps < 0) throw UsageError("--steps must be >= 0");
  cfg_.validate();
  if (a_.profiles.empty()) throw UsageError("--profile is empty");
  for (const std::string& p : a_.profiles) {
    if (std::count(a_.profiles.begin(), a_.profiles.end(), p) > 1) throw UsageError("--profile: '" + p + "' appears twice");
    world_cfg_.push_back(cfg_);
    try {
      world_cfg_.back().profile = ErrorProfile::named(p);
    } catch (const Error& e) {
      throw UsageError(std::string("--profile: ") + e.what());
    }
  }
  ideal_only_ = a_.profiles.size() == 1 && a_.profiles.front() == "ideal";
}

void FixStudy::setUpMethods() {
  model_ = a_.first_order ? FixCovariance::FirstOrder : fixCovarianceFromString(a_.covariance);
  opt2_.covariance = model_;
  opt2_.allow_one_landmark = false;
  opt2_.allow_multi = false;
  opt1_.covariance = model_;
  opt1_.allow_two_landmarks = false;
  opt1_.allow_multi = false;
  // The least-squares fix (n >= 2 landmarks + the compass at kMultiCompassDeg), with stereo
  // observations as range-bearing (R at the measured pixels) and as pixels (rig set).
  optM_rb_.allow_one_landmark = optM_rb_.allow_two_landmarks = false;
  // The linearisation rule is judged with sigma points for every covariance model.
  sp2_ = opt2_;
  sp1_ = opt1_;
  sp2_.covariance = sp1_.covariance = FixCovariance::SigmaPoints;
  max_nl_ = opt2_.linear_max_nonlinearity;
}

// One column per (world, frontend); a non-ideal world with images also gets the self-calibrated
// column (calibrated = true).
void FixStudy::setUpColumns() {
  if (a_.frontend == "both") {
    modes_ = {FrontendMode::Pixels, FrontendMode::Images};
  } else {
    modes_ = {frontendModeFromString(a_.frontend)};
  }
  try {
    self_calibration_ = SelfCalibrationConfig::parse(a_.calibrate);
  } catch (const Error& e) {
    throw UsageError(std::string("--calibrate: ") + e.what());
  }
  if (self_calibration_.odometry && !self_calibration_.stereo)
    throw UsageError("--calibrate: the self-calibrated column needs the stereo part (stereo or odometry,stereo)");
  for (size_t w = 0; w < a_.profiles.size(); ++w)
    for (FrontendMode m : modes_) {
      gs_.push_back({w, m, false});
      groups_.push_back("ours (" + toString(m) + (ideal_only_ ? "" : ", " + worldName(a_.profiles[w])) + ")");
      if (m == FrontendMode::Images && self_calibration_.stereo && !world_cfg_[w].profile.isIdeal()) {
        gs_.push_back({w, m, true});
        groups_.push_back("ours (" + toString(m) + ", " + worldName(a_.profiles[w]) + ", self-cal.)");
      }
    }
  calibration_summary_.resize(a_.profiles.size());
  ranges_.resize(gs_.size());
  images_ = std::find(modes_.begin(), modes_.end(), FrontendMode::Images) != modes_.end();
  if (!a_.out.empty() && images_ && !ideal_only_) {
    trial_csv_ = std::make_unique<AtomicOutputFile>(a_.out + "/range_trials.csv");
    trial_csv_->stream() << kTrialRangeHeader;
  }
  fo_.landmarks = frontendLandmarksFromString(a_.frontend_landmarks);
  RenderOptions ro;
  ro.compute_truth = false;  // sensor noise: addSensorNoise in observeRenderedImages
  if (images_) renderer_ = std::make_unique<StereoRenderer>(cfg_.map, StereoRig(cfg_.rig), ro);
}

void FixStudy::writeHeader() {
  char buf[600];
  std::snprintf(buf, sizeof(buf),
                "stereoloc fixstudy: thesis sections 6.3 (two landmarks) and 6.4 (one landmark + compass)\n"
                "simulator: goal-corner landmarks, pixel sigma %.3f px%s, %d run(s) per trial, seed %llu; "
                "covariance: %s\n"
                "errors are |estimate - truth| over all fixes of all trials; thesis numbers from %s\n",
                a_.pixel_sigma, a_.quantise ? " + quantisation" : "", a_.runs, static_cast<unsigned long long>(a_.seed),
                toString(model_).c_str(), tables_path_.empty() ? "(not found)" : tables_path_.c_str());
  report_ << buf;
  if (images_) {
    std::snprintf(buf, sizeof(buf),
                  "images: every step's stereo pair rendered from the true pose (%.1f grey levels of sensor noise) "
                  "and run through the vision frontend; fixes use its goal corners\n",
                  a_.image_noise);
    report_ << buf;
  }
  if (!ideal_only_) {
    std::string list;
    for (const std::string& p : a_.profiles) list += (list.empty() ? "" : ", ") + p;
    report_ << "worlds: " << list
            << " (src/sim/error_profile.h), same trial seeds; in a non-ideal world the true rig is drawn per trial, "
               "the simulated pixels are true raw projections undistorted with the given calibration and the images "
               "raw pairs of the true cameras (distortion, blur, vibration) that the frontend rectifies with the given "
               "calibration\n";
  }
  if (std::any_of(gs_.begin(), gs_.end(), [](const Group& g) { return g.calibrated; }))
    report_ << "self-cal.: the same raw pairs through the frontend with a self-calibrated rig: per trial, the batch "
               "smoother with --calibrate "
            << a_.calibrate
            << " --loss cauchy (known start, the world's profile as priors and noise model, the independent poses "
               "linked only loosely) on that trial's image observations with the given calibration, its estimate "
               "folded into the rig (solvers/self_calibrated_rig.h); the column without it uses the given calibration\n";
  report_ << "\n";
}

void FixStudy::run() {
  for (const std::string& cat : cats_) {
    const size_t ci = static_cast<size_t>(std::find(kCategories.begin(), kCategories.end(), cat) - kCategories.begin());
    const int trials = scenarioTrialCount(cat);
    const CategoryBuckets b = runCategory(cat, ci, trials);
    if (do2_) reportFix2(cat, ci, trials, b);
    if (doM_) reportMulti(cat, b);
    if (do1_) reportFix1(cat, ci, trials, b);
  }
  if (images_ && !ideal_only_) reportRanges();
  finish();
}

CategoryBuckets FixStudy::runCategory(const std::string& cat, size_t ci, int trials) {
  CategoryBuckets b(gs_.size(), kCompassLevelsDeg.size());
  for (int trial = 0; trial < trials; ++trial) {
    for (int run = 0; run < a_.runs; ++run) {
      const uint64_t s = mixSeed(a_.seed, ci, static_cast<uint64_t>(trial), static_cast<uint64_t>(run));
      for (size_t w = 0; w < a_.profiles.size(); ++w) {
        SimulationTrace trace;
        const Dataset sim = simulate(cat, trial, world_cfg_[w], s, images_ ? &trace : nullptr);
        const bool ideal_world = world_cfg_[w].profile.isIdeal();
        Dataset given_images;  // this world's image observations with the given calibration
        std::vector<StereoImages> raw_pairs;  // a non-ideal world's raw pairs, rendered once
        double ms_raw_render = 0;
        for (size_t mi = 0; mi < gs_.size(); ++mi) {
          if (gs_[mi].world != w) continue;
          const std::string mode_name = toString(gs_[mi].mode) + (gs_[mi].calibrated ? "_self_calibrated" : "") +
                                        (ideal_only_ ? "" : "," + a_.profiles[w]);
          Dataset image_data;
          if (gs_[mi].mode == FrontendMode::Images) {
            image_data = sim;
            // The same raw pairs (same noise) for the given and the self-calibrated rig.
            const uint64_t noise_seed = mixSeed(s, 0x1A6E5, 0, 0);
            std::optional<CalibrationEstimate> estimate;
            if (gs_[mi].calibrated)
              image_data.rig = selfCalibratedRigFor(given_images, world_cfg_[w].profile, self_calibration_,
                                                    mixSeed(s, 0xCA1B, 0, 0), calibration_summary_[w], &estimate);
            if (ideal_world) {
              fstats_.merge(observeRenderedImages(image_data, trace, *renderer_, a_.image_noise, noise_seed, fo_));
            } else {
              const bool first_use = raw_pairs.empty();
              if (first_use) raw_pairs = renderRawPairs(image_data, trace, a_.image_noise, noise_seed, &ms_raw_render);
              fstats_.merge(observePairs(image_data, raw_pairs, first_use ? ms_raw_render : 0.0, fo_));
            }
            if (!ideal_only_) {
              const TrialRange tr = addRanges(ranges_[mi], sim, image_data, trueFieldMap(sim.map, trace.errors));
              if (trial_csv_ && !ideal_world)
                trial_csv_->stream() << trialRangeRow(cat, trial, run, a_.profiles[w], gs_[mi].calibrated, tr,
                                                      trace.errors, estimate);
            }
            if (!gs_[mi].calibrated) given_images = image_data;
          }
          const Dataset& d = gs_[mi].mode == FrontendMode::Images ? image_data : sim;
          // Common random numbers: the same compass draws for both frontends.
          std::mt19937_64 compass_rng(mixSeed(s, 0xC0FFEE, 0, 0));
          std::normal_distribution<double> N(0.0, 1.0);
          for (size_t k = 0; k < d.steps.size(); ++k) {
            const double z = N(compass_rng);  // drawn for every step, fix or not
            fixStep(d, k, z, cat, trial, run, mi, mode_name, &b);
          }
        }
      }
    }
  }
  return b;
}

void FixStudy::fixStep(const Dataset& d, size_t k, double z, const std::string& cat, int trial, int run, size_t mi,
                       const std::string& mode_name, CategoryBuckets* b) {
  if (k >= d.groundtruth.size() || !d.groundtruth[k]) return;
  const Pose2& truth = *d.groundtruth[k];
  std::ostream* out = csv_ ? &csv_->stream() : nullptr;
  Step st = d.steps[k];
  st.compass.reset();
  char prefix[96];
  if (do2_) {
    std::snprintf(prefix, sizeof(prefix), "%s,%d,%d,fix2,", cat.c_str(), trial, run);
    Nonlinearity nl;
    const GlobalFix f = fixWith(d, st, truth, opt2_, sp2_, &nl);
    record(b->fix2[mi], f, nl, max_nl_, st, truth, out, prefix, mode_name);
  }
  if (doM_) {
    // Steps with at least two identified landmarks (else the method does not apply).
    int identified = 0;
    for (const Observation& o : st.observations) identified += o.landmark_id >= 0 ? 1 : 0;
    if (identified >= 2) {
      Step sm = st;
      const double sigma = deg2rad(kMultiCompassDeg);
      sm.compass = wrapAngle(truth.theta + sigma * z);
      sm.compass_sigma = sigma;
      for (int mm = 0; mm < 2; ++mm) {
        GlobalFixOptions om = optM_rb_;
        if (mm == 1) om.rig = d.rig;
        std::snprintf(prefix, sizeof(prefix), "%s,%d,%d,multi_%s,%g", cat.c_str(), trial, run,
                      mm ? "pixels" : "range_bearing", kMultiCompassDeg);
        const GlobalFix f = globalFix(sm, d.map, om);
        record(b->multi[mi][static_cast<size_t>(mm)], f, Nonlinearity{1.0, 1.0}, max_nl_, sm, truth, out, prefix,
               mode_name);
      }
    }
  }
  if (do1_) {
    for (size_t l = 0; l < kCompassLevelsDeg.size(); ++l) {
      const double sigma = deg2rad(kCompassLevelsDeg[l]);
      st.compass = wrapAngle(truth.theta + sigma * z);
      st.compass_sigma = std::max(sigma, deg2rad(0.01));
      std::snprintf(prefix, sizeof(prefix), "%s,%d,%d,fix1,%g", cat.c_str(), trial, run, kCompassLevelsDeg[l]);
      Nonlinearity nl;
      const GlobalFix f = fixWith(d, st, truth, opt1_, sp1_, &nl);
      record(b->fix1[mi][l], f, nl, max_nl_, st, truth, out, prefix, mode_name);
    }
  }
}

// One row of a thesis table: a statistic of every column beside the thesis's.
template <class BucketOf>
std::string statsRow(const char* label, size_t columns, BucketOf bucketOf, double Sample::*field, double scale,
                     const ThesisTable& t, const std::string& key) {
  std::string line = label;
  for (size_t mi = 0; mi < columns; ++mi) line += (mi ? " | " : "") + statsCells(statsOf(bucketOf(mi).fixes, field), scale);
  return line + " | " + thesisCells(t, key) + "\n";
}

void FixStudy::reportFix2(const std::string& cat, size_t ci, int trials, const CategoryBuckets& b) {
  char buf[400];
  const std::string id = "6." + std::to_string(4 + ci);
  const ThesisTable t = loadThesisTable(tables_path_, id);
  std::snprintf(buf, sizeof(buf), "Table %s: two landmarks (fix2), category %s, %d trials x %d run(s)\n", id.c_str(),
                cat.c_str(), trials, a_.runs);
  report_ << buf;
  const size_t n = gs_.size();
  for (size_t mi = 0; mi < n; ++mi) report_ << (n > 1 ? groups_[mi] + " " : "") << fixRateLine(b.fix2[mi]) << "\n";
  report_ << header("", groups_);
  auto bucket = [&](size_t mi) -> const Bucket& { return b.fix2[mi]; };
  report_ << statsRow("dx (mm)        ", n, bucket, &Sample::dx, 1.0, t, rowKey("dx_mm", 0));
  report_ << statsRow("dy (mm)        ", n, bucket, &Sample::dy, 1.0, t, rowKey("dy_mm", 0));
  report_ << statsRow("dtheta (deg)   ", n, bucket, &Sample::dtheta, rad2deg(1.0), t, rowKey("dtheta_deg", 0));
  for (size_t mi = 0; mi < n; ++mi) report_ << (n > 1 ? groups_[mi] + " " : "") << neesLines(b.fix2[mi].fixes, max_nl_);
  if (!t.note.empty()) report_ << "thesis note: " << t.note << "\n";
  report_ << "\n";
}

void FixStudy::reportMulti(const std::string& cat, const CategoryBuckets& b) {
  char buf[400];
  std::snprintf(buf, sizeof(buf),
                "Multi-landmark least squares (4.2.8), category %s: steps with >= 2 identified landmarks and a "
                "%.1f deg compass; stereo observations as range-bearing (R at the measured pixels) or as pixels "
                "(u_l, u_r predicted at the pose, 1 / pixel sigma)\n",
                cat.c_str(), kMultiCompassDeg);
  report_ << buf;
  const char* model_names[] = {"range-bearing", "pixels"};
  for (size_t mi = 0; mi < gs_.size(); ++mi) {
    for (size_t mm = 0; mm < 2; ++mm) {
      const Bucket& m = b.multi[mi][mm];
      report_ << (gs_.size() > 1 ? groups_[mi] + " " : "") << model_names[mm] << ": " << fixRateLine(m) << "\n";
      if (m.fixes.empty()) continue;
      std::snprintf(buf, sizeof(buf), "  mean |dx| %.2f mm, |dy| %.2f mm, |dtheta| %.3f deg\n",
                    statsOf(m.fixes, &Sample::dx).mean, statsOf(m.fixes, &Sample::dy).mean,
                    rad2deg(statsOf(m.fixes, &Sample::dtheta).mean));
      report_ << buf << neesLines(m.fixes, max_nl_, false);
    }
  }
  report_ << "\n";
}

void FixStudy::reportFix1(const std::string& cat, size_t ci, int trials, const CategoryBuckets& b) {
  char buf[400];
  const std::string id = "6." + std::to_string(9 + ci);
  const ThesisTable t = loadThesisTable(tables_path_, id);
  std::snprintf(buf, sizeof(buf), "Table %s: one landmark + compass (fix1), category %s, %d trials x %d run(s)\n",
                id.c_str(), cat.c_str(), trials, a_.runs);
  report_ << buf;
  const size_t n = gs_.size();
  for (size_t mi = 0; mi < n; ++mi) report_ << (n > 1 ? groups_[mi] + " " : "") << fixRateLine(b.fix1[mi][0]) << "\n";
  report_ << header("compass sigma", groups_);
  for (size_t l = 0; l < kCompassLevelsDeg.size(); ++l) {
    const double lv = kCompassLevelsDeg[l];
    auto bucket = [&](size_t mi) -> const Bucket& { return b.fix1[mi][l]; };
    std::snprintf(buf, sizeof(buf), "%4.1f deg  dx   ", lv);
    report_ << statsRow(buf, n, bucket, &Sample::dx, 1.0, t, rowKey("dx_mm", lv));
    report_ << statsRow("          dy   ", n, bucket, &Sample::dy, 1.0, t, rowKey("dy_mm", lv));
  }
  for (size_t mi = 0; mi < n; ++mi) {
    for (size_t l : {size_t{0}, size_t{4}, size_t{11}}) {
      // At 0 deg the compass reading is exact but declares a floor sigma, so its heading error
      // is 0 and the 3-dof mean is expected near 2, not 3.
      std::snprintf(buf, sizeof(buf), "at %.1f deg compass%s: ", kCompassLevelsDeg[l],
                    kCompassLevelsDeg[l] == 0.0 ? " (exact heading: 3-dof mean expected near 2)" : "");
      report_ << (n > 1 ? groups_[mi] + " " : "") << buf << neesLines(b.fix1[mi][l].fixes, max_nl_);
    }
  }
  if (!t.note.empty()) report_ << "thesis note: " << t.note << "\n";
  report_ << "\n";
}

// Table 6.3 per world, pooled over the categories run; the thesis's figures beside.
void FixStudy::reportRanges() {
  std::vector<std::string> names;
  std::vector<size_t> image_groups;
  for (size_t g = 0; g < gs_.size(); ++g)
    if (gs_[g].mode == FrontendMode::Images) {
      image_groups.push_back(g);
      names.push_back(groups_[g]);
    }
  const ThesisTable t = loadThesisTable(tables_path_, "6.3");
  report_ << "Table 6.3: goal-corner range error of the image frontend, all categories run (range from the robot "
             "centre; normalised = |error| / true range)\n";
  char buf[400];
  for (size_t g : image_groups) {
    const RangeStats& r = ranges_[g];
    std::snprintf(buf, sizeof(buf),
                  "%s: %zu measurements; recall %.1f %% (%ld of %ld visible goal corners found with their id within "
                  "%.0f px); %ld goal-corner detections not matched to a visible corner\n",
                  groups_[g].c_str(), r.abs_err.size(), r.visible ? 100.0 * r.detected / r.visible : 0.0, r.detected,
                  r.visible, kMatchPx, r.unmatched);
    report_ << buf;
  }
  report_ << header("", names);
  auto row = [&](const char* label, std::vector<double> RangeStats::*field, double scale, const std::string& key) {
    std::string line = label;
    for (size_t i = 0; i < image_groups.size(); ++i)
      line += (i ? " | " : "") + statsCells(errorStats(ranges_[image_groups[i]].*field), scale);
    return line + " | " + thesisCells(t, key) + "\n";
  };
  report_ << row("abs (mm)       ", &RangeStats::abs_err, 1.0, rowKey("abs_error_mm", 0));
  report_ << row("normalised (%) ", &RangeStats::norm_err, 100.0, rowKey("norm_error_pct", 0));
  // The signed error separates a range bias (a disparity offset or scale of the given
  // calibration) from the spread.
  report_ << row("signed norm (%)", &RangeStats::signed_norm, 100.0, rowKey("", 0));
  // A world's calibration is drawn per trial: the per-trial mean of the signed error is the
  // range bias of that calibration, the error about it what blur, vibration and noise add.
  report_ << row("trial bias (%) ", &RangeStats::trial_bias, 100.0, rowKey("", 0));
  report_ << row("|e - bias| (%) ", &RangeStats::unbiased, 100.0, rowKey("", 0));
  if (!t.note.empty()) report_ << "thesis note: " << t.note << "\n";
  for (size_t w = 0; w < a_.profiles.size(); ++w) {
    const SelfCalibrationSummary& c = calibration_summary_[w];
    if (c.trials == 0) continue;
    const ErrorStats dd = errorStats(c.disparity_offset), k = errorStats(c.baseline_scale), tilt = errorStats(c.tilt_deg);
    std::snprintf(buf, sizeof(buf),
                  "self-calibration, %s: %d trials, %d without an estimate (given calibration kept); estimates mean / "
                  "std: disparity offset %.2f / %.2f px, baseline scale %.4f / %.4f, tilt correction %.3f / %.3f deg\n",
                  worldName(a_.profiles[w]).c_str(), c.trials, c.failures, dd.mean, dd.std, k.mean, k.std, tilt.mean,
                  tilt.std);
    report_ << buf;
  }
  report_ << "\n";
}

void FixStudy::finish() {
  if (images_) {
    char buf[300];
    std::snprintf(buf, sizeof(buf),
                  "image frontend: %ld pairs, %.2f goal-corner observations per pair, rendering %.1f ms/pair, "
                  "frontend %.2f ms/pair\n",
                  fstats_.pairs, fstats_.pairs ? static_cast<double>(fstats_.identified) / fstats_.pairs : 0.0,
                  fstats_.pairs ? fstats_.ms_render / fstats_.pairs : 0.0,
                  fstats_.pairs ? fstats_.ms_frontend / fstats_.pairs : 0.0);
    // Timings vary between runs: on the log, so that the tables stay reproducible.
    if (a_.log) std::fputs(buf, a_.log);
  }
  std::fputs(report_.str().c_str(), a_.console);
  std::fflush(a_.console);
  if (!a_.out.empty()) {
    writeFileAtomically(a_.out + "/fixstudy.txt", report_.str());
    csv_->commit();
    if (trial_csv_) trial_csv_->commit();
  }
}

}  // namespace

void runFixStudy(const FixStudyOptions& options) { FixStudy(options).run(); }

}  // namespace stereoloc
