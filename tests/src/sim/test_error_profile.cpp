#include "src/sim/error_profile.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <string>

#include <opencv2/calib3d.hpp>

#include "src/core/error.h"
#include "src/sim/raw_render.h"
#include "src/sim/simulator.h"
#include "test_util.h"

namespace stereoloc {
namespace {

struct Moments {
  double n = 0, sum = 0, sum2 = 0;
  void add(double x) {
    n += 1;
    sum += x;
    sum2 += x * x;
  }
  double mean() const { return sum / n; }
  double sd() const { return std::sqrt(std::max(0.0, sum2 / n - mean() * mean())); }
};

// Sample mean within 4 standard errors of `mean`, sample sd within 6 % of `sd` (its standard
// error is sd / sqrt(2 n) = 1.1 % at n = 4000).
void expectDistribution(const Moments& m, double mean, double sd, const char* what) {
  EXPECT_NEAR(m.mean(), mean, 4.0 * sd / std::sqrt(m.n)) << what;
  EXPECT_NEAR(m.sd(), sd, 0.06 * sd) << what;
}

TEST(ErrorProfile, DrawnErrorsReproduceTheirStatedDistributions) {
  const ErrorProfile p = ErrorProfile::realistic();
  std::mt19937_64 rng(42);
  const size_t steps = 20;
  Moments focal, pp, base, rot, tilt, height, k1, k2, tang, k1_est, offset, wheel, wbase, clock, pitch, roll, slip_amount;
  double slips = 0, slip_steps = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    const DrawnErrors e = drawErrors(p, steps, rng);
    for (int c = 0; c < 2; ++c) {
      focal.add(e.focal_rel[c]);
      pp.add(e.principal_px[c][0]);
      pp.add(e.principal_px[c][1]);
      k1.add(e.distortion[c][0]);
      k2.add(e.distortion[c][1]);
      tang.add(e.distortion[c][2]);
      tang.add(e.distortion[c][3]);
      k1_est.add(e.distortion_given[c][0] - e.distortion[c][0]);
      wheel.add(e.wheel_radius_rel[c]);
    }
    base.add(e.baseline_rel);
    for (double r : e.relative_rotation_rad) rot.add(r);
    tilt.add(e.tilt_rad);
    height.add(e.height_mm);
    offset.add(e.exposure_offset_s);
    wbase.add(e.wheel_base_rel);
    clock.add(e.time_offset_s);
    for (size_t s = 0; s < steps; ++s) {
      pitch.add(e.pitch_rad[s]);
      roll.add(e.roll_rad[s]);
      slip_steps += 1;
      if (e.slip_left[s] > 0 || e.slip_right[s] > 0) {
        EXPECT_FALSE(e.slip_left[s] > 0 && e.slip_right[s] > 0);
        slips += 1;
        slip_amount.add(e.slip_left[s] + e.slip_right[s]);
      }
    }
  }
  expectDistribution(focal, 0, p.focal_rel_sigma, "focal");
  expectDistribution(pp, 0, p.principal_sigma_px, "principal point");
  expectDistribution(base, 0, p.baseline_rel_sigma, "baseline");
  expectDistribution(rot, 0, p.relative_rotation_sigma_rad, "relative rotation");
  expectDistribution(tilt, 0, p.tilt_sigma_rad, "tilt");
  expectDistribution(height, 0, p.height_sigma_mm, "height");
  expectDistribution(k1, p.k1_mean, p.k1_sigma, "k1");
  expectDistribution(k2, p.k2_mean, p.k2_sigma, "k2");
  expectDistribution(tang, 0, p.tangential_sigma, "tangential");
  expectDistribution(k1_est, 0, p.k1_estimate_sigma, "k1 estimate");
  expectDistribution(offset, 0, p.exposure_offset_max_s / std::sqrt(3.0), "exposure offset (uniform)");
  expectDistribution(wheel, 0, p.wheel_radius_rel_sigma, "wheel radius");
  expectDistribution(wbase, 0, p.wheel_base_rel_sigma, "wheel base");
  expectDistribution(clock, 0, p.time_offset_sigma_s, "time offset");
  expectDistribution(pitch, 0, p.pitch_sigma_rad, "pitch");
  expectDistribution(roll, 0, p.roll_sigma_rad, "roll");
  const double q = p.slip_probability, n = slip_steps;
  EXPECT_NEAR(slips / n, q, 4.0 * std::sqrt(q * (1 - q) / n));
  expectDistribution(slip_amount, 0.5 * (p.slip_min + p.slip_max), (p.slip_max - p.slip_min) / std::sqrt(12.0), "slip");
}

TEST(ErrorProfile, FilesRoundTripAndShippedRealisticMatchesBuiltIn) {
  test::TempDir dir;
  ErrorProfile::realistic().save(dir.file("p.yaml"));
  const ErrorProfile back = ErrorProfile::named(dir.file("p.yaml"));
  const ErrorProfile shipped = ErrorProfile::load(std::string(STEREOLOC_DATA_DIR) + "/profile_realistic.yaml");
  const ErrorProfile r = ErrorProfile::realistic();
  for (const ErrorProfile* p : {&back, &shipped}) {
    EXPECT_EQ(p->name, "realistic");
    EXPECT_DOUBLE_EQ(p->focal_rel_sigma, r.focal_rel_sigma);
    EXPECT_DOUBLE_EQ(p->k1_mean, r.k1_mean);
    EXPECT_DOUBLE_EQ(p->slip_max, r.slip_max);
    EXPECT_DOUBLE_EQ(p->time_offset_sigma_s, r.time_offset_sigma_s);
    EXPECT_EQ(p->exposure_samples, r.exposure_samples);
  }
  EXPECT_TRUE(ErrorProfile::named("ideal").isIdeal());
  EXPECT_FALSE(r.isIdeal());
  std::ofstream(dir.file("bad.yaml")) << "%YAML:1.0\n---\nfocal_rel_sigma: 0.01\nwheel_bse_rel_sigma: 0.02\n";
  try {
    ErrorProfile::load(dir.file("bad.yaml"));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(dir.file("bad.yaml") + ": wheel_bse_rel_sigma: unknown parameter"),
              std::string::npos)
        << e.what();
  }
  std::ofstream(dir.file("neg.yaml")) << "%YAML:1.0\n---\nbaseline_rel_sigma: -0.01\n";
  EXPECT_THROW(ErrorProfile::load(dir.file("neg.yaml")), Error);
}

// The encoders read the true wheel motion through the true radii and wheel base: with only
// those errors switched on and noise-free encoders, the readings are the nominal increments of
// the true path scaled by 1 / (1 + e) per wheel.
TEST(ErrorProfile, SimulatedOdometryCarriesWheelErrors) {
  SimulationConfig cfg;
  cfg.encoder_k = 0.0;
  cfg.profile.name = "wheels";
  cfg.profile.wheel_radius_rel_sigma = 0.01;
  cfg.profile.wheel_base_rel_sigma = 0.03;
  SimulationTrace trace;
  const Dataset d = simulate("circle", 0, cfg, 5, &trace);
  const DrawnErrors& e = trace.errors;
  ASSERT_NE(e.wheel_radius_rel[0], 0.0);
  const double wb = cfg.wheel_base_mm * (1 + e.wheel_base_rel);
  for (size_t s = 1; s < d.steps.size(); ++s) {
    const Arc arc = arcBetween(d.groundtruth[s - 1].value(), d.groundtruth[s].value());
    const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, wb);
    EXPECT_NEAR(d.steps[s].d_left, w.d_left / (1 + e.wheel_radius_rel[0]), 1e-9);
    EXPECT_NEAR(d.steps[s].d_right, w.d_right / (1 + e.wheel_radius_rel[1]), 1e-9);
  }
  // The ideal profile leaves the dataset exactly as the exact world makes it.
  SimulationConfig ideal;
  const Dataset a = simulate("circle", 0, ideal, 5), b = simulate("circle", 0, SimulationConfig(), 5);
  EXPECT_EQ(a.description, b.description);
  EXPECT_FALSE(a.rig.calibration());
}

// A wheel drift: each wheel's radius walks with its own travel (increments N(0, s^2 |d| / 1 m)),
// the wheel base with the mean travel; the draws come after all others, so the rest of the
// draw is the profile's without the drift; the simulated readings carry the walked radii.
TEST(ErrorProfile, WheelDriftWalksWithTheTravelAfterTheOtherDraws) {
  ErrorProfile p = ErrorProfile::realistic();
  const ErrorProfile plain = p;
  p.wheel_radius_drift = 0.003;
  p.wheel_base_drift = 0.01;
  const size_t steps = 2000;
  std::vector<WheelIncrements> travel(steps);
  for (size_t s = 1; s < steps; ++s) travel[s] = {20.0 + static_cast<double>(s % 7), -5.0 - static_cast<double>(s % 3)};
  std::mt19937_64 a(9), b(9);
  const DrawnErrors e = drawErrors(p, steps, a, travel), f = drawErrors(plain, steps, b);
  EXPECT_EQ(e.wheel_radius_rel[0], f.wheel_radius_rel[0]);
  EXPECT_EQ(e.slip_left, f.slip_left);
  EXPECT_EQ(e.roll_rad, f.roll_rad);
  EXPECT_TRUE(f.wheel_radius_drift_left.empty());
  ASSERT_EQ(e.wheel_radius_drift_left.size(), steps);
  EXPECT_EQ(e.wheel_radius_drift_left[0], 0.0);
  Moments left, right, base;
  for (size_t s = 1; s < steps; ++s) {
    const double l = std::fabs(travel[s].d_left) / 1000, r = std::fabs(travel[s].d_right) / 1000;
    left.add((e.wheel_radius_drift_left[s] - e.wheel_radius_drift_left[s - 1]) / std::sqrt(l));
    right.add((e.wheel_radius_drift_right[s] - e.wheel_radius_drift_right[s - 1]) / std::sqrt(r));
    base.add((e.wheel_base_drift[s] - e.wheel_base_drift[s - 1]) / std::sqrt(0.5 * (l + r)));
  }
  expectDistribution(left, 0, p.wheel_radius_drift, "left wheel's walk");
  expectDistribution(right, 0, p.wheel_radius_drift, "right wheel's walk");
  expectDistribution(base, 0, p.wheel_base_drift, "wheel base's walk");
  EXPECT_THROW(drawErrors(p, steps, a), Error);  // a drift without the travel
  ErrorProfile bad = p;
  bad.wheel_base_drift = 0.2;
  try {
    bad.validate();
    FAIL() << "a wheel base drift of 0.2 per sqrt(m) was accepted";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("wheel_base_drift"), std::string::npos) << err.what();
  }

  SimulationConfig cfg;
  cfg.encoder_k = 0.0;
  cfg.profile.name = "drifting wheels";
  cfg.profile.wheel_radius_drift = 0.01;
  cfg.profile.wheel_base_drift = 0.02;
  cfg.scenario.steps = 300;
  SimulationTrace trace;
  const Dataset d = simulate("random-walk", 0, cfg, 5, &trace);
  const DrawnErrors& t = trace.errors;
  ASSERT_EQ(t.wheel_radius_drift_left.size(), d.steps.size());
  EXPECT_GT(std::fabs(t.wheel_radius_drift_left.back()), 1e-4);
  for (size_t s = 1; s < d.steps.size(); ++s) {
    const Arc arc = arcBetween(d.groundtruth[s - 1].value(), d.groundtruth[s].value());
    const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, cfg.wheel_base_mm * (1 + t.wheel_base_drift[s]));
    EXPECT_NEAR(d.steps[s].d_left, w.d_left / (1 + t.wheel_radius_drift_left[s]), 1e-9);
    EXPECT_NEAR(d.steps[s].d_right, w.d_right / (1 + t.wheel_radius_drift_right[s]), 1e-9);
  }
  test::TempDir dir;
  t.save(dir.file("errors.yaml"), cfg.profile);
  cv::FileStorage fs(dir.file("errors.yaml"), cv::FileStorage::READ);
  std::vector<double> saved;
  fs["wheel_radius_drift_left"] >> saved;
  EXPECT_EQ(saved.size(), d.steps.size());
}

// Raw images through lens distortion: a landmark's raw truth pixel, undistorted with an exact
// calibration of the lens, lands where the calibration's rectified rig projects the landmark;
// and the raw image shows the field where the ideal one does after rectification.
TEST(RawPairRenderer, RawTruthUndistortsOntoTheRectifiedProjection) {
  ErrorProfile p;
  p.name = "lens";
  p.k1_mean = -0.2;
  p.k2_mean = 0.05;
  std::mt19937_64 rng(3);
  const DrawnErrors e = drawErrors(p, 1, rng);
  const StereoRig nominal;
  const StereoCalibration given = givenCalibration(nominal, e);
  const StereoRig rectified(nominal.params(), given);
  Scenario sc;
  sc.poses = {Pose2(300, 650, 0.0)};  // looking at the yellow goal from the field
  sc.head_pan = {0.0};
  sc.carried = {false};
  RenderOptions opt;
  opt.compute_truth = true;
  const RawPairRenderer renderer(FieldMap::miroSot(), nominal.params(), p, e, opt, 0.1);
  const StereoImages raw = renderer.render(sc, 0, {}, 1);
  int checked = 0;
  for (const ImageLandmark& l : raw.truth.left.landmarks) {
    std::vector<cv::Point2d> in{{l.pixel.x(), l.pixel.y()}}, out;
    cv::undistortPoints(in, out, given.K1, given.D1, given.R1, given.P1,
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12));
    const Landmark lm = FieldMap::miroSot().at(l.id);  // a copy: the map is a temporary
    const Eigen::Vector2d local = transformToLocal(sc.poses[0], lm.xy());
    const auto px = rectified.project(Eigen::Vector3d(local.x(), local.y(), lm.position.z()), 0.0);
    ASSERT_TRUE(px);
    EXPECT_NEAR(out[0].x, px->u_left, 1e-3) << l.id;
    EXPECT_NEAR(out[0].y, px->v_left, 1e-3) << l.id;
    ++checked;
  }
  EXPECT_GE(checked, 2);
}

}  // namespace
}  // namespace stereoloc
