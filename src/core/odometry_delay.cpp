#include "src/core/odometry_delay.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "src/core/error.h"

namespace stereoloc {

std::vector<Step> delayOdometry(const std::vector<Step>& steps, double delay_s) {
  if (!std::isfinite(delay_s)) throw Error("odometry delay: not a finite number of seconds");
  for (size_t k = 1; k < steps.size(); ++k)
    if (!(steps[k].t >= steps[k - 1].t))
      throw Error("odometry delay: step " + std::to_string(steps[k].step) + " has a time before the previous step's");
  std::vector<Step> out = steps;
  if (delay_s == 0.0 || steps.size() < 2) return out;
  // Cumulative readings at the step times (the first step's reading has no interval: 0).
  const size_t n = steps.size();
  std::vector<double> t(n), left(n, 0.0), right(n, 0.0);
  for (size_t k = 0; k < n; ++k) {
    t[k] = steps[k].t;
    if (k > 0) {
      left[k] = left[k - 1] + steps[k].d_left;
      right[k] = right[k - 1] + steps[k].d_right;
    }
  }
  // The cumulative reading at time s: linear on the step interval holding s (the last with
  // t_i <= s < t_{i+1}, so never one of zero length), clamped outside the stream.
  auto at = [&](double s, const std::vector<double>& c) {
    if (s <= t.front()) return c.front();
    if (s >= t.back()) return c.back();
    const size_t i = static_cast<size_t>(std::upper_bound(t.begin(), t.end(), s) - t.begin()) - 1;
    return c[i] + (c[i + 1] - c[i]) * (s - t[i]) / (t[i + 1] - t[i]);
  };
  for (size_t k = 1; k < n; ++k) {
    const double a = t[k - 1] - delay_s, b = t[k] - delay_s;
    out[k].d_left = at(b, left) - at(a, left);
    out[k].d_right = at(b, right) - at(a, right);
  }
  return out;
}

}  // namespace stereoloc
