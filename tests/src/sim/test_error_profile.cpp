#include "src/sim/error_profile.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>

#include <opencv2/calib3d.hpp>

#include "src/core/error.h"
#include "src/core/measurement_model.h"
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
  // The hand-built field's profile is the realistic one on a field 2 mm off.
  const ErrorProfile field = ErrorProfile::named(std::string(STEREOLOC_DATA_DIR) + "/profile_hand_built_field.yaml");
  EXPECT_EQ(field.name, "hand_built_field");
  EXPECT_EQ(field.field_dimension_sigma_mm, 2.0);
  ErrorProfile same = field;
  same.name = r.name;
  same.field_dimension_sigma_mm = 0.0;
  test::TempDir other;
  same.save(other.file("a.yaml"));
  r.save(other.file("b.yaml"));
  EXPECT_EQ(test::readFile(other.file("a.yaml")), test::readFile(other.file("b.yaml")));
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

// A hand-built field: its dimensions drawn after every other error, the true landmarks where
// the true dimensions put them, and the simulated robot seeing the true field, not the map.
TEST(ErrorProfile, FieldDimensionsDrawAfterTheOtherErrorsAndMoveTheLandmarks) {
  ErrorProfile p = ErrorProfile::realistic();
  const ErrorProfile plain = p;
  p.field_dimension_sigma_mm = 2.0;
  Moments dims;
  for (uint64_t seed = 0; seed < 500; ++seed) {
    std::mt19937_64 a(seed), b(seed);
    const DrawnErrors e = drawErrors(p, 3, a), f = drawErrors(plain, 3, b);
    if (seed == 0) {
      EXPECT_EQ(e.tilt_rad, f.tilt_rad);
      EXPECT_EQ(e.roll_rad, f.roll_rad);
      EXPECT_EQ(e.slip_right, f.slip_right);
      EXPECT_TRUE(f.field_dimension_mm.empty());
    }
    ASSERT_EQ(e.field_dimension_mm.size(), std::size(kFieldDimensions));
    for (double v : e.field_dimension_mm) dims.add(v);
  }
  expectDistribution(dims, 0.0, 2.0, "field dimensions");

  DrawnErrors e;
  e.field_dimension_mm.assign(std::size(kFieldDimensions), 0.0);
  e.field_dimension_mm[0] = 8.0;   // length
  e.field_dimension_mm[1] = -6.0;  // width
  e.field_dimension_mm[2] = 4.0;   // goal width
  e.field_dimension_mm[4] = 3.0;   // centre circle radius
  e.field_dimension_mm[7] = -5.0;  // penalty area depth
  const FieldMap given = FieldMap::miroSot();
  const FieldMap truth = trueFieldMap(given, e);
  ASSERT_EQ(truth.landmarks().size(), given.landmarks().size());
  auto at = [](const FieldMap& m, const std::string& name) {
    for (const Landmark& l : m.landmarks())
      if (l.name == name) return Eigen::Vector3d(l.position);
    ADD_FAILURE() << "no landmark " << name;
    return Eigen::Vector3d(Eigen::Vector3d::Zero());
  };
  const FieldGeometry g;
  const double W = g.width - 6.0, L = g.length + 8.0;
  EXPECT_NEAR(at(truth, "yellow_goal_y850").x(), L, 1e-9);
  EXPECT_NEAR(at(truth, "yellow_goal_y850").y(), 0.5 * (W + g.goal_width + 4.0), 1e-9);
  EXPECT_NEAR(at(truth, "halfway_junction_y1300").x(), 0.5 * L, 1e-9);
  EXPECT_NEAR(at(truth, "halfway_junction_y1300").y(), W, 1e-9);
  EXPECT_NEAR(at(truth, "halfway_circle_y400").y(), 0.5 * W - (g.centre_circle_radius + 3.0), 1e-9);
  EXPECT_NEAR(at(truth, "yellow_penalty_area_corner_y250").x(), L - (g.penalty_area_depth - 5.0), 1e-9);
  for (size_t i = 0; i < given.landmarks().size(); ++i) {
    EXPECT_EQ(truth.landmarks()[i].id, given.landmarks()[i].id);
    EXPECT_EQ(truth.landmarks()[i].name, given.landmarks()[i].name);
  }
  const FieldMap same = trueFieldMap(given, DrawnErrors());
  for (size_t i = 0; i < given.landmarks().size(); ++i)
    EXPECT_EQ(same.landmarks()[i].position, given.landmarks()[i].position);
  // Only a map its geometry derives can be moved by its dimensions.
  std::vector<Landmark> own = given.landmarks();
  own[3].position.x() += 1.0;
  const FieldMap edited("edited", given.bounds(), own, *given.geometry());
  const FieldMap bare("bare", given.bounds(), given.landmarks());
  for (const FieldMap* m : {&edited, &bare}) {
    try {
      trueFieldMap(*m, e);
      FAIL() << m->name() << " was moved";
    } catch (const Error& err) {
      EXPECT_NE(std::string(err.what()).find("'" + m->name() + "'"), std::string::npos) << err.what();
    }
  }
  ErrorProfile bad = p;
  bad.field_dimension_sigma_mm = 25.0;
  EXPECT_THROW(bad.validate(), Error);

  // Noise-free sightings of a field 20 mm off: where the true field has the landmarks.
  SimulationConfig cfg;
  cfg.encoder_k = 0.0;
  cfg.pixel_sigma = 0.0;
  cfg.landmarks = LandmarkSet::All;
  cfg.profile.name = "field only";
  cfg.profile.field_dimension_sigma_mm = 20.0;
  SimulationTrace trace;
  const Dataset d = simulate("circle", 0, cfg, 4, &trace);
  const FieldMap world = trueFieldMap(d.map, trace.errors);
  double moved = 0;
  size_t count = 0;
  for (size_t s = 0; s < d.steps.size(); ++s)
    for (const Observation& o : d.steps[s].observations) {
      const Eigen::Vector2d z = predictRangeBearing(*d.groundtruth[s], world.at(o.landmark_id).xy());
      EXPECT_NEAR(o.range, z.x(), 1e-4 * z.x());
      EXPECT_NEAR(angleDiff(o.bearing, z.y()), 0, 1e-5);
      moved = std::max(moved, (world.at(o.landmark_id).xy() - d.map.at(o.landmark_id).xy()).norm());
      ++count;
    }
  EXPECT_GT(count, 50u);
  EXPECT_GT(moved, 10.0);
  test::TempDir dir;
  trace.errors.save(dir.file("errors.yaml"), cfg.profile);
  cv::FileStorage fs(dir.file("errors.yaml"), cv::FileStorage::READ);
  EXPECT_EQ(static_cast<double>(fs["field_length_mm"]), trace.errors.field_dimension_mm[0]);
  EXPECT_EQ(static_cast<double>(fs["field_penalty_area_width_mm"]), trace.errors.field_dimension_mm[8]);
}

// Raw images through lens distortion: a landmark's raw truth pixel, undistorted with an exact
// calibration of the lens, lands where the calibration's rectified rig projects the landmark of
// the field the world is built on (its dimensions off by 10 mm here).
TEST(RawPairRenderer, RawTruthUndistortsOntoTheRectifiedProjection) {
  ErrorProfile p;
  p.name = "lens";
  p.k1_mean = -0.2;
  p.k2_mean = 0.05;
  p.field_dimension_sigma_mm = 10.0;
  std::mt19937_64 rng(3);
  const DrawnErrors e = drawErrors(p, 1, rng);
  const FieldMap world = trueFieldMap(FieldMap::miroSot(), e);
  ASSERT_GT(std::fabs(e.field_dimension_mm[0]), 1.0);
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
    const Landmark& lm = world.at(l.id);
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
