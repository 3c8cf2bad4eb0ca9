// delayOdometry: a step stream's wheel readings re-timed by a delay (src/core/odometry_delay.h).
#include "src/core/odometry_delay.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "test_util.h"

namespace stereoloc {
namespace {

// Steps 0.1 s apart; step 0 reads nothing, step k reads (k, -2k) mm; step 3 has a sighting.
std::vector<Step> rampSteps(int n) {
  std::vector<Step> steps(static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    Step& s = steps[static_cast<size_t>(k)];
    s.step = 10 + k;
    s.t = 5.0 + 0.1 * k;
    s.d_left = k > 0 ? 1.0 * k : 0.0;
    s.d_right = -2.0 * s.d_left;
  }
  steps[3].observations.push_back(Observation{});
  return steps;
}

TEST(OdometryDelay, NoDelayKeepsTheReadings) {
  const std::vector<Step> steps = rampSteps(8);
  const std::vector<Step> same = delayOdometry(steps, 0.0);
  ASSERT_EQ(same.size(), steps.size());
  for (size_t k = 0; k < steps.size(); ++k) {
    EXPECT_EQ(same[k].d_left, steps[k].d_left);
    EXPECT_EQ(same[k].d_right, steps[k].d_right);
  }
}

TEST(OdometryDelay, WholeStepsShiftTheReadingsHalfStepsAverageThem) {
  const std::vector<Step> steps = rampSteps(10);
  // Two steps late: step k moves as step k - 2 read; nothing moved before the first step.
  const std::vector<Step> late = delayOdometry(steps, 0.2);
  for (size_t k = 1; k < steps.size(); ++k) {
    const double want = k >= 3 ? steps[k - 2].d_left : 0.0;
    EXPECT_NEAR(late[k].d_left, want, 1e-9) << k;
    EXPECT_NEAR(late[k].d_right, -2.0 * want, 1e-9) << k;
    EXPECT_EQ(late[k].t, steps[k].t);
    EXPECT_EQ(late[k].step, steps[k].step);
    EXPECT_EQ(late[k].observations.size(), steps[k].observations.size());
  }
  // One step early: step k moves as step k + 1 read; the robot stands after the last step.
  const std::vector<Step> early = delayOdometry(steps, -0.1);
  for (size_t k = 1; k + 1 < steps.size(); ++k) EXPECT_NEAR(early[k].d_left, steps[k + 1].d_left, 1e-9) << k;
  EXPECT_NEAR(early.back().d_left, 0.0, 1e-12);
  // Half a step late: the mean of the step's own reading and the one before (constant speed
  // within each step).
  const std::vector<Step> half = delayOdometry(steps, 0.05);
  for (size_t k = 2; k < steps.size(); ++k)
    EXPECT_NEAR(half[k].d_left, 0.5 * (steps[k - 1].d_left + steps[k].d_left), 1e-9) << k;
  EXPECT_NEAR(half[1].d_left, 0.5 * steps[1].d_left, 1e-9);
}

TEST(OdometryDelay, ARunFromRestToRestKeepsItsTravel) {
  // Uneven step times, two steps at the same time, the robot at rest for over 0.45 s at both
  // ends (so no delay below that moves travel out of the stream).
  std::vector<Step> steps;
  const std::vector<double> t = {0.0, 0.5, 0.65, 0.65, 0.78, 0.95, 0.97, 1.35, 1.75, 2.25, 2.85};
  const std::vector<double> d = {0.0, 0.0, 3.0, 0.0, 4.0, -1.0, 0.5, 7.0, 2.0, 0.0, 0.0};
  for (size_t k = 0; k < t.size(); ++k) {
    Step s;
    s.step = static_cast<long>(k);
    s.t = t[k];
    s.d_left = d[k];
    s.d_right = 2 * d[k];
    steps.push_back(s);
  }
  for (double delay : {-0.4, -0.13, 0.07, 0.25, 0.41}) {
    const std::vector<Step> out = delayOdometry(steps, delay);
    double left = 0, right = 0;
    for (const Step& s : out) {
      ASSERT_TRUE(std::isfinite(s.d_left) && std::isfinite(s.d_right)) << delay;
      left += s.d_left;
      right += s.d_right;
    }
    EXPECT_NEAR(left, 15.5, 1e-9) << delay;
    EXPECT_NEAR(right, 31.0, 1e-9) << delay;
  }
}

TEST(OdometryDelay, TheStreamRetimerGivesTheBatchsReadingsToTheLastBit) {
  // Uneven step times, equal ones, a reading on a zero-length interval; delays shorter and
  // longer than a step, and longer than the stream.
  std::vector<Step> steps;
  const std::vector<double> t = {0.0, 0.1, 0.13, 0.13, 0.3, 0.31, 0.72, 0.9, 0.9, 1.0, 1.6, 1.65, 2.0};
  for (size_t k = 0; k < t.size(); ++k) {
    Step s;
    s.step = static_cast<long>(k);
    s.t = t[k];
    s.d_left = 0.1 + std::sin(3.0 * static_cast<double>(k));
    s.d_right = 0.7 * std::cos(2.0 * static_cast<double>(k));
    steps.push_back(s);
  }
  for (double delay : {0.0, 0.03, 0.1, 0.13, 0.25, 0.6, 3.0}) {
    const std::vector<Step> batch = delayOdometry(steps, delay);
    OdometryRetimer stream(delay);
    for (size_t k = 0; k < steps.size(); ++k) {
      const WheelIncrements d = stream.next(steps[k].t, steps[k].d_left, steps[k].d_right);
      EXPECT_EQ(d.d_left, batch[k].d_left) << delay << " step " << k;
      EXPECT_EQ(d.d_right, batch[k].d_right) << delay << " step " << k;
    }
  }
  EXPECT_NE(test::errorOf([] { OdometryRetimer r(-0.1); }).find("a negative one needs the steps after"),
            std::string::npos);
  OdometryRetimer r(0.2);
  r.next(1.0, 1.0, 1.0);
  EXPECT_NE(test::errorOf([&] { r.next(0.5, 1.0, 1.0); }).find("before the previous"), std::string::npos);
  const WheelIncrements after = r.next(1.1, 2.0, 4.0);  // the refused step changed nothing
  EXPECT_NEAR(after.d_left, 0.0, 1e-12);                // 0.1 s of the 0.2 s delay: still before the motion
  EXPECT_NEAR(r.next(1.3, 2.0, 4.0).d_right, 4.0, 1e-12);
}

TEST(OdometryDelay, BadDelayAndStepsOutOfOrderAreErrors) {
  std::vector<Step> steps = rampSteps(5);
  EXPECT_NE(test::errorOf([&] { delayOdometry(steps, std::nan("")); }).find("not a finite"), std::string::npos);
  steps[3].t = steps[1].t - 0.01;
  const std::string e = test::errorOf([&] { delayOdometry(steps, 0.1); });
  EXPECT_NE(e.find("step 13"), std::string::npos) << e;
}

}  // namespace
}  // namespace stereoloc
