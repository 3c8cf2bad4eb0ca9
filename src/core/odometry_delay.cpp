#include "src/core/odometry_delay.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "src/core/error.h"

namespace stereoloc {
namespace {

// The cumulative reading at time s of knots in time order (t, left, right): linear on the
// interval holding s (the last knot with t_i <= s, and the next, so never an interval of zero
// length), clamped outside the knots. One formula for the batch and the stream, so that they
// agree to the last bit.
template <typename Knots>
WheelIncrements cumulativeAt(const Knots& knots, double s) {
  if (s <= knots.front().t) return {knots.front().left, knots.front().right};
  if (s >= knots.back().t) return {knots.back().left, knots.back().right};
  const auto next = std::upper_bound(knots.begin(), knots.end(), s, [](double v, const auto& k) { return v < k.t; });
  const auto& a = *(next - 1);
  const auto& b = *next;
  const double f = (s - a.t) / (b.t - a.t);
  return {a.left + (b.left - a.left) * f, a.right + (b.right - a.right) * f};
}

struct Knot {
  double t, left, right;
};

}  // namespace

std::vector<Step> delayOdometry(const std::vector<Step>& steps, double delay_s) {
  if (!std::isfinite(delay_s)) throw Error("odometry delay: not a finite number of seconds");
  for (size_t k = 1; k < steps.size(); ++k)
    if (!(steps[k].t >= steps[k - 1].t))
      throw Error("odometry delay: step " + std::to_string(steps[k].step) + " has a time before the previous step's");
  std::vector<Step> out = steps;
  if (delay_s == 0.0 || steps.size() < 2) return out;
  // Cumulative readings at the step times (the first step's reading has no interval: 0).
  std::vector<Knot> knots(steps.size());
  knots[0] = {steps[0].t, 0.0, 0.0};
  for (size_t k = 1; k < steps.size(); ++k)
    knots[k] = {steps[k].t, knots[k - 1].left + steps[k].d_left, knots[k - 1].right + steps[k].d_right};
  for (size_t k = 1; k < steps.size(); ++k) {
    const WheelIncrements a = cumulativeAt(knots, steps[k - 1].t - delay_s), b = cumulativeAt(knots, steps[k].t - delay_s);
    out[k].d_left = b.d_left - a.d_left;
    out[k].d_right = b.d_right - a.d_right;
  }
  return out;
}

OdometryRetimer::OdometryRetimer(double delay_s) : delay_s_(delay_s) {
  if (!(std::isfinite(delay_s) && delay_s >= 0.0 && delay_s <= 10.0))
    throw Error("odometry delay: a stream is re-timed by a delay of 0 to 10 s (a negative one needs the steps after; "
                "re-time offline)");
}

WheelIncrements OdometryRetimer::next(double t, double d_left, double d_right) {
  if (delay_s_ == 0.0) return {d_left, d_right};  // as delayOdometry: the readings unchanged
  if (!std::isfinite(t)) throw Error("odometry delay: a step time is not finite");
  if (knots_.empty()) {
    knots_.push_back({t, 0.0, 0.0});
    return {d_left, d_right};  // the first step: no interval
  }
  const Knot& last = knots_.back();
  if (!(t >= last.t)) throw Error("odometry delay: a step time before the previous step's");
  const double previous_t = last.t;
  knots_.push_back({t, last.left + d_left, last.right + d_right});
  const WheelIncrements a = cumulativeAt(knots_, previous_t - delay_s_), b = cumulativeAt(knots_, t - delay_s_);
  // The next step's interval begins at t - delay: keep the knots from the last one before it
  // (strictly, so that the interpolation there sees the knots delayOdometry sees).
  while (knots_.size() > 2 && knots_[1].t < t - delay_s_) knots_.pop_front();
  return {b.d_left - a.d_left, b.d_right - a.d_right};
}

}  // namespace stereoloc
