#include "solvers/odometry_delay_profile.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>

#include "src/core/error.h"
#include "src/core/odometry_delay.h"

namespace stereoloc {

void OdometryDelaySearch::validate() const {
  auto check = [](bool ok, const char* field) {
    if (!ok) throw Error(std::string("odometry delay search: ") + field + " is out of range");
  };
  check(std::isfinite(min_s) && std::isfinite(max_s) && min_s < max_s, "min_s < max_s");
  check(std::isfinite(step_s) && step_s > 0 && max_s - min_s >= 2 * step_s, "step_s (at least three delays)");
  check(std::isfinite(prior_sigma_s) && prior_sigma_s >= 0, "prior_sigma_s");
}

OdometryDelayEstimate profileOdometryDelay(const std::function<double(double)>& cost_at,
                                           const OdometryDelaySearch& search) {
  search.validate();
  std::map<double, double> profile;
  auto cost = [&](double delay) {
    const auto it = profile.find(delay);
    if (it != profile.end()) return it->second;
    double c = cost_at(delay);
    if (!std::isfinite(c)) throw Error("odometry delay: the cost at " + std::to_string(delay) + " s is not finite");
    if (search.prior_sigma_s > 0) c += 0.5 * (delay / search.prior_sigma_s) * (delay / search.prior_sigma_s);
    profile[delay] = c;
    return c;
  };
  // Delays by grid index (half-integer: the refinement), so that a delay is evaluated once.
  const double h = search.step_s;
  auto delay_at = [&](double index) { return search.min_s + index * h; };
  const int n = static_cast<int>(std::floor((search.max_s - search.min_s) / h + 1e-9)) + 1;
  int best = 0;
  double least = 0, most = 0;
  for (int i = 0; i < n; ++i) {
    const double c = cost(delay_at(i));
    if (i == 0 || c < least) {
      best = i;
      least = c;
    }
    most = i == 0 ? c : std::max(most, c);
  }
  // Half a unit of 1/2 chi^2: the delays are all within about a standard deviation of each other.
  if (most - least < 0.5)
    throw Error("odometry delay: the batch's cost changes by less than 0.5 over the search; the data do not "
                "determine the delay");
  const double centre = delay_at(best);
  if (best == 0 || best == n - 1)
    throw Error("odometry delay: the batch's cost is least at the edge of the search, " + std::to_string(centre) +
                " s; widen it");
  // Halve the spacing around the least: the least of the grid's best delay and the two half a
  // step either side, then the parabola through it and its neighbours half a step away (all
  // evaluated; a cost far from the least, where the batch may settle in another basin, does not
  // enter).
  const double below = cost(delay_at(best - 0.5)), above = cost(delay_at(best + 0.5));
  const double m = below < least && below <= above ? best - 0.5 : (above < least ? best + 0.5 : best);
  const double c_minus = cost(delay_at(m - 0.5)), c_0 = cost(delay_at(m)), c_plus = cost(delay_at(m + 0.5));
  const double half = 0.5 * h;
  const double a = (c_minus - 2 * c_0 + c_plus) / (2 * half * half);  // cost ~ a x^2 + b x + c
  const double slope = (c_plus - c_minus) / (2 * half);
  if (!(a > 0))
    throw Error("odometry delay: the batch's cost is not convex around " + std::to_string(delay_at(m)) +
                " s; the data do not determine the delay");
  OdometryDelayEstimate e;
  e.delay_s = delay_at(m) + std::clamp(-slope / (2 * a), -half, half);
  e.profile_sigma_s = 1.0 / std::sqrt(2 * a);
  e.sigma_s = e.profile_sigma_s;
  e.profile.assign(profile.begin(), profile.end());
  return e;
}

double batchCostWithOdometryDelay(const FieldMap& map, const OdometryParams& odometry, const BatchSmootherConfig& config,
                                  const std::vector<Step>& steps, double delay_s) {
  BatchSmootherConfig c = config;
  c.compute_covariance = false;  // the cost is all the profile needs
  c.progress = nullptr;
  c.cut_at_reinitialisation = false;
  BatchSmoother batch(map, odometry, c);
  for (Step s : delayOdometry(steps, delay_s)) {
    s.observations.erase(std::remove_if(s.observations.begin(), s.observations.end(),
                                        [](const Observation& o) { return o.landmark_id < 0; }),
                         s.observations.end());
    batch.process(s);
  }
  batch.finish();
  if (!batch.summary().solved)
    throw Error("odometry delay: the batch found no solution at a delay of " + std::to_string(delay_s) + " s");
  return batch.summary().final_cost;
}

OdometryDelayEstimate estimateOdometryDelay(const FieldMap& map, const OdometryParams& odometry,
                                            const BatchSmootherConfig& config, const std::vector<Step>& steps,
                                            const OdometryDelaySearch& search) {
  OdometryDelayEstimate e = profileOdometryDelay(
      [&](double delay_s) { return batchCostWithOdometryDelay(map, odometry, config, steps, delay_s); }, search);
  std::vector<double> intervals;
  for (size_t k = 1; k < steps.size(); ++k)
    if (steps[k].t > steps[k - 1].t) intervals.push_back(steps[k].t - steps[k - 1].t);
  if (!intervals.empty()) {
    std::nth_element(intervals.begin(), intervals.begin() + static_cast<long>(intervals.size() / 2), intervals.end());
    e.resolution_s = intervals[intervals.size() / 2] / std::sqrt(12.0);
  }
  e.sigma_s = std::hypot(e.profile_sigma_s, e.resolution_s);
  return e;
}

}  // namespace stereoloc
