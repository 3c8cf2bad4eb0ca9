#include "src/study/study_rows.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include "src/core/angles.h"
#include "src/core/atomic_file.h"
#include "src/io/csv.h"
#include "src/pipeline/usage_error.h"
#include "src/study/study.h"
#include "src/study/text_format.h"

namespace stereoloc::study {

std::string g17(double v) {
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

std::string toCsv(const TrialRow& r) {
  std::ostringstream o;
  o << r.scenario << ',' << r.profile << ',' << r.trial << ',' << r.method << ',' << r.steps << ',' << r.estimates << ',' << g17(r.sse_position)
    << ',' << g17(r.sse_theta);
  for (const WindowSums* w : {&r.distance, &r.window1, &r.window2})
    o << ',' << w->n << ',' << g17(w->sum) << ',' << g17(w->sum_sq) << ',' << g17(w->min) << ',' << g17(w->max);
  o << ',' << r.nees_count << ',' << g17(r.nees_sum) << ',' << r.nees_in_band << ',' << g17(r.ms_per_step) << ','
    << r.attempted << ',' << r.fixed << ',' << r.failed << ',' << g17(r.nees_position_sum) << ','
    << g17(r.nees_heading_sum);
  return o.str();
}

std::string toCsv(const StepRow& r) {
  std::ostringstream o;
  o << r.scenario << ',' << r.profile << ',' << r.trial << ',' << r.method << ',' << r.step << ',' << g17(r.dx) << ',' << g17(r.dy) << ','
    << g17(r.dtheta) << ',' << g17(r.sx) << ',' << g17(r.sy) << ',' << g17(r.stheta) << ',' << (r.nees ? g17(*r.nees) : "") << ',' << r.particles;
  return o.str();
}

std::string toCsv(const CalibrationRow& r) {
  std::ostringstream o;
  o << r.scenario << ',' << r.profile << ',' << r.trial << ',' << r.method << ',' << r.parameter << ',' << g17(r.truth) << ','
    << g17(r.estimate) << ',' << g17(r.sigma);
  return o.str();
}

std::string calibrationTable(const std::vector<CalibrationRow>& rows) {
  struct Acc {
    int n = 0, within = 0;
    double err = 0, sigma = 0;
  };
  std::vector<std::string> keys;
  std::map<std::string, Acc> acc;
  for (const CalibrationRow& r : rows) {
    const std::string key = "| " + r.scenario + " | " + r.profile + " | " + r.method + " | " + r.parameter + " |";
    if (!acc.count(key)) keys.push_back(key);
    Acc& a = acc[key];
    ++a.n;
    a.within += std::fabs(r.estimate - r.truth) <= 2 * r.sigma ? 1 : 0;
    a.err += r.estimate - r.truth;
    a.sigma += r.sigma;
  }
  std::ostringstream o;
  o << "| scenario | profile | method | parameter | trials | within 2 sigma | mean error | mean sigma |\n";
  o << "|---|---|---|---|---|---|---|---|\n";
  for (const std::string& k : keys) {
    const Acc& a = acc[k];
    o << k << ' ' << a.n << " | " << fmt("%.0f %%", 100.0 * a.within / a.n) << " | " << fmt("%.3g", a.err / a.n) << " | "
      << fmt("%.3g", a.sigma / a.n) << " |\n";
  }
  return o.str();
}

std::string joinList(const std::vector<std::string>& v) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? "," : "") + v[i];
  return s;
}

std::vector<SummaryRow> summarise(const StudyConfig& c, const std::vector<TrialRow>& rows) {
  std::vector<SummaryRow> out;
  for (const std::string& sc : c.scenarios) {
    for (const std::string& pr : c.profiles) {
      for (const std::string& m : c.methods) {
        SummaryRow s;
        s.scenario = sc;
        s.profile = pr;
        s.method = m;
        for (const TrialRow& r : rows) {
          if (r.scenario != sc || r.profile != pr || r.method != m) continue;
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
          s.nees_position_sum += r.nees_position_sum;
          s.nees_heading_sum += r.nees_heading_sum;
          s.ms_sum += r.ms_per_step;
          s.attempted += r.attempted;
          s.fixed += r.fixed;
          s.failed += r.failed;
          if (r.estimates > 0) {
            const double rmse = std::sqrt(r.sse_position / static_cast<double>(r.estimates));
            ++s.rmse_trials;
            s.trial_rmse_sum += rmse;
            s.trial_rmse_sum_sq += rmse * rmse;
          }
          if (r.window2.n > 0) {
            ++s.judged;
            s.converged += r.window2.max <= kConvergedMaxErrorMm ? 1 : 0;
          }
        }
        out.push_back(s);
      }
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
  out.stream() << "scenario,profile,method,trials,position_rmse_mm,dist_mean_mm,dist_std_mm,dist_min_mm,dist_max_mm,"
                  "theta_rmse_rad,nees_mean,nees_in_band,ms_per_step,fix_rate,converged,trial_rmse_mean_mm,trial_rmse_ci95_mm,failed,"
                  "nees_position_mean,nees_heading_mean\n";
  for (const SummaryRow& s : rows) {
    out.stream() << s.scenario << ',' << s.profile << ',' << s.method << ',' << s.trials << ',' << g17(s.rmse()) << ',' << g17(s.distance.mean())
                 << ',' << g17(s.distance.std()) << ',' << g17(s.distance.min) << ',' << g17(s.distance.max) << ','
                 << g17(s.theta_rmse()) << ',' << g17(s.meanNees()) << ',' << g17(s.inBand()) << ',' << g17(s.msPerStep())
                 << ',' << g17(s.fixRate()) << ',' << g17(s.convergedFraction()) << ',' << g17(s.meanTrialRmse()) << ','
                 << g17(s.trialRmseHalfWidth95()) << ',' << s.failed << ',' << g17(s.meanPositionNees()) << ','
                 << g17(s.meanHeadingNees()) << '\n';
  }
  out.commit();
}

namespace {

bool anyNonIdeal(const std::vector<SummaryRow>& rows) {
  return std::any_of(rows.begin(), rows.end(), [](const SummaryRow& s) { return s.profile != "ideal"; });
}

}  // namespace

std::string summaryTable(const std::vector<SummaryRow>& rows, const std::string& scenario) {
  const bool profiles = anyNonIdeal(rows);
  std::ostringstream o;
  o << "| method | " << (profiles ? "profile | " : "")
    << "trials | position RMSE [mm] | mean [mm] | std [mm] | min [mm] | max [mm] | theta RMSE [deg] | mean NEES | NEES "
       "position (2) / heading (1) | NEES in 95% band | ms/step | fix/estimate rate | converged |\n";
  o << "|---|" << (profiles ? "---|" : "") << "---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const SummaryRow& s : rows) {
    if (s.scenario != scenario) continue;
    o << "| " << s.method << " | " << (profiles ? s.profile + " | " : "") << s.trials << " | " << fmt("%.1f", s.rmse())
      << " | " << fmt("%.1f", s.distance.mean())
      << " | " << fmt("%.1f", s.distance.std()) << " | " << fmt("%.1f", s.distance.min) << " | " << fmt("%.1f", s.distance.max)
      << " | " << fmt("%.2f", rad2deg(s.theta_rmse())) << " | " << (s.nees_count ? fmt("%.2f", s.meanNees()) : "-") << " | "
      << (s.nees_count ? fmt("%.2f", s.meanPositionNees()) + " / " + fmt("%.2f", s.meanHeadingNees()) : "-") << " | "
      << (s.nees_count ? fmt("%.0f %%", 100 * s.inBand()) : "-") << " | " << fmt("%.3f", s.msPerStep()) << " | "
      << fmt("%.0f %%", 100 * s.fixRate()) << " | "
      << (s.judged ? fmt("%.0f %%", 100 * s.convergedFraction()) : "-") << " |\n";
  }
  return o.str();
}

std::string profileComparisonTable(const std::vector<SummaryRow>& rows, const std::string& scenario,
                                   const std::vector<std::string>& profiles) {
  std::ostringstream o;
  o << "| method |";
  for (const std::string& p : profiles) o << " RMSE " << p << " [mm] | NEES " << p << " | ms/step " << p << " |";
  o << " failed trials |";
  o << "\n|---|";
  for (size_t i = 0; i < profiles.size(); ++i) o << "---|---|---|";
  o << "---|\n";
  std::vector<std::string> methods;
  for (const SummaryRow& s : rows)
    if (s.scenario == scenario && std::find(methods.begin(), methods.end(), s.method) == methods.end())
      methods.push_back(s.method);
  for (const std::string& m : methods) {
    o << "| " << m << " |";
    std::string failed;
    for (const std::string& p : profiles) {
      const auto it = std::find_if(rows.begin(), rows.end(), [&](const SummaryRow& s) {
        return s.scenario == scenario && s.profile == p && s.method == m;
      });
      if (it != rows.end() && it->failed > 0)
        failed += (failed.empty() ? "" : ", ") + p + " " + std::to_string(it->failed) + "/" + std::to_string(it->trials);
      if (it == rows.end() || it->rmse_trials == 0) {
        o << " - | - | - |";
        continue;
      }
      o << " " << fmt("%.1f", it->meanTrialRmse()) << " +- " << fmt("%.1f", it->trialRmseHalfWidth95()) << " | "
        << (it->nees_count ? fmt("%.2f", it->meanNees()) : "-") << " | " << fmt("%.3f", it->msPerStep()) << " |";
    }
    o << " " << (failed.empty() ? "0" : failed) << " |\n";
  }
  return o.str();
}

std::string summaryText(const std::vector<SummaryRow>& rows) {
  const bool profiles = anyNonIdeal(rows);
  auto label = [&](const SummaryRow& s) { return profiles ? s.scenario + "/" + s.profile : s.scenario; };
  int width = 8;
  for (const SummaryRow& s : rows) width = std::max(width, static_cast<int>(label(s).size()));
  std::string text = formatText("%-*s %-12s %6s %10s %9s %9s %9s %9s %8s %6s %5s\n", width, "scenario", "method", "trials",
                                "RMSE[mm]", "mean[mm]", "std[mm]", "max[mm]", "th[deg]", "NEES", "ms/st", "conv");
  for (const SummaryRow& s : rows)
    text += formatText("%-*s %-12s %6d %10.1f %9.1f %9.1f %9.1f %9.2f %8.2f %6.3f %4.0f%%\n", width, label(s).c_str(),
                       s.method.c_str(), s.trials, s.rmse(), s.distance.mean(), s.distance.std(), s.distance.max,
                       rad2deg(s.theta_rmse()), s.meanNees(), s.msPerStep(), 100 * s.convergedFraction());
  return text;
}

std::vector<TrialRow> readTrialRows(const std::string& path) {
  CsvReader in(path);
  in.expectHeader({splitCommaList(kTrialHeader)});
  std::vector<TrialRow> out;
  while (in.next()) {
    TrialRow r;
    r.scenario = in.field(0);
    r.profile = in.field(1);
    r.trial = static_cast<int>(in.getLong(2));
    r.method = in.field(3);
    r.steps = in.getLong(4);
    r.estimates = in.getLong(5);
    r.sse_position = in.getDouble(6);
    r.sse_theta = in.getDouble(7);
    int k = 8;
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
    r.failed = static_cast<int>(in.getLong(k++));
    r.nees_position_sum = in.getDouble(k++);
    r.nees_heading_sum = in.getDouble(k++);
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
    r.profile = in.field(1);
    r.trial = static_cast<int>(in.getLong(2));
    r.method = in.field(3);
    r.step = in.getLong(4);
    r.dx = in.getDouble(5);
    r.dy = in.getDouble(6);
    r.dtheta = in.getDouble(7);
    r.sx = in.getDouble(8);
    r.sy = in.getDouble(9);
    r.stheta = in.getDouble(10);
    if (!in.field(11).empty()) r.nees = in.getDouble(11);
    r.particles = static_cast<int>(in.getLong(12));
    out.push_back(r);
  }
  return out;
}

std::vector<CalibrationRow> readCalibrationRows(const std::string& path) {
  CsvReader in(path);
  in.expectHeader({splitCommaList(kCalibrationHeader)});
  std::vector<CalibrationRow> out;
  while (in.next()) {
    CalibrationRow r;
    r.scenario = in.field(0);
    r.profile = in.field(1);
    r.trial = static_cast<int>(in.getLong(2));
    r.method = in.field(3);
    r.parameter = in.field(4);
    r.truth = in.getDouble(5);
    r.estimate = in.getDouble(6);
    r.sigma = in.getDouble(7);
    out.push_back(r);
  }
  return out;
}

}  // namespace stereoloc::study
