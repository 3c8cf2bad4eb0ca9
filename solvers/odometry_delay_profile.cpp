#include "solvers/odometry_delay_profile.h"

#include <Eigen/Dense>
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
  // Least-squares parabola through the five delays around the least: cost = a x^2 + b x + c,
  // x = delay - centre.
  Eigen::Matrix<double, 5, 3> A;
  Eigen::Matrix<double, 5, 1> y;
  int row = 0;
  for (double k : {-1.0, -0.5, 0.0, 0.5, 1.0}) {
    const double d = delay_at(best + k), x = d - centre;
    A.row(row) << x * x, x, 1.0;
    y[row] = cost(d) - least;  // about the least, for the conditioning
    ++row;
  }
  const Eigen::Vector3d p = A.colPivHouseholderQr().solve(y);
  if (!(p[0] > 0))
    throw Error("odometry delay: the batch's cost is not convex around " + std::to_string(centre) +
                " s; the data do not determine the delay");
  OdometryDelayEstimate e;
  e.delay_s = centre + std::clamp(-p[1] / (2 * p[0]), -h, h);
  e.sigma_s = 1.0 / std::sqrt(2 * p[0]);
  e.profile.assign(profile.begin(), profile.end());
  return e;
}

double batchCostWithOdometryDelay(const FieldMap& map, const OdometryParams& odometry, const BatchSmootherConfig& config,
                                  const std::vector<Step>& steps, double delay_s) {
  BatchSmootherConfig c = config;
  c.compute_covariance = false;  // the cost is all the profile needs
  c.progress = nullptr;
  BatchSmoother batch(map, odometry, c);
  for (const Step& s : delayOdometry(steps, delay_s)) batch.process(s);
  batch.finish();
  if (!batch.summary().solved)
    throw Error("odometry delay: the batch found no solution at a delay of " + std::to_string(delay_s) + " s");
  return batch.summary().final_cost;
}

}  // namespace stereoloc
