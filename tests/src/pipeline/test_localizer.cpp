// The embeddable pipeline (src/pipeline/localizer.h): the same estimates as its estimator fed
// directly, observations of the newest step joining it, late ones inserted or reported too
// late, bad input refused without harm, images through the frontend, memory bounded by W.
#include <gtest/gtest.h>

#include <random>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "solvers/smoother_common.h"
#include "src/core/error.h"
#include "src/core/measurement_model.h"
#include "src/core/odometry_delay.h"
#include "src/pipeline/localizer.h"
#include "src/sim/renderer.h"
#include "kidnapped_walk.h"
#include "test_util.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kP0 = Eigen::Vector3d(10.0, 10.0, 0.02).cwiseAbs2().asDiagonal();

// Resident set size now and its peak since the last resetPeakRss(), in kB.
long rssKb() {
  std::ifstream statm("/proc/self/statm");
  long pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * (sysconf(_SC_PAGESIZE) / 1024);
}
long peakRssKb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}
void resetPeakRss() { std::ofstream("/proc/self/clear_refs") << "5"; }

// A closed circle of constant wheel increments through the MiroSot field, with exact
// range-bearing sightings of the two nearest landmarks in front of the robot.
struct Circle {
  FieldMap map = FieldMap::miroSot();
  OdometryParams odometry;
  Pose2 start{750.0, 350.0, 0.0};
  double d_left = 1.903125, d_right = 2.296875;  // mm per step: a circle of radius 400 mm around (750, 750)
  std::vector<Observation> sight(const Pose2& pose) const {
    std::multimap<double, const Landmark*> near;
    for (const Landmark& lm : map.landmarks()) {
      const Eigen::Vector2d z = predictRangeBearing(pose, lm.xy());
      if (std::fabs(z[1]) < 1.0) near.emplace(z[0], &lm);
    }
    std::vector<Observation> out;
    for (auto it = near.begin(); it != near.end() && out.size() < 2; ++it) {
      const Eigen::Vector2d z = predictRangeBearing(pose, it->second->xy());
      out.push_back(observationFromRangeBearing(it->second->id, it->second->type, z[0], z[1], 10.0, 0.01));
    }
    return out;
  }
};

LocalizerConfig windowConfig(const SyntheticProblem& p) {
  LocalizerConfig c;
  c.map = p.map;
  c.odometry = p.odometry;
  c.init = knownBelief(p.truth[0], kP0);
  c.window.window = 10;
  return c;
}

void expectSame(const Estimate& a, const Estimate& b) {
  EXPECT_EQ(a.step, b.step);
  EXPECT_EQ(toString(a.status), toString(b.status)) << "step " << a.step;
  EXPECT_EQ(a.pose.x, b.pose.x) << "step " << a.step;
  EXPECT_EQ(a.pose.y, b.pose.y) << "step " << a.step;
  EXPECT_EQ(a.pose.theta, b.pose.theta) << "step " << a.step;
  EXPECT_EQ((a.covariance - b.covariance).cwiseAbs().maxCoeff(), 0.0) << "step " << a.step;
}

// 1,000,000 odometry steps at 100 Hz (2.8 hours) on `config`'s tracker, a sighting every 20th:
// the RSS peak over the whole run stays within 10 % of the RSS after 100,000 steps (nothing is
// kept per step), and the run is tracked. The length is what makes a leak of a few bytes per
// step visible.
void expectConstantMemoryOverAMillionSteps(LocalizerConfig config) {
  const Circle c;
  config.init = knownBelief(c.start, kP0);
  Localizer loc(config);
  resetPeakRss();
  Pose2 truth = c.start;
  long rss_100k = 0;
  long tracking = 0;
  for (long k = 0; k < 1000000; ++k) {
    if (k > 0) truth = predictPose(truth, Eigen::Matrix3d::Zero(), c.d_left, c.d_right, c.odometry).pose;
    loc.addOdometry(k, 0.01 * static_cast<double>(k), k > 0 ? c.d_left : 0.0, k > 0 ? c.d_right : 0.0);
    if (k % 20 == 0) loc.addObservations(k, c.sight(truth));
    const Estimate e = loc.estimate();
    if (k % 20 == 0) tracking += e.status == EstimateStatus::Tracking;
    if (k == 100000) rss_100k = rssKb();
  }
  const long peak = peakRssKb();
  ::testing::Test::RecordProperty("rss_100k_kb", std::to_string(rss_100k));
  ::testing::Test::RecordProperty("peak_rss_kb", std::to_string(peak));
  EXPECT_GT(tracking, 49000);  // the run is tracked, not lost and predicting
  EXPECT_LT(std::hypot(loc.estimate().pose.x - truth.x, loc.estimate().pose.y - truth.y), 1.0);
  ASSERT_GT(rss_100k, 0);
  EXPECT_LE(static_cast<double>(peak), 1.10 * static_cast<double>(rss_100k)) << "kB";
  EXPECT_EQ(loc.smoothedTrajectory().size(), config.method == LocalizerMethod::Window ? 5u : 1u);
}

TEST(Localizer, MemoryIsBoundedByTheWindow) {
#ifdef __SANITIZE_ADDRESS__
  GTEST_SKIP() << "sanitizer build: the address sanitizer's quarantine holds freed memory, so RSS grows; checked in the Release build";
#endif
  // About 2.5 s of CPU.
  LocalizerConfig config;
  config.window.window = 5;  // the bound is what is tested; W = 20 costs 4 times as much
  config.window.keep_history = false;
  config.window.observation_model.model = ObservationModel::RangeBearing;
  config.window.sparse_solver = false;  // cheaper for 60 variables
  config.window.max_iterations = 1;     // exact data: the prediction is the solution
  expectConstantMemoryOverAMillionSteps(config);
}

TEST(Localizer, MemoryIsConstantWithTheFilterKeepingNoHistory) {
#ifdef __SANITIZE_ADDRESS__
  GTEST_SKIP() << "sanitizer build: the address sanitizer's quarantine holds freed memory, so RSS grows; checked in the Release build";
#endif
  // Kept, a million estimates would take about 150 MB.
  LocalizerConfig config;
  config.method = LocalizerMethod::Ekf;
  config.ekf.keep_history = false;
  expectConstantMemoryOverAMillionSteps(config);
}

TEST(Localizer, StepsGiveTheEstimatesOfTheWindowFedDirectly) {
  SyntheticProblemOptions o;
  o.steps = 120;
  o.compass_sigma = 0.05;
  const SyntheticProblem p = makeRandomWalkProblem(o, 5);
  const LocalizerConfig config = windowConfig(p);
  Localizer whole(config), split(config);
  SlidingWindowConfig wc = config.window;
  wc.init = config.init;
  SlidingWindowSmoother direct(p.map, p.odometry, wc);
  for (const Step& s : p.steps) {
    const Estimate ref = direct.process(s);
    whole.addStep(s);
    expectSame(whole.estimate(), ref);
    // Odometry first, then the same step's observations: fused with it.
    Step odometry = s;
    odometry.observations.clear();
    split.addStep(odometry);
    if (!s.observations.empty()) {
      EXPECT_EQ(toString(split.addObservations(s.step, s.observations)), "with_step");
    }
    expectSame(split.estimate(), ref);
    EXPECT_GT(split.computeMilliseconds(), 0.0);
  }
  const std::vector<Estimate> a = direct.finish(), b = whole.smoothedTrajectory();
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) expectSame(b[i], a[i]);
  EXPECT_THROW(whole.addOdometry(1000, 0, 1, 1), Error);  // after the end
}

// The self-calibrating EKF through the pipeline: the estimates and the calibration of the filter
// fed directly (the pipeline hands it its rig).
TEST(Localizer, SelfCalibratingEkfGivesTheFiltersEstimatesAndCalibration) {
  SyntheticProblemOptions o;
  o.steps = 80;
  const SyntheticProblem p = makeRandomWalkProblem(o, 6);
  LocalizerConfig config = windowConfig(p);
  config.method = LocalizerMethod::Ekf;
  config.ekf.calibration = SelfCalibrationConfig::parse("odometry,stereo");
  Localizer loc(config);
  EkfConfig ec = config.ekf;
  ec.init = config.init;
  ec.observation_model.rig = config.rig;
  Ekf direct(p.map, p.odometry, ec);
  for (const Step& s : p.steps) {
    const Estimate ref = direct.process(s);
    loc.addStep(s);
    expectSame(loc.estimate(), ref);
  }
  ASSERT_TRUE(loc.calibration());
  EXPECT_EQ(loc.calibration()->wheels, direct.calibration()->wheels);
  EXPECT_EQ(loc.calibration()->head_covariance, direct.calibration()->head_covariance);
  config.ekf.calibration = SelfCalibrationConfig();
  EXPECT_FALSE(Localizer(config).calibration());
}

// A wheel calibration handed over from an earlier run scales the raw increments as they come
// in, and an odometry that runs late against the camera re-times them: the same estimates as
// the window fed the steps scaled and re-timed by delayOdometry, through either entry.
TEST(Localizer, WheelScalesAndTheOdometryDelayApplyToTheIncomingIncrements) {
  SyntheticProblemOptions o;
  o.steps = 60;
  const SyntheticProblem p = makeRandomWalkProblem(o, 8);
  std::vector<Step> scaled = p.steps;
  for (Step& s : scaled) {
    s.d_left *= 1.03;
    s.d_right *= 0.98;
  }
  LocalizerConfig config = windowConfig(p);
  config.wheel_scales = Eigen::Vector2d(1.03, 0.98);
  for (double delay : {0.0, 0.25}) {
    config.odometry_delay_s = delay;
    Localizer by_step(config), by_odometry(config);
    const std::vector<Step> retimed = delayOdometry(scaled, delay);
    SlidingWindowConfig wc = config.window;
    wc.init = config.init;
    SlidingWindowSmoother direct(p.map, p.odometry, wc);
    size_t moved = 0;
    for (size_t k = 0; k < p.steps.size(); ++k) {
      const Step& s = p.steps[k];
      if (std::fabs(retimed[k].d_left - scaled[k].d_left) > 1e-6) ++moved;
      const Estimate ref = direct.process(retimed[k]);
      by_step.addStep(s);
      expectSame(by_step.estimate(), ref);
      by_odometry.addOdometry(s.step, s.t, s.d_left, s.d_right);
      if (!s.observations.empty()) by_odometry.addObservations(s.step, s.observations);
      expectSame(by_odometry.estimate(), ref);
    }
    EXPECT_EQ(moved > p.steps.size() / 2, delay > 0) << delay;
  }
  config.odometry_delay_s = -0.1;  // would need the steps to come
  EXPECT_THROW(Localizer bad(config), Error);
  config.odometry_delay_s = 0.0;
  config.wheel_scales = Eigen::Vector2d(1.0, 0.0);
  EXPECT_THROW(Localizer bad(config), Error);
}

TEST(Localizer, LateObservationsAreInsertedOrTooLate) {
  SyntheticProblemOptions o;
  o.steps = 80;
  const SyntheticProblem p = makeRandomWalkProblem(o, 6);
  LocalizerConfig config = windowConfig(p);
  config.window.window = 4;
  Localizer loc(config);
  SlidingWindowConfig wc = config.window;
  wc.init = config.init;
  SlidingWindowSmoother direct(p.map, p.odometry, wc);
  int inserted = 0;
  for (size_t k = 0; k < p.steps.size(); ++k) {
    Step s = p.steps[k];
    s.observations.clear();
    loc.addStep(s);
    direct.process(s);
    if (k >= 3 && k % 3 == 0) {  // the sightings of three steps ago
      const Step& late = p.steps[k - 3];
      const ObservationDelivery r = loc.addObservations(late.step, late.observations);
      const LateObservationResult ref = direct.insertLate(late.step, late.observations);
      EXPECT_EQ(toString(r), toString(ref.status)) << "step " << late.step;
      inserted += r == ObservationDelivery::Inserted;
      expectSame(loc.estimate(), ref.estimate);
    }
  }
  EXPECT_GT(inserted, 20);
  // Observations of a step long gone, and of a step whose odometry has not come yet.
  EXPECT_EQ(toString(loc.addObservations(2, p.steps[2].observations)), "too_late");
  EXPECT_THROW(loc.addObservations(p.steps.back().step + 1, p.steps[2].observations), Error);

  LocalizerConfig ekf = config;
  ekf.method = LocalizerMethod::Ekf;
  ekf.replay_steps = 0;  // no going back: too late
  Localizer filter(ekf);
  filter.addStep(p.steps[0]);
  filter.addStep(p.steps[1]);
  EXPECT_EQ(toString(filter.addObservations(0, p.steps[0].observations)), "too_late");
  EXPECT_EQ(toString(filter.estimate().status), "tracking");
  ekf.replay_steps = -1;
  EXPECT_THROW(Localizer{ekf}, Error);
}

// A filter goes back for a late observation: restored to its state before the observation's
// step (the particle filter's random stream included), it processes the steps since again.
// Sightings 1-5 steps late then give, once they are in, exactly the estimates of the filter that
// had them in time; older than the replay horizon they are too late and change nothing.
TEST(Localizer, TheFiltersReplayTheirStepsForLateObservations) {
  SyntheticProblemOptions o;
  o.steps = 150;
  o.compass_sigma = 0.05;
  const SyntheticProblem p = makeRandomWalkProblem(o, 8);
  struct Filter {
    const char* name;
    LocalizerMethod method;
    const char* calibration;
    bool kld;  // the particle filter's adaptive sample size
  };
  for (const Filter& f : {Filter{"ekf", LocalizerMethod::Ekf, "", false},
                          Filter{"ekf:calib", LocalizerMethod::Ekf, "odometry", false},
                          Filter{"ekf calibrating odometry and range", LocalizerMethod::Ekf, "odometry,range", false},
                          Filter{"pf", LocalizerMethod::ParticleFilter, "", false},
                          Filter{"pf with KLD-sampling", LocalizerMethod::ParticleFilter, "", true}}) {
    SCOPED_TRACE(f.name);
    LocalizerConfig config = windowConfig(p);
    config.method = f.method;
    config.replay_steps = 6;
    config.ekf.calibration = SelfCalibrationConfig::parse(f.calibration);
    config.particle_filter.particles = 300;
    config.particle_filter.kld.enabled = f.kld;
    config.particle_filter.kld.min_particles = 100;
    Localizer late(config), in_time(config);
    std::mt19937 rng(3);
    std::map<long, long> arrives;  // observations of step s arrive with step arrives[s]
    for (const Step& s : p.steps) arrives[s.step] = s.step + std::uniform_int_distribution<long>(0, 5)(rng);
    int inserted = 0;
    for (size_t k = 0; k < p.steps.size(); ++k) {
      Step odometry = p.steps[k];
      odometry.observations.clear();
      late.addStep(odometry);
      in_time.addStep(p.steps[k]);
      for (size_t j = 0; j <= k; ++j) {  // what arrives now, oldest first
        const Step& s = p.steps[j];
        if (arrives[s.step] != p.steps[k].step || s.observations.empty()) continue;
        const ObservationDelivery r = late.addObservations(s.step, s.observations);
        EXPECT_EQ(r, s.step == p.steps[k].step ? ObservationDelivery::WithStep : ObservationDelivery::Inserted);
        inserted += r == ObservationDelivery::Inserted;
      }
      const Estimate e = late.estimate(), ref = in_time.estimate();
      // Once every observation up to this step has come, the estimates are the in-time filter's.
      bool complete = true;
      for (size_t j = 0; j <= k; ++j) complete &= arrives[p.steps[j].step] <= p.steps[k].step;
      if (complete) expectSame(e, ref);
    }
    EXPECT_GT(inserted, 50);
    for (const Step& s : p.steps)  // the ones still on their way when the odometry ended
      if (arrives[s.step] > p.steps.back().step && !s.observations.empty()) late.addObservations(s.step, s.observations);
    const std::vector<Estimate> a = late.smoothedTrajectory(), b = in_time.smoothedTrajectory();
    ASSERT_EQ(a.size(), b.size());  // no step twice
    for (size_t i = 0; i < a.size(); ++i) expectSame(a[i], b[i]);
    // Beyond the horizon: too late, and the estimate stays what it was.
    Localizer loc(config);
    for (size_t k = 0; k < 20; ++k) {
      Step odometry = p.steps[k];
      odometry.observations.clear();
      loc.addStep(odometry);
    }
    const Estimate before = loc.estimate();
    size_t old = 0;
    while (p.steps[old].observations.empty()) ++old;
    ASSERT_LT(old, 12u);
    EXPECT_EQ(loc.addObservations(p.steps[old].step, p.steps[old].observations), ObservationDelivery::TooLate);
    expectSame(loc.estimate(), before);
  }
}

TEST(Localizer, AFilterStepThatFailsHalfwayIsTakenWithItsOdometryAlone) {
  // A global start whose fix (a plug-in) has nothing before step 10 and fails on its first call
  // after: the Localizer reports the failure, takes the step again from the filter's state
  // before it with its odometry alone, and goes on: every estimate, the failed step's included,
  // is then that of the same filter fed the step without its sightings.
  SyntheticProblemOptions o;
  o.steps = 60;
  const SyntheticProblem p = makeRandomWalkProblem(o, 12);
  for (const LocalizerMethod method : {LocalizerMethod::Ekf, LocalizerMethod::ParticleFilter}) {
    SCOPED_TRACE(toString(method));
    const GlobalFixFunction fix = defaultGlobalFix();
    long failed = -1;
    const GlobalFixFunction late = [&](const Step& s, const FieldMap& map) -> std::optional<PoseFix> {
      return s.step < 10 ? std::nullopt : fix(s, map);
    };
    const auto failingOnce = [&](const Step& s, const FieldMap& map) -> std::optional<PoseFix> {
      if (failed < 0 && s.step >= 10 && s.observations.size() >= 2) {
        failed = s.step;
        throw Error("map server: no answer");
      }
      return late(s, map);
    };
    for (const int replay_steps : {6, 0}) {
      SCOPED_TRACE(replay_steps);
      LocalizerConfig config = windowConfig(p);
      config.init = InitialBelief();
      config.method = method;
      config.replay_steps = replay_steps;
      config.particle_filter.particles = 300;
      config.ekf.global_fix = config.particle_filter.global_fix = failingOnce;
      failed = -1;
      Localizer failing(config);
      std::vector<Estimate> out;
      int errors = 0;
      for (const Step& s : p.steps) {
        failing.addStep(s);
        try {
          out.push_back(failing.estimate());
        } catch (const Error& e) {
          ++errors;
          EXPECT_NE(std::string(e.what()).find("map server: no answer"), std::string::npos);
          out.push_back(failing.estimate());  // the step's odometry was taken
        }
      }
      ASSERT_EQ(errors, 1);
      ASSERT_GE(failed, 10);
      config.ekf.global_fix = config.particle_filter.global_fix = late;
      Localizer reference(config);
      for (size_t k = 0; k < p.steps.size(); ++k) {
        Step s = p.steps[k];
        if (s.step == failed) {
          s.observations.clear();
          s.compass.reset();
        }
        reference.addStep(s);
        expectSame(out[k], reference.estimate());
      }
      EXPECT_EQ(toString(out.back().status), "tracking");
    }
  }
}

TEST(Localizer, AReplayThatFailsHalfwayTakesThatStepWithItsOdometryAlone) {
  // Every step's sightings arrive two steps late; the robot is kidnapped at step 100, and the
  // global fix the lost filter asks for (a plug-in) fails on its first call after: the filter
  // meets it while replaying for late sightings. The delivery reports the failure, the replay
  // takes that step with its odometry alone and goes on with the steps after it: every estimate
  // is then that of the same deliveries without the failed step's sightings.
  const SyntheticProblem p = test::kidnappedWalk();
  for (const LocalizerMethod method : {LocalizerMethod::Ekf, LocalizerMethod::ParticleFilter}) {
    SCOPED_TRACE(toString(method));
    const GlobalFixFunction fix = defaultGlobalFix();
    long failed = -1;
    LocalizerConfig config = windowConfig(p);
    config.method = method;
    config.replay_steps = 6;
    config.particle_filter.particles = 300;
    config.ekf.global_fix = config.particle_filter.global_fix = [&](const Step& s, const FieldMap& map) {
      if (failed < 0 && s.step >= 100 && s.observations.size() >= 2) {
        failed = s.step;
        throw Error("map server: no answer");
      }
      return fix(s, map);
    };
    const auto feed = [&](Localizer& loc, long skip, int* errors) {
      std::vector<Estimate> out;
      for (size_t k = 0; k < p.steps.size(); ++k) {
        Step odometry = p.steps[k];
        odometry.observations.clear();
        loc.addStep(odometry);
        if (k >= 2 && !p.steps[k - 2].observations.empty() && p.steps[k - 2].step != skip) {
          try {
            EXPECT_EQ(loc.addObservations(p.steps[k - 2].step, p.steps[k - 2].observations),
                      ObservationDelivery::Inserted);
          } catch (const Error& e) {
            ++*errors;
            EXPECT_NE(std::string(e.what()).find("map server: no answer"), std::string::npos);
          }
        }
        out.push_back(loc.estimate());
      }
      return out;
    };
    int errors = 0;
    Localizer failing(config);
    const std::vector<Estimate> a = feed(failing, -1, &errors);
    ASSERT_EQ(errors, 1);
    ASSERT_GE(failed, 100);
    config.ekf.global_fix = config.particle_filter.global_fix = fix;
    Localizer reference(config);
    const std::vector<Estimate> b = feed(reference, failed, &errors);
    EXPECT_EQ(errors, 1);
    for (size_t k = 0; k < a.size(); ++k) expectSame(a[k], b[k]);
  }
}

TEST(Localizer, BadInputIsRefusedAndChangesNothing) {
  SyntheticProblemOptions o;
  o.steps = 12;
  const SyntheticProblem p = makeRandomWalkProblem(o, 7);
  Localizer loc(windowConfig(p)), ref(windowConfig(p));
  for (size_t k = 0; k < 8; ++k) {
    loc.addStep(p.steps[k]);
    ref.addStep(p.steps[k]);
  }
  EXPECT_THROW(loc.addStep(p.steps[3]), Error);  // a step going backwards
  Step nan = p.steps[8];
  nan.d_left = std::nan("");
  EXPECT_THROW(loc.addStep(nan), Error);
  Step earlier = p.steps[8];  // a later step whose clock went back
  earlier.t = p.steps[7].t - 0.05;
  EXPECT_NE(test::errorOf([&] { loc.addStep(earlier); }).find("is earlier than step 7"), std::string::npos);
  std::vector<Observation> unknown = p.steps[7].observations;
  ASSERT_FALSE(unknown.empty());
  unknown[0].landmark_id = 4242;
  EXPECT_THROW(loc.addObservations(7, unknown), Error);
  const cv::Mat small(120, 160, CV_8UC3, cv::Scalar(0, 0, 0));
  EXPECT_THROW(loc.addImages(7, small, small), Error);
  EXPECT_THROW(loc.addImageFiles(7, "/nonexistent/left.png", "/nonexistent/right.png"), Error);
  for (size_t k = 8; k < p.steps.size(); ++k) {
    loc.addStep(p.steps[k]);
    ref.addStep(p.steps[k]);
    expectSame(loc.estimate(), ref.estimate());
  }
  EXPECT_THROW(localizerMethodFromString("kalman"), Error);
  EXPECT_EQ(toString(localizerMethodFromString("pf")), "pf");
}

TEST(Localizer, ImagesGoThroughTheFrontend) {
  LocalizerConfig config;
  const Pose2 pose(300.0, 650.0, 0.0);  // facing the right goal from the left half
  config.init = knownBelief(pose, kP0);
  RenderOptions ro;
  ro.compute_truth = false;
  const StereoRenderer renderer(config.map, config.rig, ro);
  const StereoImages img = renderer.render(pose, 0.0, {});
  Localizer loc(config);
  loc.addOdometry(0, 0.0, 0.0, 0.0);
  EXPECT_EQ(toString(loc.addImages(0, img.left, img.right)), "with_step");
  const Estimate e = loc.estimate();
  ImageObserver observer(config.rig, config.map, config.frontend);
  const std::vector<Observation> expected = observer.observe(img.left, img.right, 0.0);
  ASSERT_FALSE(expected.empty());
  EXPECT_EQ(loc.frontendStats().pairs, 1);
  EXPECT_EQ(loc.frontendStats().observations, static_cast<long>(expected.size()));
  EXPECT_EQ(toString(e.status), "tracking");
  EXPECT_LT(std::hypot(e.pose.x - pose.x, e.pose.y - pose.y), 10.0);
}

}  // namespace
}  // namespace stereoloc
