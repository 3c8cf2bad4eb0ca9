#include <gtest/gtest.h>

#include <cmath>

#include "src/core/error.h"
#include "src/core/odometry_model.h"
#include "src/sim/scenario.h"

namespace stereoloc {
namespace {

Scenario make(const std::string& name, int trial = 0, ScenarioOptions o = ScenarioOptions(), uint64_t seed = 1) {
  std::mt19937_64 rng(seed);
  return makeScenario(name, trial, o, rng);
}

double stepLength(const Scenario& sc, size_t s) {
  return (sc.poses[s].translation() - sc.poses[s - 1].translation()).norm();
}

TEST(Scenario, EveryNamedScenarioAndTrialBuilds) {
  const auto names = scenarioNames();
  EXPECT_EQ(names.size(), 10u);
  for (const std::string& n : names) {
    const int trials = scenarioTrialCount(n);
    for (int t = 0; t < trials; ++t) {
      ScenarioOptions o;
      if (n == "random-walk") o.steps = 500;
      const Scenario sc = make(n, t, o);
      EXPECT_FALSE(sc.poses.empty()) << n << " " << t;
      EXPECT_EQ(sc.poses.size(), sc.head_pan.size());
      EXPECT_EQ(sc.poses.size(), sc.carried.size());
      for (const Pose2& p : sc.poses) {
        EXPECT_TRUE(p.x > -1 && p.x < 1501 && p.y > -1 && p.y < 1301) << n << " trial " << t << ": " << p.x << " " << p.y;
      }
    }
  }
  EXPECT_EQ(scenarioTrialCount("rect"), 4);
  EXPECT_EQ(scenarioTrialCount("spin-at"), 8);
  EXPECT_EQ(scenarioTrialCount("rect-spin"), 5);
  EXPECT_EQ(scenarioTrialCount("line-fixed"), 6);
  EXPECT_EQ(scenarioTrialCount("line-turn"), 5);
}

TEST(Scenario, RejectsUnknownNameAndTrial) {
  std::mt19937_64 rng(1);
  EXPECT_THROW(makeScenario("square", 0, ScenarioOptions(), rng), Error);
  EXPECT_THROW(makeScenario("rect", 4, ScenarioOptions(), rng), Error);
  EXPECT_THROW(makeScenario("circle", -1, ScenarioOptions(), rng), Error);
}

TEST(Scenario, CircleGeometry) {
  const Scenario sc = make("circle");
  ASSERT_EQ(sc.poses.size(), 100u);
  EXPECT_NEAR(sc.poses[0].x, 1350, 1e-9);
  EXPECT_NEAR(sc.poses[0].y, 650, 1e-9);
  EXPECT_NEAR(sc.poses[0].theta, kPi / 2, 1e-12);
  const double chord = 2 * 500 * std::sin(kPi / 100);
  double length = 0;
  for (size_t s = 1; s < sc.poses.size(); ++s) {
    EXPECT_NEAR((sc.poses[s].translation() - Eigen::Vector2d(850, 650)).norm(), 500, 1e-9);
    EXPECT_NEAR(stepLength(sc, s), chord, 1e-9);
    EXPECT_NEAR(angleDiff(sc.poses[s].theta, sc.poses[s - 1].theta), deg2rad(3.6), 1e-12);  // CCW
    length += stepLength(sc, s);
  }
  EXPECT_NEAR(length, 99 * chord, 1e-6);
  EXPECT_FALSE(sc.independent_poses);
}

TEST(Scenario, LineAndSpinGeometry) {
  const Scenario line = make("line");
  ASSERT_EQ(line.poses.size(), 100u);
  for (size_t s = 1; s < 100; ++s) {
    EXPECT_NEAR(line.poses[s].x - line.poses[s - 1].x, 8.9, 1e-9);  // towards the right
    EXPECT_NEAR(line.poses[s].y, line.poses[0].y, 1e-12);
    EXPECT_NEAR(std::fabs(line.poses[s].theta), kPi, 1e-12);       // facing left: reverse
    const Arc arc = arcBetween(line.poses[s - 1], line.poses[s]);
    EXPECT_NEAR(arc.length, -8.9, 1e-9);
  }
  const Scenario spin = make("spin");
  EXPECT_NEAR(spin.poses[0].theta, deg2rad(-90), 1e-12);
  for (size_t s = 1; s < 100; ++s) {
    EXPECT_EQ(spin.poses[s].translation(), Eigen::Vector2d(750, 650));
    EXPECT_NEAR(angleDiff(spin.poses[s].theta, spin.poses[s - 1].theta), deg2rad(-1.8), 1e-12);  // clockwise
  }
}

TEST(Scenario, GlobalFixTrialsFollowTheThesis) {
  // 6.3.1 (a): 900x600 from (1200, 950), heading 180, CCW, perimeter / 100 = 30 mm steps.
  const Scenario r = make("rect", 0);
  EXPECT_TRUE(r.independent_poses);
  EXPECT_NEAR(r.poses[0].x, 1200, 1e-9);
  EXPECT_NEAR(r.poses[0].y, 950, 1e-9);
  EXPECT_NEAR(r.poses[1].x, 1170, 1e-9);  // first leg runs -x
  for (size_t s = 1; s < r.poses.size(); ++s) {
    EXPECT_NEAR(std::fabs(r.poses[s].theta), kPi, 1e-12);
    EXPECT_LE(stepLength(r, s), 30 + 1e-9);
  }
  EXPECT_NEAR(r.poses[30].x, 300, 1e-9);  // 900 mm along the top = 30 steps
  EXPECT_NEAR(r.poses[30].y, 950, 1e-9);
  // 6.3.3 (a): 1200x800 from (1350, 1050), -90 deg, 3.6 deg CW per step.
  const Scenario rs = make("rect-spin", 0);
  EXPECT_NEAR(rs.poses[0].theta, deg2rad(-90), 1e-12);
  EXPECT_NEAR(angleDiff(rs.poses[10].theta, rs.poses[9].theta), deg2rad(-3.6), 1e-12);
  EXPECT_NEAR(stepLength(rs, 1), 40, 1e-9);
  // 6.3.2 (b): (350, 350), -90 deg, 360 deg CW.
  const Scenario sa = make("spin-at", 1);
  EXPECT_EQ(sa.poses[50].translation(), Eigen::Vector2d(350, 350));
  EXPECT_NEAR(angleDiff(sa.poses[1].theta, sa.poses[0].theta), deg2rad(-3.6), 1e-12);
  // 6.3.2 (f): -135 deg, 90 deg CW.
  const Scenario sf = make("spin-at", 5);
  EXPECT_NEAR(sf.poses[0].theta, deg2rad(-135), 1e-12);
  EXPECT_NEAR(angleDiff(sf.poses[1].theta, sf.poses[0].theta), deg2rad(-0.9), 1e-12);
  // 6.3.4 (e): (750, 222), heading 0, +y in 9 mm steps.
  const Scenario le = make("line-fixed", 4);
  EXPECT_NEAR(le.poses[0].y, 222, 1e-9);
  EXPECT_NEAR(le.poses[10].y - le.poses[9].y, 9, 1e-9);
  EXPECT_NEAR(le.poses[10].theta, 0, 1e-12);
  // 6.3.5 (a): (950, 452), -170 deg turning 0.2 deg CW per step, to about 170 deg at the end.
  const Scenario lt = make("line-turn", 0);
  EXPECT_NEAR(lt.poses[0].x, 950, 1e-9);
  EXPECT_NEAR(lt.poses[0].y, 452, 1e-9);
  EXPECT_NEAR(lt.poses[0].theta, deg2rad(-170), 1e-12);
  EXPECT_NEAR(lt.poses[99].theta, deg2rad(170.2), 1e-9);
}

TEST(Scenario, KidnapCarriesTheRobotBackToA) {
  const Scenario k = make("kidnap");
  ASSERT_EQ(k.poses.size(), 200u);
  EXPECT_TRUE(k.carried[100]);
  EXPECT_FALSE(k.carried[99]);
  EXPECT_FALSE(k.carried[101]);
  EXPECT_EQ(k.poses[100].translation(), k.poses[0].translation());
  EXPECT_GT(k.poses[99].x - k.poses[0].x, 800);
}

TEST(Scenario, RandomWalkIsSmoothInsideAndSeeded) {
  const Scenario a = make("random-walk", 0, ScenarioOptions(), 7);
  ASSERT_EQ(a.poses.size(), 10000u);
  for (size_t s = 1; s < a.poses.size(); ++s) {
    EXPECT_TRUE(a.poses[s].x > 50 && a.poses[s].x < 1450 && a.poses[s].y > 50 && a.poses[s].y < 1250) << s;
    EXPECT_LE(std::fabs(angleDiff(a.poses[s].theta, a.poses[s - 1].theta)), 0.2 + 1e-12);
    EXPECT_NEAR(arcBetween(a.poses[s - 1], a.poses[s]).length, 20, 1e-6);
  }
  const Scenario b = make("random-walk", 0, ScenarioOptions(), 7);
  const Scenario c = make("random-walk", 0, ScenarioOptions(), 8);
  EXPECT_EQ(a.poses.back().vector(), b.poses.back().vector());
  EXPECT_NE(a.poses.back().vector(), c.poses.back().vector());
}

TEST(Scenario, ArcReproducesDrivableMotionThroughTheOdometryModel) {
  for (const char* name : {"circle", "line", "spin"}) {
    const Scenario sc = make(name);
    for (size_t s = 1; s < sc.poses.size(); ++s) {
      const Arc arc = arcBetween(sc.poses[s - 1], sc.poses[s]);
      const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, 75.0);
      const Eigen::Vector3d u = controlVector(w.d_left, w.d_right, 75.0);
      const Pose2 next = compose(sc.poses[s - 1], Pose2(u.x(), u.y(), u.z()));
      EXPECT_LT((next.translation() - sc.poses[s].translation()).norm(), 1e-9) << name << " " << s;
      EXPECT_NEAR(angleDiff(next.theta, sc.poses[s].theta), 0, 1e-12);
    }
  }
}

TEST(Scenario, HeadScanSweepsThePan) {
  ScenarioOptions o;
  o.head_scan = true;
  const Scenario sc = make("circle", 0, o);
  double lo = 0, hi = 0;
  for (double g : sc.head_pan) {
    lo = std::min(lo, g);
    hi = std::max(hi, g);
  }
  EXPECT_NEAR(hi, deg2rad(30), 1e-3);
  EXPECT_NEAR(lo, -deg2rad(30), 1e-3);
  EXPECT_EQ(make("circle").head_pan[10], 0.0);
}

}  // namespace
}  // namespace stereoloc
