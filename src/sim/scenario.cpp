#include "src/sim/scenario.h"

#include <algorithm>
#include <cmath>

#include "src/core/error.h"

namespace stereoloc {
namespace {

constexpr int kDefaultSteps = 100;  // "every trial consists of 100 steps" (L1981, L2275)

std::string trialLetter(int trial) { return std::string(1, static_cast<char>('a' + trial)); }

// Positions at equal arc-length steps along a rectangle centred on the field centre, starting at
// its top-right corner and running counter-clockwise (thesis 6.3.1/6.3.3, Fig. 6.16 caption
// L2143): first leg -x along the top, then -y, +x, +y. Step = perimeter / steps (INFERRED,
// "the step size in each trial stays the same", L1987).
std::vector<Eigen::Vector2d> rectanglePath(double x0, double y0, double sx, double sy, int steps) {
  const double perimeter = 2.0 * (sx + sy);
  const double step = perimeter / kDefaultSteps;
  std::vector<Eigen::Vector2d> out;
  for (int s = 0; s < steps; ++s) {
    double d = std::fmod(s * step, perimeter);
    Eigen::Vector2d p;
    if (d <= sx) {
      p = {x0 - d, y0};
    } else if ((d -= sx) <= sy) {
      p = {x0 - sx, y0 - d};
    } else if ((d -= sy) <= sx) {
      p = {x0 - sx + d, y0 - sy};
    } else {
      d -= sx;
      p = {x0, y0 - sy + d};
    }
    out.push_back(p);
  }
  return out;
}

struct RectTrial {
  double x0, y0, sx, sy, theta0_deg;
};
// Section 6.3.1, L1987.
const RectTrial kRect[] = {{1200, 950, 900, 600, 180}, {1125, 900, 750, 500, 180}, {1050, 850, 600, 400, 0},
                           {975, 800, 450, 300, 0}};
// Section 6.3.3, L2031-2033: (a), (b) stated; (c)-(e) "the same pattern" with sizes not stated,
// INFERRED as further rectangles centred on (750, 650).
const RectTrial kRectSpin[] = {{1350, 1050, 1200, 800, -90}, {1150, 950, 800, 600, -90},
                               {1250, 1000, 1000, 700, -90}, {1050, 850, 600, 400, -90},
                               {950, 750, 400, 200, -90}};

struct SpinTrial {
  double x, y, theta0_deg, rotation_deg;  // rotation > 0 = clockwise
};
// Section 6.3.2, L2008-2010. (c)-(e): "the other three corners", INFERRED by symmetry;
// (g): start heading not stated, INFERRED -90 as in the 6.5 spin; (h): start heading not
// stated, INFERRED -135 as in (f).
const SpinTrial kSpinAt[] = {{750, 650, -90, 360},  {350, 350, -90, 360},  {350, 950, -90, 360},
                             {1150, 950, -90, 360}, {1150, 350, -90, 360}, {750, 650, -135, 90},
                             {750, 650, -90, 180},  {1050, 650, -135, 90}};

struct LineTrial {
  double x0, y0, theta_deg, dx, dy;  // per-step displacement (mm)
};
// Section 6.3.4, L2055-2060. (f): step size "different", not stated: INFERRED 8 mm.
const LineTrial kLineFixed[] = {{321, 650, 180, 9, 0}, {321, 650, 0, 9, 0},   {321, 450, 180, 9, 0},
                                {321, 850, 0, 9, 0},   {750, 222, 0, 0, 9},   {1300, 650, 180, -8, 0}};
// Section 6.3.5, L2074 and the Fig. 6.24 caption L2318: start x 950, 750, 550, 1050, 450; the text
// gives y0 = 452 and ~9 mm/step, the caption y0 ~ 400 and ~4 mm/step; 452 + 99 * 9 leaves the
// field, so we take y0 = 452 with 4 mm steps (INFERRED). Heading -170 deg, 0.2 deg CW per step.
const double kLineTurnX[] = {950, 750, 550, 1050, 450};

// Section 6.5 line (L2329): start A not stated; INFERRED (190, 550) from the visibility windows
// (first sighting at step 2, two landmarks from step 44) -- see scenarios.md 3.2.
const Eigen::Vector2d kLineStart(190.0, 550.0);
constexpr double kLineStep = 8.9;

Pose2 P(double x, double y, double theta_deg) { return Pose2(x, y, deg2rad(theta_deg)); }

int stepsOr(const ScenarioOptions& o, int fallback) { return o.steps > 0 ? o.steps : fallback; }

void randomWalk(Scenario& sc, int steps, std::mt19937_64& rng) {
  // Constant speed, curvature from a mean-reverting random process, steered back towards the
  // field centre when a look-ahead point leaves the inner area. Turning is bounded so the path
  // is smooth (radius >= speed / max_turn = 100 mm).
  constexpr double speed = 20.0, max_turn = 0.2, margin = 200.0, lookahead = 250.0;
  std::normal_distribution<double> N(0.0, 1.0);
  Pose2 p(750.0, 650.0, 0.0);
  double omega = 0.0;
  for (int s = 0; s < steps; ++s) {
    sc.poses.push_back(p);
    omega = 0.9 * omega + 0.03 * N(rng);
    const Eigen::Vector2d ahead = p.translation() + lookahead * Eigen::Vector2d(std::cos(p.theta), std::sin(p.theta));
    if (ahead.x() < margin || ahead.x() > 1500.0 - margin || ahead.y() < margin || ahead.y() > 1300.0 - margin) {
      const double to_centre = std::atan2(650.0 - p.y, 750.0 - p.x);
      omega = angleDiff(to_centre, p.theta);
    }
    omega = std::clamp(omega, -max_turn, max_turn);
    // An exact arc of length `speed` and heading change omega (B.4/B.5 geometry).
    const double half = 0.5 * omega;
    const double chord = std::fabs(omega) < 1e-12 ? speed : speed * std::sin(half) / half;
    p = Pose2(p.x + chord * std::cos(p.theta + half), p.y + chord * std::sin(p.theta + half), p.theta + omega);
  }
}

}  // namespace

std::vector<std::string> scenarioNames() {
  return {"circle", "line", "spin", "rect", "spin-at", "rect-spin", "line-fixed", "line-turn", "kidnap", "random-walk"};
}

int scenarioTrialCount(const std::string& name) {
  if (name == "rect") return 4;
  if (name == "spin-at") return 8;
  if (name == "rect-spin") return 5;
  if (name == "line-fixed") return 6;
  if (name == "line-turn") return 5;
  for (const std::string& n : scenarioNames())
    if (n == name) return 1;
  std::string list;
  for (const std::string& n : scenarioNames()) list += (list.empty() ? "" : ", ") + n;
  throw Error("unknown scenario '" + name + "' (expected one of: " + list + ")");
}

namespace {

// The drives of section 6.5 and 5.1.3: one trial each, consecutive poses.
void makeDrive(const std::string& name, const ScenarioOptions& o, Scenario& sc) {
  if (name == "circle") {
    // Fig. 6.26, L2315/L2324: radius 500, start [1350 650 90 deg], counter-clockwise, one
    // revolution per 100 steps (3.6 deg, 31.4 mm per step; centre (850, 650) INFERRED).
    const int n = stepsOr(o, kDefaultSteps);
    const double dphi = kTwoPi / kDefaultSteps;
    for (int s = 0; s < n; ++s) {
      const double phi = s * dphi;
      sc.poses.emplace_back(850.0 + 500.0 * std::cos(phi), 650.0 + 500.0 * std::sin(phi), kPi / 2 + phi);
    }
    sc.description = "circle r=500 mm from [1350 650 90deg], CCW, 3.6 deg/step (thesis 6.5, Fig. 6.26)";
  } else if (name == "line") {
    // Fig. 6.27, L2329: heading fixed at 180 deg, reverse to the right in 8.9 mm steps.
    const int n = stepsOr(o, kDefaultSteps);
    for (int s = 0; s < n; ++s) sc.poses.emplace_back(kLineStart.x() + kLineStep * s, kLineStart.y(), kPi);
    sc.description = "line, heading 180 deg, reverse +x in 8.9 mm steps from (190, 550) (thesis 6.5, Fig. 6.27)";
  } else if (name == "spin") {
    // Fig. 6.28, L2330: at [750 650 -90 deg], 180 deg clockwise in 100 steps.
    const int n = stepsOr(o, kDefaultSteps);
    for (int s = 0; s < n; ++s) sc.poses.push_back(P(750, 650, -90.0 - 180.0 * s / kDefaultSteps));
    sc.description = "spin at [750 650 -90deg], 180 deg clockwise, 1.8 deg/step (thesis 6.5, Fig. 6.28)";
  } else {  // kidnap
    // Section 5.1.3, L1637-1644: A to B in 100 steps, carried back to A at step 100 without the
    // robot knowing, then A to B again. A, B not stated: INFERRED the 6.5 line path.
    const int n = stepsOr(o, 2 * kDefaultSteps);
    const int half = std::max(1, n / 2);
    for (int s = 0; s < n; ++s)
      sc.poses.emplace_back(kLineStart.x() + kLineStep * (s % half), kLineStart.y(), kPi);
    sc.carried.assign(n, false);
    if (half < n) sc.carried[half] = true;
    sc.description = "kidnap: line A->B in " + std::to_string(half) + " steps, carried back to A at step " +
                     std::to_string(half) + ", then A->B again (thesis 5.1.3)";
  }
}

// The fix scenarios of section 6.3: independent poses, one trial per place or path.
void makeFixPoses(const std::string& name, int trial, const ScenarioOptions& o, Scenario& sc) {
  if (name == "rect" || name == "rect-spin") {
    const bool spin = name == "rect-spin";
    const RectTrial& r = spin ? kRectSpin[trial] : kRect[trial];
    const int n = stepsOr(o, kDefaultSteps);
    const auto path = rectanglePath(r.x0, r.y0, r.sx, r.sy, n);
    for (int s = 0; s < n; ++s)
      sc.poses.push_back(P(path[s].x(), path[s].y(), r.theta0_deg - (spin ? 3.6 * s : 0.0)));
    sc.independent_poses = true;
    char buf[200];
    std::snprintf(buf, sizeof(buf), "%s trial %s: %gx%g rectangle from (%g, %g), CCW, heading %g deg%s (thesis %s)",
                  name.c_str(), trialLetter(trial).c_str(), r.sx, r.sy, r.x0, r.y0, r.theta0_deg,
                  spin ? " turning 3.6 deg/step CW" : " fixed", spin ? "6.3.3" : "6.3.1");
    sc.description = buf;
  } else if (name == "spin-at") {
    const SpinTrial& t = kSpinAt[trial];
    const int n = stepsOr(o, kDefaultSteps);
    for (int s = 0; s < n; ++s) sc.poses.push_back(P(t.x, t.y, t.theta0_deg - t.rotation_deg * s / kDefaultSteps));
    sc.independent_poses = true;
    char buf[200];
    std::snprintf(buf, sizeof(buf), "spin-at trial %s: at (%g, %g) from %g deg, %g deg clockwise (thesis 6.3.2)",
                  trialLetter(trial).c_str(), t.x, t.y, t.theta0_deg, t.rotation_deg);
    sc.description = buf;
  } else if (name == "line-fixed") {
    const LineTrial& t = kLineFixed[trial];
    const int n = stepsOr(o, kDefaultSteps);
    for (int s = 0; s < n; ++s) sc.poses.push_back(P(t.x0 + t.dx * s, t.y0 + t.dy * s, t.theta_deg));
    sc.independent_poses = true;
    char buf[200];
    std::snprintf(buf, sizeof(buf), "line-fixed trial %s: from (%g, %g), heading %g deg, step (%g, %g) mm (thesis 6.3.4)",
                  trialLetter(trial).c_str(), t.x0, t.y0, t.theta_deg, t.dx, t.dy);
    sc.description = buf;
  } else if (name == "line-turn") {
    const int n = stepsOr(o, kDefaultSteps);
    for (int s = 0; s < n; ++s) sc.poses.push_back(P(kLineTurnX[trial], 452.0 + 4.0 * s, -170.0 - 0.2 * s));
    sc.independent_poses = true;
    char buf[200];
    std::snprintf(buf, sizeof(buf), "line-turn trial %s: from (%g, 452), +y 4 mm/step, heading -170 deg turning 0.2 deg/step CW (thesis 6.3.5)",
                  trialLetter(trial).c_str(), kLineTurnX[trial]);
    sc.description = buf;
  }
}

// The head's pan per step: 0, or the scan of ScenarioOptions::head_scan.
void setHeadPan(const ScenarioOptions& o, Scenario& sc) {
  sc.head_pan.assign(sc.poses.size(), 0.0);
  if (o.head_scan) {
    if (o.head_scan_period_steps < 1) throw Error("scenario: head_scan_period_steps must be >= 1");
    for (size_t s = 0; s < sc.poses.size(); ++s)
      sc.head_pan[s] = o.head_scan_amplitude_rad * std::sin(kTwoPi * static_cast<double>(s) / o.head_scan_period_steps);
  }
}

}  // namespace

Scenario makeScenario(const std::string& name, int trial, const ScenarioOptions& o, std::mt19937_64& rng) {
  const int trials = scenarioTrialCount(name);
  if (trial < 0 || trial >= trials)
    throw Error("scenario '" + name + "': trial " + std::to_string(trial) + " out of range (0.." +
                std::to_string(trials - 1) + ")");
  if (o.steps < 0) throw Error("scenario: steps must be >= 0");
  Scenario sc;
  sc.name = name;
  sc.trial = trial;
  if (name == "circle" || name == "line" || name == "spin" || name == "kidnap") {
    makeDrive(name, o, sc);
  } else if (name == "random-walk") {
    randomWalk(sc, stepsOr(o, 10000), rng);
    sc.description = "random walk, 20 mm/step, smooth, inside the field";
  } else {
    makeFixPoses(name, trial, o, sc);
  }
  if (sc.carried.empty()) sc.carried.assign(sc.poses.size(), false);
  setHeadPan(o, sc);
  return sc;
}

}  // namespace stereoloc
