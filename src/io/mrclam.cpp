#include "src/io/mrclam.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// Median of a chi-square variable with one degree of freedom: a robust variance estimate of
// zero-mean Gaussian errors is median(e^2) / kChi2Median1.
constexpr double kChi2Median1 = 0.454936423119572;
// Scale of the MAD for a Gaussian: sigma = 1.4826 MAD.
constexpr double kMadToSigma = 1.482602218505602;

std::string where(const std::string& path, long line) { return path + ":" + std::to_string(line); }

double parseNumber(const std::string& token, const std::string& path, long line, const char* field) {
  errno = 0;
  char* end = nullptr;
  const double v = std::strtod(token.c_str(), &end);
  if (end == token.c_str() || *end != '\0' || errno == ERANGE || !std::isfinite(v))
    throw Error(where(path, line) + ": " + field + ": '" + token + "' is not a finite number");
  return v;
}

int parseInteger(const std::string& token, const std::string& path, long line, const char* field) {
  const double v = parseNumber(token, path, line, field);
  if (v != std::floor(v) || std::fabs(v) > 1e9)
    throw Error(where(path, line) + ": " + field + ": '" + token + "' is not an integer");
  return static_cast<int>(v);
}

// Calls f(line, fields) for every data line (comment lines start with '#'); a blank line, a
// wrong field count or an empty file are errors.
template <typename F>
void forEachRow(const std::string& path, size_t n_fields, const std::vector<const char*>& names, F&& f) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open");
  std::string text;
  long line = 0, rows = 0;
  std::vector<std::string> fields;
  while (std::getline(in, text)) {
    ++line;
    if (!text.empty() && text.back() == '\r') text.pop_back();
    const size_t first = text.find_first_not_of(" \t");
    if (first == std::string::npos) {
      // A blank last line is the file's final newline convention; elsewhere it is a hole.
      if (in.peek() == std::char_traits<char>::eof()) break;
      throw Error(where(path, line) + ": blank line");
    }
    if (text[first] == '#') continue;
    fields.clear();
    std::istringstream ss(text);
    std::string tok;
    while (ss >> tok) fields.push_back(tok);
    if (fields.size() != n_fields) {
      std::string expected;
      for (const char* n : names) expected += std::string(expected.empty() ? "" : ", ") + n;
      throw Error(where(path, line) + ": expected " + std::to_string(n_fields) + " fields (" + expected + "), found " +
                  std::to_string(fields.size()) + " (truncated or malformed row)");
    }
    f(line, fields);
    ++rows;
  }
  if (rows == 0) throw Error(path + ": no data rows");
}

void checkTimeOrder(double t, double previous, bool have_previous, const std::string& path, long line) {
  if (have_previous && t < previous) {
    char buf[160];
    std::snprintf(buf, sizeof buf, ": time %.3f s goes backwards (previous row %.3f s)", t, previous);
    throw Error(where(path, line) + buf);
  }
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t n = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(n), v.end());
  double m = v[n];
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + static_cast<long>(n)));
  return m;
}

std::string formatStats(const RobustErrorStats& s, double scale, const char* unit) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "n %zu, median %+.3g %s, robust sigma %.3g %s (1.4826 MAD), mean %+.3g, std %.3g, max |e| %.3g, "
                "outliers (>5 sigma) %zu",
                s.count, s.median * scale, unit, s.mad_sigma * scale, unit, s.mean * scale, s.std * scale,
                s.max_abs * scale, s.outliers);
  return buf;
}

}  // namespace

// ---------------------------------------------------------------- readers

std::map<int, int> readMrclamBarcodes(const std::string& path) {
  std::map<int, int> barcode_to_subject;
  std::set<int> subjects;
  forEachRow(path, 2, {"subject", "barcode"}, [&](long line, const std::vector<std::string>& f) {
    const int subject = parseInteger(f[0], path, line, "subject");
    const int barcode = parseInteger(f[1], path, line, "barcode");
    if (!subjects.insert(subject).second) throw Error(where(path, line) + ": subject: duplicate subject " + f[0]);
    if (!barcode_to_subject.emplace(barcode, subject).second)
      throw Error(where(path, line) + ": barcode: duplicate barcode " + f[1]);
  });
  return barcode_to_subject;
}

std::map<int, Eigen::Vector2d> readMrclamLandmarks(const std::string& path) {
  std::map<int, Eigen::Vector2d> landmarks;
  forEachRow(path, 5, {"subject", "x", "y", "x std-dev", "y std-dev"},
             [&](long line, const std::vector<std::string>& f) {
               const int subject = parseInteger(f[0], path, line, "subject");
               const Eigen::Vector2d xy(1000.0 * parseNumber(f[1], path, line, "x"),
                                        1000.0 * parseNumber(f[2], path, line, "y"));
               parseNumber(f[3], path, line, "x std-dev");
               parseNumber(f[4], path, line, "y std-dev");
               if (!landmarks.emplace(subject, xy).second)
                 throw Error(where(path, line) + ": subject: duplicate landmark " + f[0]);
             });
  return landmarks;
}

std::vector<MrclamOdometryRow> readMrclamOdometry(const std::string& path) {
  std::vector<MrclamOdometryRow> rows;
  forEachRow(path, 3, {"time", "forward velocity", "angular velocity"},
             [&](long line, const std::vector<std::string>& f) {
               MrclamOdometryRow r;
               r.t = parseNumber(f[0], path, line, "time");
               r.v = 1000.0 * parseNumber(f[1], path, line, "forward velocity");
               r.omega = parseNumber(f[2], path, line, "angular velocity");
               checkTimeOrder(r.t, rows.empty() ? 0.0 : rows.back().t, !rows.empty(), path, line);
               rows.push_back(r);
             });
  return rows;
}

std::vector<MrclamMeasurementRow> readMrclamMeasurements(const std::string& path) {
  std::vector<MrclamMeasurementRow> rows;
  forEachRow(path, 4, {"time", "barcode", "range", "bearing"}, [&](long line, const std::vector<std::string>& f) {
    MrclamMeasurementRow r;
    r.t = parseNumber(f[0], path, line, "time");
    r.barcode = parseInteger(f[1], path, line, "barcode");
    r.range = 1000.0 * parseNumber(f[2], path, line, "range");
    r.bearing = parseNumber(f[3], path, line, "bearing");
    r.line = line;
    if (!(r.range > 0)) throw Error(where(path, line) + ": range: '" + f[2] + "' is not positive");
    checkTimeOrder(r.t, rows.empty() ? 0.0 : rows.back().t, !rows.empty(), path, line);
    rows.push_back(r);
  });
  return rows;
}

std::vector<MrclamPoseRow> readMrclamGroundtruth(const std::string& path) {
  std::vector<MrclamPoseRow> rows;
  forEachRow(path, 4, {"time", "x", "y", "orientation"}, [&](long line, const std::vector<std::string>& f) {
    MrclamPoseRow r;
    r.t = parseNumber(f[0], path, line, "time");
    r.pose = Pose2(1000.0 * parseNumber(f[1], path, line, "x"), 1000.0 * parseNumber(f[2], path, line, "y"),
                   parseNumber(f[3], path, line, "orientation"));
    checkTimeOrder(r.t, rows.empty() ? 0.0 : rows.back().t, !rows.empty(), path, line);
    rows.push_back(r);
  });
  return rows;
}

// ---------------------------------------------------------------- odometry

WheelIncrements wheelIncrementsForTwist(double v, double omega, double dt, double wheel_base_mm) {
  // The wheels sit at -+w/2 from the centre along the axle, so their speeds are v -+ omega w/2;
  // this is wheelIncrementsForArc(v dt, omega dt, w), the inverse of (B.1), (B.2).
  return wheelIncrementsForArc(v * dt, omega * dt, wheel_base_mm);
}

WheelOdometer::WheelOdometer(const std::vector<MrclamOdometryRow>& rows, double wheel_base_mm)
    : rows_(rows), w_(wheel_base_mm) {
  if (rows_.empty()) throw Error("odometry: no rows");
  if (!(std::isfinite(w_) && w_ > 0)) throw Error("odometry: wheel base must be positive");
  cumulative_.resize(rows_.size());
  for (size_t i = 1; i < rows_.size(); ++i) {
    const MrclamOdometryRow& r = rows_[i - 1];
    const WheelIncrements d = wheelIncrementsForTwist(r.v, r.omega, rows_[i].t - r.t, w_);
    cumulative_[i] = WheelIncrements{cumulative_[i - 1].d_left + d.d_left, cumulative_[i - 1].d_right + d.d_right};
  }
}

WheelIncrements WheelOdometer::travelAt(double t) const {
  if (t <= rows_.front().t) return cumulative_.front();
  if (t >= rows_.back().t) return cumulative_.back();
  // The command of the last row at or before t is in force at t.
  const auto it = std::upper_bound(rows_.begin(), rows_.end(), t,
                                   [](double tt, const MrclamOdometryRow& r) { return tt < r.t; });
  const size_t i = static_cast<size_t>(it - rows_.begin()) - 1;
  const MrclamOdometryRow& r = rows_[i];
  const WheelIncrements d = wheelIncrementsForTwist(r.v, r.omega, t - r.t, w_);
  return WheelIncrements{cumulative_[i].d_left + d.d_left, cumulative_[i].d_right + d.d_right};
}

WheelIncrements WheelOdometer::between(double t0, double t1) const {
  const WheelIncrements a = travelAt(t0), b = travelAt(t1);
  return WheelIncrements{b.d_left - a.d_left, b.d_right - a.d_right};
}

// ---------------------------------------------------------------- ground truth

std::optional<Pose2> interpolateGroundtruth(const std::vector<MrclamPoseRow>& gt, double t, double max_gap_s) {
  if (gt.empty() || t < gt.front().t || t > gt.back().t) return std::nullopt;
  auto it = std::lower_bound(gt.begin(), gt.end(), t, [](const MrclamPoseRow& r, double tt) { return r.t < tt; });
  if (it->t == t) return it->pose;
  const MrclamPoseRow& b = *it;
  const MrclamPoseRow& a = *(it - 1);
  if (b.t - a.t > max_gap_s) return std::nullopt;
  const double s = (t - a.t) / (b.t - a.t);
  // Heading on the circle: along the shorter arc from a to b.
  return Pose2(a.pose.x + s * (b.pose.x - a.pose.x), a.pose.y + s * (b.pose.y - a.pose.y),
               a.pose.theta + s * angleDiff(b.pose.theta, a.pose.theta));
}

// ---------------------------------------------------------------- command delay

namespace {

// The heading change the commands give over [t0, t1] held from their rows' times + delay.
double commandedTurn(const WheelOdometer& odometer, double t0, double t1, double delay_s, double wheel_base_mm) {
  const WheelIncrements d = odometer.between(t0 - delay_s, t1 - delay_s);
  return (d.d_right - d.d_left) / wheel_base_mm;  // (B.1)
}

}  // namespace

CommandDelayFit fitCommandDelay(const std::vector<MrclamOdometryRow>& odometry, const std::vector<MrclamPoseRow>& gt,
                                const CommandDelaySearch& search) {
  if (!(search.window_s > 0 && search.step_s > 0 && search.min_s < search.max_s &&
        search.max_s - search.min_s >= 2 * search.step_s))
    throw Error("command delay fit: the search needs window_s, step_s > 0 and max_s - min_s >= 2 step_s");
  if (odometry.empty() || gt.empty()) throw Error("command delay fit: no odometry or no ground truth");
  double max_turn_rate = 0;
  for (const MrclamOdometryRow& r : odometry) max_turn_rate = std::max(max_turn_rate, std::fabs(r.omega));
  if (max_turn_rate < 1e-3) throw Error("command delay fit: the commands never turn, so no delay shows in the heading");
  // The wheel base cancels in commandedTurn (the turn is omega dt); any positive value does.
  const double w = 1000.0;
  const WheelOdometer odometer(odometry, w);
  struct Window {
    double t0, t1, turn;  // s, s, rad (ground truth)
  };
  std::vector<Window> windows;
  const double begin = std::max(odometry.front().t, gt.front().t), end = std::min(odometry.back().t, gt.back().t);
  for (double t = begin; t + search.window_s <= end; t += search.window_s) {
    const std::optional<Pose2> a = interpolateGroundtruth(gt, t, search.max_groundtruth_gap_s);
    const std::optional<Pose2> b = interpolateGroundtruth(gt, t + search.window_s, search.max_groundtruth_gap_s);
    if (a && b) windows.push_back({t, t + search.window_s, angleDiff(b->theta, a->theta)});
  }
  if (windows.size() < 20)
    throw Error("command delay fit: " + std::to_string(windows.size()) +
                " windows with ground truth at both ends (at least 20 needed)");
  auto spread = [&](double delay_s) {
    std::vector<double> e;
    e.reserve(windows.size());
    for (const Window& win : windows) e.push_back(angleDiff(win.turn, commandedTurn(odometer, win.t0, win.t1, delay_s, w)));
    return robustErrorStats(std::move(e)).mad_sigma;
  };
  const int n = static_cast<int>(std::floor((search.max_s - search.min_s) / search.step_s + 1e-9)) + 1;
  std::vector<double> cost(static_cast<size_t>(n));
  int best = 0;
  for (int i = 0; i < n; ++i) {
    cost[static_cast<size_t>(i)] = spread(search.min_s + i * search.step_s);
    if (cost[static_cast<size_t>(i)] < cost[static_cast<size_t>(best)]) best = i;
  }
  if (best == 0 || best == n - 1)
    throw Error("command delay fit: the best delay is at the edge of the search, " +
                std::to_string(search.min_s + best * search.step_s) + " s");
  // Vertex of the parabola through the best grid point and its neighbours, kept within them.
  const double cm = cost[static_cast<size_t>(best - 1)], c0 = cost[static_cast<size_t>(best)],
               cp = cost[static_cast<size_t>(best + 1)];
  const double curvature = cm - 2 * c0 + cp;
  const double shift = curvature > 0 ? std::clamp(0.5 * (cm - cp) / curvature, -0.5, 0.5) : 0.0;
  CommandDelayFit fit;
  fit.delay_s = search.min_s + (best + shift) * search.step_s;
  fit.windows = windows.size();
  fit.heading_sigma_at_zero = spread(0.0);
  fit.heading_sigma = spread(fit.delay_s);
  return fit;
}

// ---------------------------------------------------------------- statistics

RobustErrorStats robustErrorStats(std::vector<double> errors) {
  RobustErrorStats s;
  s.count = errors.size();
  if (errors.empty()) return s;
  double sum = 0, sum2 = 0;
  for (double e : errors) {
    sum += e;
    s.max_abs = std::max(s.max_abs, std::fabs(e));
  }
  s.mean = sum / static_cast<double>(s.count);
  for (double e : errors) sum2 += (e - s.mean) * (e - s.mean);
  s.std = std::sqrt(sum2 / static_cast<double>(s.count));
  s.median = median(errors);
  std::vector<double> dev(errors.size());
  for (size_t i = 0; i < errors.size(); ++i) dev[i] = std::fabs(errors[i] - s.median);
  s.mad_sigma = kMadToSigma * median(dev);
  for (double d : dev)
    if (d > 5.0 * s.mad_sigma) ++s.outliers;
  return s;
}

OdometryNoiseFit fitOdometryNoise(const std::vector<Step>& steps, const std::vector<std::optional<Pose2>>& groundtruth,
                                  double wheel_base_mm, double window_s, double min_travel_mm) {
  if (steps.size() != groundtruth.size()) throw Error("odometry fit: steps and ground truth differ in length");
  const double w = wheel_base_mm;
  std::vector<double> q_heading, q_along, e_heading, e_along, e_lateral, lateral_per_m, travels;
  double step_count = 0;
  OdometryNoiseFit fit;
  size_t a = 0;
  while (a < steps.size()) {
    if (!groundtruth[a]) {
      ++a;
      continue;
    }
    size_t b = a + 1;
    Pose2 rel;  // odometry from a to b in a's frame
    double travel = 0.0;
    bool complete = false;
    for (; b < steps.size(); ++b) {
      if (!groundtruth[b]) break;
      const Eigen::Vector3d u = controlVector(steps[b].d_left, steps[b].d_right, w);
      rel = compose(rel, Pose2(u.x(), u.y(), u.z()));
      travel += std::fabs(steps[b].d_left) + std::fabs(steps[b].d_right);
      if (steps[b].t - steps[a].t >= window_s) {
        complete = true;
        break;
      }
    }
    if (!complete) {
      a = b;
      continue;
    }
    if (travel >= min_travel_mm) {
      const Pose2 truth = between(*groundtruth[a], *groundtruth[b]);
      const Pose2 err = between(rel, truth);  // truth in the odometry's end frame
      e_heading.push_back(err.theta);
      e_along.push_back(err.x);
      e_lateral.push_back(err.y);
      // (B.6) summed over the window: var(dtheta) = k S / w^2, var(along) ~= k S / 4.
      q_heading.push_back(err.theta * err.theta * w * w / travel);
      q_along.push_back(4.0 * err.x * err.x / travel);
      lateral_per_m.push_back(err.y / (0.5 * travel / 1000.0));
      travels.push_back(travel);
      step_count += static_cast<double>(b - a);
    }
    a = b;
  }
  fit.windows = q_heading.size();
  if (fit.windows == 0) return fit;
  fit.k_heading = median(q_heading) / kChi2Median1;
  fit.k_along = median(q_along) / kChi2Median1;
  fit.heading_error = robustErrorStats(e_heading);
  fit.along_error = robustErrorStats(e_along);
  fit.lateral_error = robustErrorStats(e_lateral);
  fit.lateral_sigma_per_m = robustErrorStats(lateral_per_m).mad_sigma;
  fit.median_travel_mm = median(travels);
  fit.mean_steps = step_count / static_cast<double>(fit.windows);
  return fit;
}

// ---------------------------------------------------------------- range correction

double RangeCorrection::correct(double range, double bearing) const {
  const double f = factor(bearing);
  if (!(f >= 0.5 && f <= 2.0)) {
    char buf[160];
    std::snprintf(buf, sizeof buf, "range correction: factor %.3g at bearing %.1f deg is outside [0.5, 2]", f,
                  rad2deg(bearing));
    throw Error(buf);
  }
  return range / f;
}

RangeCorrection fitRangeCorrection(const std::vector<RangeSample>& samples) {
  if (samples.size() < 10) throw Error("range correction fit: fewer than 10 ranges with ground truth");
  RangeCorrection rc;
  std::vector<double> residual(samples.size());
  for (int iteration = 0; iteration < 10; ++iteration) {
    for (size_t i = 0; i < samples.size(); ++i) {
      const RangeSample& s = samples[i];
      residual[i] = s.measured / s.truth - rc.factor(s.bearing);
    }
    // Huber weights at 1.345 robust sigmas of the current residuals (all 1 on the first pass).
    std::vector<double> dev(residual.size());
    for (size_t i = 0; i < residual.size(); ++i) dev[i] = std::fabs(residual[i]);
    const double k = 1.345 * kMadToSigma * median(dev);
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < samples.size(); ++i) {
      const RangeSample& s = samples[i];
      const double w = iteration == 0 || !(k > 0) || dev[i] <= k ? 1.0 : k / dev[i];
      const Eigen::Vector3d phi(1.0, s.bearing, s.bearing * s.bearing);
      A += w * phi * phi.transpose();
      b += w * phi * (s.measured / s.truth - 1.0);
    }
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(A);
    if (ldlt.info() != Eigen::Success || !(ldlt.rcond() > 1e-12))
      throw Error("range correction fit: the bearings do not spread enough to fit a quadratic");
    rc.c = ldlt.solve(b);
  }
  return rc;
}

// ---------------------------------------------------------------- map and import

void MrclamImportConfig::validate() const {
  auto check = [](bool ok, const char* field) {
    if (!ok) throw Error(std::string("mrclam import: ") + field + " is out of range");
  };
  check(robot >= 1 && robot <= kMrclamRobotCount, "robot (1..5)");
  check(std::isfinite(rate_hz) && rate_hz > 0 && rate_hz <= 1000, "rate_hz");
  check(std::isfinite(wheel_base_mm) && wheel_base_mm > 0, "wheel_base_mm");
  check(std::isfinite(merge_tolerance_s) && merge_tolerance_s >= 0 && merge_tolerance_s < 0.5 / rate_hz,
        "merge_tolerance_s");
  check(std::isfinite(max_groundtruth_gap_s) && max_groundtruth_gap_s > 0, "max_groundtruth_gap_s");
  check(std::isfinite(map_margin_mm) && map_margin_mm >= 0, "map_margin_mm");
  check(!sigma_range_mm || (std::isfinite(*sigma_range_mm) && *sigma_range_mm > 0), "sigma_range_mm");
  check(!sigma_bearing_rad || (std::isfinite(*sigma_bearing_rad) && *sigma_bearing_rad > 0), "sigma_bearing_rad");
  check(std::isfinite(odometry_window_s) && odometry_window_s > 0, "odometry_window_s");
  check(std::isfinite(odometry_noise_scale) && odometry_noise_scale > 0, "odometry_noise_scale");
  check(std::isfinite(correlation_max_lag_s) && correlation_max_lag_s > 0, "correlation_max_lag_s");
  check(range_correction != CorrectionSource::Given || given_range_correction.c.allFinite(),
        "given_range_correction");
  check(command_delay != CorrectionSource::Given ||
            (std::isfinite(given_command_delay_s) && std::fabs(given_command_delay_s) <= 2.0),
        "given_command_delay_s (|delay| <= 2 s)");
}

ObservationCorrelation ImportReport::correlation() const {
  ObservationCorrelation c;
  c.range_same = range_same.correlation;
  c.range_other = range_other.correlation;
  c.bearing_same = bearing_same.correlation;
  c.bearing_other = bearing_other.correlation;
  return c;
}

FieldMap mrclamMap(const std::map<int, Eigen::Vector2d>& landmarks, const std::vector<Eigen::Vector2d>& extent,
                   double margin_mm, const std::string& name) {
  if (landmarks.empty()) throw Error("mrclam map: no landmarks");
  Bounds b;
  b.xmin = b.ymin = std::numeric_limits<double>::infinity();
  b.xmax = b.ymax = -std::numeric_limits<double>::infinity();
  auto grow = [&](const Eigen::Vector2d& p) {
    b.xmin = std::min(b.xmin, p.x());
    b.xmax = std::max(b.xmax, p.x());
    b.ymin = std::min(b.ymin, p.y());
    b.ymax = std::max(b.ymax, p.y());
  };
  std::vector<Landmark> lms;
  for (const auto& [subject, xy] : landmarks) {
    grow(xy);
    Landmark l;
    l.id = subject;
    l.type = LandmarkType::Point;
    l.name = "subject" + std::to_string(subject);
    l.position = Eigen::Vector3d(xy.x(), xy.y(), 0.0);
    l.unique = true;  // each barcode identifies its landmark
    lms.push_back(l);
  }
  for (const Eigen::Vector2d& p : extent) grow(p);
  b.xmin -= margin_mm;
  b.ymin -= margin_mm;
  b.xmax += margin_mm;
  b.ymax += margin_mm;
  return FieldMap(name, b, std::move(lms));
}

namespace {

// The landmark sightings inside the odometry's span [t0, t_end]; the rest counted by reason.
std::vector<const MrclamMeasurementRow*> landmarkSightings(const std::vector<MrclamMeasurementRow>& meas,
                                                           const std::map<int, int>& barcodes,
                                                           const std::map<int, Eigen::Vector2d>& landmarks, double t0,
                                                           double t_end, ImportReport* rep) {
  std::vector<const MrclamMeasurementRow*> kept;
  for (const MrclamMeasurementRow& m : meas) {
    const auto it = barcodes.find(m.barcode);
    if (it == barcodes.end() || (it->second > kMrclamRobotCount && !landmarks.count(it->second))) {
      ++rep->dropped_unknown_barcode;
    } else if (it->second <= kMrclamRobotCount) {
      ++rep->dropped_other_robot;
    } else if (m.t < t0 || m.t > t_end) {
      ++rep->dropped_outside_odometry;
    } else {
      kept.push_back(&m);
    }
  }
  return kept;
}

// A step: its time (relative to t0) and the sightings merged into it.
struct StepTime {
  double t;
  std::vector<const MrclamMeasurementRow*> meas;
};

// Step times: clusters of sightings within the merge tolerance, then the grid of config.rate_hz
// where no cluster is close, and a last step at the last odometry row.
std::vector<StepTime> stepTimes(const std::vector<const MrclamMeasurementRow*>& kept, double t0, double t_end,
                                const MrclamImportConfig& config, ImportReport* rep) {
  std::vector<StepTime> times;
  for (const MrclamMeasurementRow* m : kept) {
    const double tr = m->t - t0;
    if (times.empty() || tr - times.back().t > config.merge_tolerance_s) times.push_back({tr, {}});
    rep->max_time_shift_s = std::max(rep->max_time_shift_s, tr - times.back().t);
    times.back().meas.push_back(m);
  }
  rep->measurement_steps = times.size();
  std::vector<StepTime> merged;
  merged.reserve(times.size() + static_cast<size_t>((t_end - t0) * config.rate_hz) + 2);
  size_t j = 0;
  const long n_grid = static_cast<long>(std::floor((t_end - t0) * config.rate_hz + 1e-9));
  for (long k = 0; k <= n_grid; ++k) {
    const double tg = static_cast<double>(k) / config.rate_hz;
    while (j < times.size() && times[j].t < tg - config.merge_tolerance_s) merged.push_back(std::move(times[j++]));
    if (j < times.size() && std::fabs(times[j].t - tg) <= config.merge_tolerance_s) continue;
    merged.push_back({tg, {}});
    ++rep->grid_steps;
  }
  while (j < times.size()) merged.push_back(std::move(times[j++]));
  // A last step at the last odometry row, so that no commanded motion is left out.
  if (t_end - t0 - merged.back().t > config.merge_tolerance_s) {
    merged.push_back({t_end - t0, {}});
    ++rep->grid_steps;
  }
  return merged;
}

// Range and bearing errors against the ground truth at each sighting's own time, the
// observation sigmas (the configured ones, or the errors' robust sigma) and the errors'
// correlation over sightings. `where` names the measurement file in errors.
void observationSigmas(const std::vector<const MrclamMeasurementRow*>& kept, const std::vector<MrclamPoseRow>& gt,
                       const std::map<int, int>& barcodes, const std::map<int, Eigen::Vector2d>& landmarks,
                       const MrclamImportConfig& config, const std::string& where, ImportReport* rep) {
  std::vector<double> range_err, bearing_err;
  std::vector<ErrorSample> range_samples, bearing_samples;
  for (const MrclamMeasurementRow* m : kept) {
    const std::optional<Pose2> p = interpolateGroundtruth(gt, m->t, config.max_groundtruth_gap_s);
    if (!p) {
      ++rep->measurements_outside_groundtruth;
      continue;
    }
    const Eigen::Vector2d& lm = landmarks.at(barcodes.at(m->barcode));
    if ((lm - p->translation()).norm() < 1e-6) continue;  // bearing undefined; cannot happen for a robot
    const Eigen::Vector2d z = predictRangeBearing(*p, lm);
    range_err.push_back(m->range - z.x());
    bearing_err.push_back(angleDiff(m->bearing, z.y()));
    const int subject = barcodes.at(m->barcode);
    range_samples.push_back({m->t, subject, range_err.back()});
    bearing_samples.push_back({m->t, subject, bearing_err.back()});
  }
  rep->range_same = fitErrorCorrelation(range_samples, true, config.correlation_max_lag_s);
  rep->range_other = fitErrorCorrelation(range_samples, false, config.correlation_max_lag_s);
  rep->bearing_same = fitErrorCorrelation(bearing_samples, true, config.correlation_max_lag_s);
  rep->bearing_other = fitErrorCorrelation(bearing_samples, false, config.correlation_max_lag_s);
  rep->range_error = robustErrorStats(range_err);
  rep->bearing_error = robustErrorStats(bearing_err);
  rep->sigmas_estimated = !(config.sigma_range_mm && config.sigma_bearing_rad);
  if (!config.sigma_range_mm && rep->range_error.count < 10)
    throw Error(where + ": fewer than 10 landmark measurements with ground truth; give the range sigma");
  if (!config.sigma_bearing_rad && rep->bearing_error.count < 10)
    throw Error(where + ": fewer than 10 landmark measurements with ground truth; give the bearing sigma");
  // A zero MAD (quantised readings) would give an infinite information: floor at the resolution
  // of the files (1 mm, 1 mrad).
  rep->sigma_range_mm = config.sigma_range_mm ? *config.sigma_range_mm : std::max(rep->range_error.mad_sigma, 1.0);
  rep->sigma_bearing_rad =
      config.sigma_bearing_rad ? *config.sigma_bearing_rad : std::max(rep->bearing_error.mad_sigma, 1e-3);
}

// The range correction of config.range_correction, applied to the kept sightings' rows of
// `meas` (which `kept` points into), with the uncorrected range errors in the report.
void correctRanges(const std::vector<const MrclamMeasurementRow*>& kept, const std::vector<MrclamPoseRow>& gt,
                   const std::map<int, int>& barcodes, const std::map<int, Eigen::Vector2d>& landmarks,
                   const MrclamImportConfig& config, const std::string& where,
                   std::vector<MrclamMeasurementRow>* meas, ImportReport* rep) {
  rep->range_correction_mode = config.range_correction;
  if (config.range_correction == CorrectionSource::None) return;
  std::vector<RangeSample> samples;
  std::vector<double> errors;
  for (const MrclamMeasurementRow* m : kept) {
    const std::optional<Pose2> p = interpolateGroundtruth(gt, m->t, config.max_groundtruth_gap_s);
    if (!p) continue;
    const double truth = (landmarks.at(barcodes.at(m->barcode)) - p->translation()).norm();
    if (truth < 1e-6) continue;
    samples.push_back({m->range, truth, m->bearing});
    errors.push_back(m->range - truth);
  }
  rep->range_error_uncorrected = robustErrorStats(errors);
  try {
    rep->range_correction =
        config.range_correction == CorrectionSource::Fit ? fitRangeCorrection(samples) : config.given_range_correction;
  } catch (const Error& e) {
    throw Error(where + ": " + e.what());
  }
  for (const MrclamMeasurementRow* m : kept) {
    MrclamMeasurementRow& row = (*meas)[static_cast<size_t>(m - meas->data())];
    try {
      row.range = rep->range_correction.correct(row.range, row.bearing);
    } catch (const Error& e) {
      throw Error(where + ":" + std::to_string(row.line) + ": " + e.what());
    }
  }
}

// Odometry noise from the data (see fitOdometryNoise). Commanded velocities are not measured
// wheel travel: their error is mostly a common speed error, which independent wheel noise
// (B.6) cannot express. k comes from the heading; the along-track and lateral variance the
// wheels do not explain is spread over a window's steps as the per-step control floor (U is
// in the previous pose's frame, so floor x is along-track and y cross-track).
OdometryParams odometryFromFit(const OdometryNoiseFit& fit, const MrclamImportConfig& config) {
  OdometryParams params;
  params.readings = OdometryReadings::Commands;
  params.wheel_base_mm = config.wheel_base_mm;
  if (fit.windows >= 10) {
    params.k_left = params.k_right = config.odometry_noise_scale * fit.k_heading;
    const double n = std::max(1.0, fit.mean_steps);
    const double along = fit.along_error.mad_sigma, lateral = fit.lateral_error.mad_sigma;
    const double explained = fit.k_heading * fit.median_travel_mm / 4.0;
    params.control_variance_floor =
        Eigen::Vector3d(config.odometry_noise_scale * std::max(1.0, (along * along - explained) / n),
                        config.odometry_noise_scale * std::max(1.0, lateral * lateral / n),
                        params.control_variance_floor.z());
  }
  return params;
}

}  // namespace

MrclamImport importMrclam(const std::string& src_dir, const MrclamImportConfig& config) {
  config.validate();
  const std::string dir = src_dir.empty() || src_dir.back() == '/' ? src_dir : src_dir + "/";
  const std::string robot = "Robot" + std::to_string(config.robot) + "_";
  const std::map<int, int> barcodes = readMrclamBarcodes(dir + "Barcodes.dat");
  const std::map<int, Eigen::Vector2d> landmarks = readMrclamLandmarks(dir + "Landmark_Groundtruth.dat");
  const std::vector<MrclamOdometryRow> odo = readMrclamOdometry(dir + robot + "Odometry.dat");
  std::vector<MrclamMeasurementRow> meas = readMrclamMeasurements(dir + robot + "Measurement.dat");
  const std::vector<MrclamPoseRow> gt = readMrclamGroundtruth(dir + robot + "Groundtruth.dat");
  for (const auto& [subject, xy] : landmarks)
    if (subject <= kMrclamRobotCount)
      throw Error(dir + "Landmark_Groundtruth.dat: subject " + std::to_string(subject) + " is a robot, not a landmark");

  MrclamImport out;
  ImportReport& rep = out.report;
  rep.robot = config.robot;
  rep.odometry_rows = odo.size();
  rep.measurement_rows = meas.size();
  rep.groundtruth_rows = gt.size();
  const double t0 = odo.front().t, t_end = odo.back().t;
  rep.epoch_s = t0;
  const std::vector<const MrclamMeasurementRow*> kept = landmarkSightings(meas, barcodes, landmarks, t0, t_end, &rep);
  correctRanges(kept, gt, barcodes, landmarks, config, dir + robot + "Measurement.dat", &meas, &rep);
  const std::vector<StepTime> times = stepTimes(kept, t0, t_end, config, &rep);

  // Steps: wheel travel since the previous step (each command held from its time + the delay),
  // ground truth at the step time.
  rep.command_delay_mode = config.command_delay;
  if (config.command_delay == CorrectionSource::Fit) {
    try {
      rep.command_delay = fitCommandDelay(odo, gt);
    } catch (const Error& e) {
      throw Error(dir + robot + "Odometry.dat: " + e.what());
    }
  } else if (config.command_delay == CorrectionSource::Given) {
    rep.command_delay.delay_s = config.given_command_delay_s;
  }
  const double delay = rep.command_delay.delay_s;
  const WheelOdometer odometer(odo, config.wheel_base_mm);
  out.steps.reserve(times.size());
  out.groundtruth.reserve(times.size());
  std::vector<std::pair<size_t, const MrclamMeasurementRow*>> to_observe;  // (step index, row)
  for (size_t i = 0; i < times.size(); ++i) {
    Step s;
    s.step = static_cast<long>(i);
    s.t = times[i].t;
    if (i > 0) {
      const WheelIncrements d = odometer.between(t0 + times[i - 1].t - delay, t0 + times[i].t - delay);
      s.d_left = d.d_left;
      s.d_right = d.d_right;
    }
    for (const MrclamMeasurementRow* m : times[i].meas) to_observe.emplace_back(i, m);
    out.steps.push_back(std::move(s));
    out.groundtruth.push_back(interpolateGroundtruth(gt, t0 + times[i].t, config.max_groundtruth_gap_s));
    if (out.groundtruth.back()) ++rep.steps_with_groundtruth;
  }
  rep.steps = out.steps.size();
  rep.duration_s = out.steps.back().t;

  observationSigmas(kept, gt, barcodes, landmarks, config, dir + robot + "Measurement.dat", &rep);
  for (const auto& [i, m] : to_observe) {
    out.steps[i].observations.push_back(observationFromRangeBearing(barcodes.at(m->barcode), LandmarkType::Point,
                                                                    m->range, m->bearing, rep.sigma_range_mm,
                                                                    rep.sigma_bearing_rad));
  }
  rep.observations = to_observe.size();
  if (config.correlated_errors) {
    inflateForCorrelatedErrors(out.steps, rep.correlation());
    rep.correlated_errors = true;
    double fr = 0, fb = 0;
    for (const Step& s : out.steps)
      for (const Observation& o : s.observations) {
        fr += o.covariance(0, 0) / (rep.sigma_range_mm * rep.sigma_range_mm);
        fb += o.covariance(1, 1) / (rep.sigma_bearing_rad * rep.sigma_bearing_rad);
      }
    if (rep.observations > 0) {
      rep.mean_range_variance_factor = fr / static_cast<double>(rep.observations);
      rep.mean_bearing_variance_factor = fb / static_cast<double>(rep.observations);
    }
  }

  rep.odometry_fit = fitOdometryNoise(out.steps, out.groundtruth, config.wheel_base_mm, config.odometry_window_s);
  rep.odometry = odometryFromFit(rep.odometry_fit, config);
  out.odometry = rep.odometry;

  std::vector<Eigen::Vector2d> extent;
  extent.reserve(gt.size());
  for (const MrclamPoseRow& r : gt) extent.push_back(r.pose.translation());
  out.name = "mrclam_robot" + std::to_string(config.robot);
  out.map = mrclamMap(landmarks, extent, config.map_margin_mm, "mrclam");
  if (!out.groundtruth.empty() && out.groundtruth.front()) out.initial_pose = out.groundtruth.front();
  return out;
}

std::string ImportReport::summary() const {
  std::ostringstream os;
  char buf[512];
  std::snprintf(buf, sizeof buf, "MR.CLAM robot %d: epoch %.3f s, %.1f s of odometry\n", robot, epoch_s, duration_s);
  os << buf;
  std::snprintf(buf, sizeof buf, "  rows: odometry %zu, measurements %zu, ground truth %zu\n", odometry_rows,
                measurement_rows, groundtruth_rows);
  os << buf;
  std::snprintf(buf, sizeof buf,
                "  steps: %zu (%zu on the grid, %zu at measurement times), %zu with ground truth, %zu without\n", steps,
                grid_steps, measurement_steps, steps_with_groundtruth, steps - steps_with_groundtruth);
  os << buf;
  std::snprintf(buf, sizeof buf,
                "  measurements: %zu landmark observations kept; dropped: %zu of other robots, %zu unknown barcode, "
                "%zu outside the odometry span; %zu kept without ground truth; max time shift %.1f ms\n",
                observations, dropped_other_robot, dropped_unknown_barcode, dropped_outside_odometry,
                measurements_outside_groundtruth, 1000.0 * max_time_shift_s);
  os << buf;
  if (range_correction_mode != CorrectionSource::None) {
    os << "  range error before the correction [mm]: " << formatStats(range_error_uncorrected, 1.0, "mm") << "\n";
    std::snprintf(buf, sizeof buf,
                  "  range correction (%s): range / (1 %+.4f %+.4f b %+.4f b^2), b the bearing in rad\n",
                  range_correction_mode == CorrectionSource::Fit ? "fitted against ground truth" : "given",
                  range_correction.c(0), range_correction.c(1), range_correction.c(2));
    os << buf;
  }
  if (command_delay_mode == CorrectionSource::Fit) {
    std::snprintf(buf, sizeof buf,
                  "  command delay (fitted against ground truth over %zu windows): %.3f s; heading error per window "
                  "%.3f deg robust sigma (%.3f deg without the delay)\n",
                  command_delay.windows, command_delay.delay_s, rad2deg(command_delay.heading_sigma),
                  rad2deg(command_delay.heading_sigma_at_zero));
    os << buf;
  } else if (command_delay_mode == CorrectionSource::Given) {
    std::snprintf(buf, sizeof buf, "  command delay (given): %.3f s\n", command_delay.delay_s);
    os << buf;
  }
  os << "  range error [mm]:    " << formatStats(range_error, 1.0, "mm") << "\n";
  os << "  bearing error [deg]: " << formatStats(bearing_error, 180.0 / kPi, "deg") << "\n";
  std::snprintf(buf, sizeof buf, "  observation sigmas: range %.1f mm, bearing %.2f deg (%s)\n", sigma_range_mm,
                rad2deg(sigma_bearing_rad), sigmas_estimated ? "estimated" : "given");
  os << buf;
  auto rho = [](const ErrorCorrelationFit& f) {
    char b[96];
    std::snprintf(b, sizeof b, "%.2f exp(-dt / %.1f s)", f.correlation.at_zero, f.correlation.time_constant_s);
    return std::string(b);
  };
  os << "  error correlation of two sightings dt apart: range " << rho(range_same) << " (same landmark), "
     << rho(range_other) << " (another); bearing " << rho(bearing_same) << ", " << rho(bearing_other) << "\n";
  if (correlated_errors) {
    std::snprintf(buf, sizeof buf,
                  "  sigmas inflated for it: mean variance factor range %.2f, bearing %.2f "
                  "(sigma x sqrt((1 + rho) / (1 - rho)), rho to the previous sighting)\n",
                  mean_range_variance_factor, mean_bearing_variance_factor);
  } else {
    std::snprintf(buf, sizeof buf, "  (sigmas not inflated for it: --correlated-errors does)\n");
  }
  os << buf;
  std::snprintf(buf, sizeof buf,
                "  odometry noise fit over %zu windows: k_heading %.3g, k_along %.3g mm^2/mm; median travel %.0f mm, "
                "%.1f steps; window errors (median, robust sigma): heading %+.2f, %.2f deg, along %+.1f, %.1f mm, "
                "lateral %+.1f, %.1f mm\n",
                odometry_fit.windows, odometry_fit.k_heading, odometry_fit.k_along, odometry_fit.median_travel_mm,
                odometry_fit.mean_steps, rad2deg(odometry_fit.heading_error.median),
                rad2deg(odometry_fit.heading_error.mad_sigma), odometry_fit.along_error.median,
                odometry_fit.along_error.mad_sigma, odometry_fit.lateral_error.median,
                odometry_fit.lateral_error.mad_sigma);
  os << buf;
  std::snprintf(buf, sizeof buf,
                "  odometry model: wheel base %.0f mm, k_left = k_right = %.3g mm^2/mm, control floor (%.3g mm^2, "
                "%.3g mm^2, %.3g rad^2)\n",
                odometry.wheel_base_mm, odometry.k_left, odometry.control_variance_floor.x(),
                odometry.control_variance_floor.y(), odometry.control_variance_floor.z());
  os << buf;
  return os.str();
}

}  // namespace stereoloc
