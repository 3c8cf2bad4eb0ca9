#include "src/core/observation_correlation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <string>

#include "src/core/error.h"

namespace stereoloc {

double ErrorCorrelation::at(double dt_s) const {
  if (!(dt_s >= 0.0) || !std::isfinite(dt_s)) return 0.0;
  return at_zero * std::exp(-dt_s / time_constant_s);
}

double correlationVarianceFactor(double rho) {
  if (!(rho >= 0.0 && rho <= 1.0)) throw Error("error correlation " + std::to_string(rho) + " is outside [0, 1]");
  rho = std::min(rho, kMaxErrorCorrelation);
  return (1.0 + rho) / (1.0 - rho);
}

namespace {

double median(std::vector<double> v) {
  const size_t n = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(n), v.end());
  double m = v[n];
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + static_cast<long>(n)));
  return m;
}

// Pair products binned by lag: the fit needs only sum g(dt)^2 and sum p g(dt) per tau, and
// within a bin of max_lag / 4096 the lag's spread is negligible against any tau of the grid.
struct LagBin {
  double count = 0, sum_dt = 0, sum_p = 0, sum_pp = 0;
};

}  // namespace

ErrorCorrelationFit fitErrorCorrelation(std::vector<ErrorSample> samples, bool same_key, double max_lag_s) {
  if (!(std::isfinite(max_lag_s) && max_lag_s > 0)) throw Error("error correlation fit: max lag must be positive");
  for (const ErrorSample& s : samples)
    if (!std::isfinite(s.t_s) || !std::isfinite(s.error)) throw Error("error correlation fit: a sample is not finite");
  ErrorCorrelationFit fit;
  if (samples.size() < 2) return fit;
  std::stable_sort(samples.begin(), samples.end(),
                   [](const ErrorSample& a, const ErrorSample& b) { return a.t_s < b.t_s; });

  std::vector<double> e(samples.size());
  for (size_t i = 0; i < samples.size(); ++i) e[i] = samples[i].error;
  const double m = median(e);
  std::vector<double> dev(e.size());
  for (size_t i = 0; i < e.size(); ++i) dev[i] = std::fabs(e[i] - m);
  const double limit = 5.0 * 1.482602218505602 * median(dev);
  std::vector<char> inlier(e.size());
  double sum_sq = 0;
  size_t n_in = 0;
  for (size_t i = 0; i < e.size(); ++i) {
    inlier[i] = dev[i] <= limit;
    if (inlier[i]) {
      sum_sq += (e[i] - m) * (e[i] - m);
      ++n_in;
    }
  }
  if (n_in < 2 || !(sum_sq > 0)) return fit;
  const double mean_sq = sum_sq / static_cast<double>(n_in);
  fit.rms = std::sqrt(mean_sq);

  constexpr int kBins = 4096;
  std::vector<LagBin> bins(kBins);
  for (size_t i = 0; i < samples.size(); ++i) {
    if (!inlier[i]) continue;
    for (size_t j = i + 1; j < samples.size(); ++j) {
      const double dt = samples[j].t_s - samples[i].t_s;
      if (dt > max_lag_s) break;
      if (!inlier[j] || (samples[i].key == samples[j].key) != same_key) continue;
      const double p = (e[i] - m) * (e[j] - m) / mean_sq;
      LagBin& b = bins[std::min(kBins - 1, static_cast<int>(dt / max_lag_s * kBins))];
      b.count += 1;
      b.sum_dt += dt;
      b.sum_p += p;
      b.sum_pp += p * p;
      ++fit.pairs;
    }
  }
  if (fit.pairs < 10) return fit;

  // SSE(a, tau) = sum_pp - 2 a sum g p + a^2 sum g^2 over the bins (g at the bin's mean lag).
  double best_sse = std::numeric_limits<double>::infinity();
  constexpr int kTaus = 241;
  const double tau_min = std::min(0.05, max_lag_s);
  for (int k = 0; k < kTaus; ++k) {
    const double tau = tau_min * std::pow(max_lag_s / tau_min, static_cast<double>(k) / (kTaus - 1));
    double sgg = 0, sgp = 0, spp = 0;
    for (const LagBin& b : bins) {
      if (b.count == 0) continue;
      const double g = std::exp(-(b.sum_dt / b.count) / tau);
      sgg += b.count * g * g;
      sgp += g * b.sum_p;
      spp += b.sum_pp;
    }
    const double a = std::clamp(sgp / sgg, 0.0, 1.0);
    const double sse = spp - 2.0 * a * sgp + a * a * sgg;
    if (sse < best_sse) {
      best_sse = sse;
      fit.correlation.at_zero = a;
      fit.correlation.time_constant_s = tau;
    }
  }
  return fit;
}

void inflateForCorrelatedErrors(std::vector<Step>& steps, const ObservationCorrelation& c) {
  const std::pair<const ErrorCorrelation*, const char*> parts[] = {{&c.range_same, "range_same"},
                                                                   {&c.range_other, "range_other"},
                                                                   {&c.bearing_same, "bearing_same"},
                                                                   {&c.bearing_other, "bearing_other"}};
  for (const auto& [rho, name] : parts) {
    if (!(rho->at_zero >= 0.0 && rho->at_zero <= 1.0))
      throw Error(std::string("correlated errors: ") + name + ".at_zero is outside [0, 1]");
    if (!(std::isfinite(rho->time_constant_s) && rho->time_constant_s > 0))
      throw Error(std::string("correlated errors: ") + name + ".time_constant_s must be positive");
  }
  std::map<int, double> last_seen;  // landmark id -> time of its latest sighting
  // The two latest sightings of distinct landmarks: the latest sighting of a landmark other
  // than the one at hand is one of them.
  int newest_key = 0;
  double newest_t = 0, second_t = 0;
  bool have_newest = false, have_second = false;
  for (size_t i = 0; i < steps.size(); ++i) {
    Step& s = steps[i];
    if (i > 0 && !(s.t >= steps[i - 1].t))
      throw Error("correlated errors: step " + std::to_string(s.step) + " is earlier than the step before it");
    for (Observation& o : s.observations) {
      if (o.landmark_id < 0)
        throw Error("correlated errors: an observation at step " + std::to_string(s.step) + " has no landmark id");
      const auto it = last_seen.find(o.landmark_id);
      const double dt_same = it == last_seen.end() ? std::numeric_limits<double>::infinity() : s.t - it->second;
      double dt_other = std::numeric_limits<double>::infinity();
      if (have_newest && newest_key != o.landmark_id) dt_other = s.t - newest_t;
      else if (have_second) dt_other = s.t - second_t;
      const double fr =
          correlationVarianceFactor(std::max(c.range_same.at(dt_same), c.range_other.at(dt_other)));
      const double fb =
          correlationVarianceFactor(std::max(c.bearing_same.at(dt_same), c.bearing_other.at(dt_other)));
      const Eigen::Vector2d scale(std::sqrt(fr), std::sqrt(fb));
      o.covariance = scale.asDiagonal() * o.covariance * scale.asDiagonal();

      last_seen[o.landmark_id] = s.t;
      if (have_newest && newest_key == o.landmark_id) {
        newest_t = s.t;
      } else {
        if (have_newest) {
          second_t = newest_t;
          have_second = true;
        }
        newest_key = o.landmark_id;
        newest_t = s.t;
        have_newest = true;
      }
    }
  }
}

}  // namespace stereoloc
