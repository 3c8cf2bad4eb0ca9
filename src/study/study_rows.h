#pragma once
// The rows of the accuracy study (src/study/study.h): one trial row per method and trial
// (trials.csv), one step row per compared estimate (steps.csv), and the summary row that pools
// the trials of a scenario and method (summary.csv). Rows keep sums, not means, so that trials
// and shards pool exactly. Numbers are written with 17 significant digits (%.17g), so a file
// read back gives the same doubles.
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "src/core/field_map.h"

namespace stereoloc {
struct StudyConfig;
}

namespace stereoloc::study {

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
  std::string scenario, profile = "ideal", method;
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
  int failed = 0;          // 1: the method failed on this trial (no estimates)
  // The NEES's position (2 dof) and heading (1 dof) parts over the same estimates (PoseError).
  double nees_position_sum = 0, nees_heading_sum = 0;
};


inline constexpr const char* kTrialHeader =
    "scenario,profile,trial,method,steps,estimates,sse_position,sse_theta,"
    "dist_n,dist_sum,dist_sum_sq,dist_min,dist_max,"
    "w1_n,w1_sum,w1_sum_sq,w1_min,w1_max,w2_n,w2_sum,w2_sum_sq,w2_min,w2_max,"
    "nees_count,nees_sum,nees_in_band,ms_per_step,attempted,fixed,failed,nees_position_sum,nees_heading_sum";

// One row of steps.csv: the error of one estimate.
struct StepRow {
  std::string scenario, profile = "ideal", method;
  int trial = 0;
  long step = 0;
  double dx = 0, dy = 0, dtheta = 0;
  double sx = 0, sy = 0, stheta = 0;  // sqrt of the covariance diagonal
  std::optional<double> nees;
  int particles = 0;  // the particle filter's sample size (KLD-sampling adapts it); 0 otherwise
};


inline constexpr const char* kStepHeader =
    "scenario,profile,trial,method,step,dx,dy,dtheta,sigma_x,sigma_y,sigma_theta,nees,particles";

// One row of calibration.csv: one calibration parameter of a self-calibrating method
// (solvers/self_calibration.h) on one trial, against the world's drawn truth.
struct CalibrationRow {
  std::string scenario, profile = "ideal", method, parameter;
  int trial = 0;
  double truth = 0, estimate = 0, sigma = 0;  // parameter units (wheel base mm, tilt rad, exposure offset s)
};

inline constexpr const char* kCalibrationHeader = "scenario,profile,trial,method,parameter,truth,estimate,sigma";

// The parameters in calibration.csv's order: the rig's, then the field's dimensions (their change
// against the map, mm, in kFieldDimensions' order; the saveAsRig keys).
inline constexpr int kCalibrationParameterCount = 7 + kFieldDimensionCount;
inline constexpr const char* kCalibrationParameters[kCalibrationParameterCount] = {
    "wheel_scale_left", "wheel_scale_right", "wheel_base_mm", "tilt_correction_rad", "baseline_scale", "focal_scale",
    "exposure_offset_s", "field_length_mm", "field_width_mm", "field_goal_width_mm", "field_corner_triangle_mm",
    "field_centre_circle_radius_mm", "field_goal_area_depth_mm", "field_goal_area_width_mm",
    "field_penalty_area_depth_mm", "field_penalty_area_width_mm"};
inline constexpr int kFirstFieldCalibrationParameter = 7;

// A trial has converged when every position error over the thesis's second window (steps
// 80-100, Table 6.14) is at most this, mm: about ten times the trackers' error there.
inline constexpr double kConvergedMaxErrorMm = 100.0;

struct SummaryRow {
  std::string scenario, profile = "ideal", method;
  int trials = 0;
  // Per-trial position RMSE over the trials with estimates: sums for its mean and spread.
  int rmse_trials = 0;
  double trial_rmse_sum = 0, trial_rmse_sum_sq = 0;
  long estimates = 0, steps = 0;
  double sse_position = 0, sse_theta = 0;
  WindowSums distance, window1, window2;
  long nees_count = 0, nees_in_band = 0;
  double nees_sum = 0, ms_sum = 0;
  double nees_position_sum = 0, nees_heading_sum = 0;
  long attempted = 0, fixed = 0;
  int judged = 0, converged = 0;  // trials with estimates over steps 80-100, and those converged there
  int failed = 0;                 // trials on which the method failed
  double rmse() const { return estimates ? std::sqrt(sse_position / estimates) : 0; }
  double theta_rmse() const { return estimates ? std::sqrt(sse_theta / estimates) : 0; }
  double meanNees() const { return nees_count ? nees_sum / nees_count : 0; }
  double meanPositionNees() const { return nees_count ? nees_position_sum / nees_count : 0; }  // 2 consistent
  double meanHeadingNees() const { return nees_count ? nees_heading_sum / nees_count : 0; }    // 1 consistent
  double inBand() const { return nees_count ? static_cast<double>(nees_in_band) / nees_count : 0; }
  // Fraction of the judged trials that converged (kConvergedMaxErrorMm); 0 when none was judged.
  double convergedFraction() const { return judged ? static_cast<double>(converged) / judged : 0; }
  double msPerStep() const { return trials ? ms_sum / trials : 0; }
  // Mean per-trial RMSE and the half width of its 95 % confidence interval (normal
  // approximation over the trials: 1.96 s / sqrt(n)); 0 with fewer than two trials.
  double meanTrialRmse() const { return rmse_trials ? trial_rmse_sum / rmse_trials : 0; }
  double trialRmseHalfWidth95() const {
    if (rmse_trials < 2) return 0;
    const double n = rmse_trials, m = meanTrialRmse();
    return 1.96 * std::sqrt(std::max(0.0, (trial_rmse_sum_sq - n * m * m) / (n - 1)) / n);
  }
  // Global fixes: steps with a fix over steps with observations; trackers: steps with an estimate.
  double fixRate() const {
    if (attempted > 0) return static_cast<double>(fixed) / attempted;
    return steps ? static_cast<double>(estimates) / steps : 0;
  }
};

std::string g17(double v);                          // "%.17g"
std::string fmt(const char* format, double v);      // one number with a printf format
std::string joinList(const std::vector<std::string>& v);  // {"a", "b"} -> "a,b"

std::string toCsv(const TrialRow& r);
std::string toCsv(const StepRow& r);
std::string toCsv(const CalibrationRow& r);
// Read back trials.csv / steps.csv (Error naming file, line and field on bad input).
std::vector<TrialRow> readTrialRows(const std::string& path);
std::vector<StepRow> readStepRows(const std::string& path);
std::vector<CalibrationRow> readCalibrationRows(const std::string& path);

// Per scenario, profile, method and parameter: the trials, the fraction whose estimate is within
// 2 sigma of the truth, the mean error and the mean sigma (report.md).
std::string calibrationTable(const std::vector<CalibrationRow>& rows);

// Pools the rows per (scenario, profile, method) in the config's order.
std::vector<SummaryRow> summarise(const StudyConfig& c, const std::vector<TrialRow>& rows);
void writeSummaryCsv(const std::vector<SummaryRow>& rows, const std::string& path);
// The markdown table of one scenario (report.md; with a profile column when a row is not of the
// ideal world) and the console table of all.
std::string summaryTable(const std::vector<SummaryRow>& rows, const std::string& scenario);
// The worlds side by side for one scenario: per method, the mean per-trial RMSE with its 95 %
// interval, the mean NEES and ms/step of each profile in `profiles`.
std::string profileComparisonTable(const std::vector<SummaryRow>& rows, const std::string& scenario,
                                   const std::vector<std::string>& profiles);
std::string summaryText(const std::vector<SummaryRow>& rows);

}  // namespace stereoloc::study
