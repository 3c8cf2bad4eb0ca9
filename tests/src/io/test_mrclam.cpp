// MR.CLAM import: exact wheel integration, ground-truth interpolation, robust statistics,
// parser errors, and an import of a short slice of the shared Dataset 6 (skipped when absent).
#include "src/io/mrclam.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <set>
#include <sstream>

#include "src/core/angles.h"
#include "src/core/error.h"
#include "src/core/odometry_model.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// The unicycle driven at constant (v, omega) for dt from `p`, integrated in closed form: a
// circular arc whose chord has length v dt sinc(phi/2) and points along theta + phi/2.
Pose2 unicycle(const Pose2& p, double v, double omega, double dt) {
  const double phi = omega * dt;
  const double sinc = std::fabs(phi) < 1e-6 ? 1.0 - phi * phi / 24.0 : std::sin(phi / 2) / (phi / 2);
  const double chord = v * dt * sinc;
  return Pose2(p.x + chord * std::cos(p.theta + phi / 2), p.y + chord * std::sin(p.theta + phi / 2), p.theta + phi);
}

TEST(MrclamOdometry, ConstantTwistWheelTravelReproducesUnicycleExactly) {
  const Pose2 start(1200.0, -340.0, 2.9);
  const double w = 260.0;
  OdometryParams params;
  params.wheel_base_mm = w;
  for (double v : {0.0, 86.0, -50.0, 300.0}) {
    for (double omega : {0.0, 1e-9, -0.398, 0.408, 2.5}) {
      for (double dt : {0.015, 0.1, 1.7}) {
        const WheelIncrements d = wheelIncrementsForTwist(v, omega, dt, w);
        EXPECT_NEAR(d.d_left, (v - omega * w / 2) * dt, 1e-12);
        EXPECT_NEAR(d.d_right, (v + omega * w / 2) * dt, 1e-12);
        const Pose2 got = predictPose(start, Eigen::Matrix3d::Zero(), d.d_left, d.d_right, params).pose;
        const Pose2 want = unicycle(start, v, omega, dt);
        EXPECT_NEAR(got.x, want.x, 1e-9) << v << " " << omega << " " << dt;
        EXPECT_NEAR(got.y, want.y, 1e-9) << v << " " << omega << " " << dt;
        EXPECT_NEAR(angleDiff(got.theta, want.theta), 0.0, 1e-12);
      }
    }
  }
}

TEST(MrclamOdometry, OdometerIntegratesPiecewiseConstantCommandsExactly) {
  const double w = 200.0;
  // Commands held until the next row; the last row has no duration.
  const std::vector<MrclamOdometryRow> rows = {{10.0, 100.0, 0.5}, {10.5, 100.0, 0.5}, {11.0, 0.0, -1.0},
                                               {11.0, 50.0, 0.0},  {12.0, 20.0, 0.2}};
  const WheelOdometer odo(rows, w);
  // Total: 1 s at (100, 0.5), then 1 s at (50, 0): left 100 - 50 + 50 = 100 - 0.5*100 + 50.
  const WheelIncrements total = odo.between(10.0, 12.0);
  EXPECT_NEAR(total.d_left, (100 - 0.5 * w / 2) * 1.0 + 50.0, 1e-9);
  EXPECT_NEAR(total.d_right, (100 + 0.5 * w / 2) * 1.0 + 50.0, 1e-9);
  // Mid-piece query and additivity over an arbitrary split.
  const WheelIncrements a = odo.between(10.0, 10.75), b = odo.between(10.75, 12.0);
  EXPECT_NEAR(a.d_left, (100 - 0.5 * w / 2) * 0.75, 1e-9);
  EXPECT_NEAR(a.d_left + b.d_left, total.d_left, 1e-9);
  EXPECT_NEAR(a.d_right + b.d_right, total.d_right, 1e-9);
  // Outside the rows: clamped (no extrapolation of the last command).
  EXPECT_NEAR(odo.between(12.0, 20.0).d_left, 0.0, 1e-12);
  EXPECT_NEAR(odo.between(0.0, 10.0).d_right, 0.0, 1e-12);
  // A step inside one constant piece equals the arc model's exact motion.
  const WheelIncrements piece = odo.between(10.1, 10.4);
  const WheelIncrements want = wheelIncrementsForTwist(100.0, 0.5, 0.3, w);
  EXPECT_NEAR(piece.d_left, want.d_left, 1e-9);
  EXPECT_NEAR(piece.d_right, want.d_right, 1e-9);
}

TEST(MrclamGroundtruth, InterpolatesOnTheCircleAndNotOutsideItsSpan) {
  const std::vector<MrclamPoseRow> gt = {
      {1.0, Pose2(0, 0, 3.1)}, {2.0, Pose2(100, -200, -3.1)}, {2.5, Pose2(100, -200, 0.0)}, {10.0, Pose2(0, 0, 0)}};
  const auto mid = interpolateGroundtruth(gt, 1.5, 1.0);
  ASSERT_TRUE(mid);
  EXPECT_NEAR(mid->x, 50.0, 1e-9);
  EXPECT_NEAR(mid->y, -100.0, 1e-9);
  // Across +-pi along the short arc: halfway between 3.1 and -3.1 is pi, not 0.
  EXPECT_NEAR(std::fabs(mid->theta), kPi, 1e-9);
  const auto q = interpolateGroundtruth(gt, 1.25, 1.0);
  ASSERT_TRUE(q);
  EXPECT_NEAR(angleDiff(q->theta, 3.1 + 0.25 * (2 * kPi - 6.2)), 0.0, 1e-9);
  EXPECT_TRUE(interpolateGroundtruth(gt, 1.0, 1.0));   // exactly the first row
  EXPECT_TRUE(interpolateGroundtruth(gt, 10.0, 10.0)); // exactly the last row
  EXPECT_FALSE(interpolateGroundtruth(gt, 0.999, 1.0));
  EXPECT_FALSE(interpolateGroundtruth(gt, 10.001, 1.0));
  EXPECT_FALSE(interpolateGroundtruth(gt, 5.0, 1.0));  // a 7.5 s Vicon gap
  EXPECT_TRUE(interpolateGroundtruth(gt, 5.0, 8.0));
}

TEST(MrclamStatistics, RobustStatsIgnoreOutliers) {
  std::vector<double> e = {-2, -1, 0, 1, 2, 1000};
  const RobustErrorStats s = robustErrorStats(e);
  EXPECT_EQ(s.count, 6u);
  EXPECT_NEAR(s.median, 0.5, 1e-12);
  // |e - 0.5| = 2.5 1.5 0.5 0.5 1.5 999.5 -> MAD 1.5
  EXPECT_NEAR(s.mad_sigma, 1.482602218505602 * 1.5, 1e-9);
  EXPECT_EQ(s.outliers, 1u);
  EXPECT_NEAR(s.max_abs, 1000.0, 1e-12);
  EXPECT_GT(s.std, 300.0);
}

// ---- parser errors ----

std::string writeFile(const test::TempDir& dir, const std::string& name, const std::string& text) {
  std::ofstream(dir.file(name)) << text;
  return dir.file(name);
}

using test::errorOf;

const char* kHeader = "# a\n# b\n# c\n# d\n";

TEST(MrclamRangeCorrection, FitRecoversAPlantedModelDespiteOutliers) {
  RangeCorrection planted;
  planted.c = Eigen::Vector3d(0.03, 0.01, -0.45);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> bearing(-0.55, 0.55), range(800.0, 7000.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  std::vector<RangeSample> samples;
  for (int i = 0; i < 2000; ++i) {
    const double b = bearing(rng), r = range(rng);
    double measured = planted.factor(b) * r * (1.0 + noise(rng));
    if (i % 50 == 0) measured *= 1.3;  // 2 % gross errors
    samples.push_back({measured, r, b});
  }
  const RangeCorrection fit = fitRangeCorrection(samples);
  EXPECT_NEAR(fit.c(0), 0.03, 0.002);
  EXPECT_NEAR(fit.c(1), 0.01, 0.003);
  EXPECT_NEAR(fit.c(2), -0.45, 0.015);
  // The correction inverts the model.
  EXPECT_NEAR(planted.correct(planted.factor(0.3) * 2500.0, 0.3), 2500.0, 1e-9);
}

TEST(MrclamRangeCorrection, DegenerateFitsAndAbsurdFactorsAreErrors) {
  std::vector<RangeSample> few(9, RangeSample{1000.0, 1000.0, 0.1});
  EXPECT_NE(errorOf([&] { fitRangeCorrection(few); }).find("fewer than 10"), std::string::npos);
  std::vector<RangeSample> one_bearing(50, RangeSample{1010.0, 1000.0, 0.2});
  EXPECT_NE(errorOf([&] { fitRangeCorrection(one_bearing); }).find("do not spread"), std::string::npos);
  RangeCorrection rc;
  rc.c = Eigen::Vector3d(0.0, 0.0, -4.0);  // factor 0.36 at 0.4 rad
  EXPECT_NE(errorOf([&] { rc.correct(1000.0, 0.4); }).find("outside [0.5, 2]"), std::string::npos);
  EXPECT_NEAR(rc.correct(1000.0, 0.0), 1000.0, 1e-12);
}

// A robot driving random piecewise-constant commands (rows at 67 Hz, each command held 0.5-2 s)
// whose drive follows them `delay_s` late; ground truth at 100 Hz with 0.2 degree heading noise
// and 1 % gross heading errors, over `duration_s`.
struct DelayedDrive {
  std::vector<MrclamOdometryRow> commands;
  std::vector<MrclamPoseRow> truth;
};
DelayedDrive delayedDrive(double delay_s, double duration_s, double max_omega, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> hold(0.5, 2.0), speed(0.0, 200.0), turn(-max_omega, max_omega);
  std::normal_distribution<double> heading_noise(0.0, deg2rad(0.2));
  DelayedDrive d;
  double next_change = 0, v = 0, omega = 0;
  for (double t = 0; t <= duration_s; t += 0.015) {
    if (t >= next_change) {
      v = speed(rng);
      omega = turn(rng);
      next_change = t + hold(rng);
    }
    d.commands.push_back({100.0 + t, v, omega});
  }
  // The command in force at time t - delay (queried at increasing times), integrated in 1 ms
  // substeps.
  size_t in_force = 0;
  auto command = [&](double t) {
    while (in_force + 1 < d.commands.size() && d.commands[in_force + 1].t <= t) ++in_force;
    return t < d.commands.front().t ? MrclamOdometryRow{t, 0.0, 0.0} : d.commands[in_force];
  };
  Pose2 p(0, 0, 0.3);
  const double dt = 1e-3;
  int sample = 0;
  for (int k = 0; 100.0 + k * dt <= 100.0 + duration_s; ++k) {
    const double t = 100.0 + k * dt;
    if (k % 10 == 0) {
      Pose2 seen = p;
      seen.theta = wrapAngle(p.theta + heading_noise(rng) + (++sample % 100 == 0 ? 0.5 : 0.0));
      d.truth.push_back({t, seen});
    }
    const MrclamOdometryRow c = command(t + 0.5 * dt - delay_s);
    p = unicycle(p, c.v, c.omega, dt);
  }
  return d;
}

TEST(MrclamCommandDelay, FitRecoversAPlantedDelayDespiteOutliers) {
  for (double planted : {0.23, -0.12}) {
    const DelayedDrive d = delayedDrive(planted, 200.0, 0.8, 5);
    const CommandDelayFit fit = fitCommandDelay(d.commands, d.truth);
    EXPECT_NEAR(fit.delay_s, planted, 0.01);
    EXPECT_GT(fit.windows, 380u);
    EXPECT_LT(fit.heading_sigma, 0.5 * fit.heading_sigma_at_zero) << planted;
  }
}

TEST(MrclamCommandDelay, DegenerateFitsAreErrors) {
  const DelayedDrive straight = delayedDrive(0.2, 60.0, 0.0, 1);
  EXPECT_NE(errorOf([&] { fitCommandDelay(straight.commands, straight.truth); }).find("never turn"), std::string::npos);
  const DelayedDrive short_run = delayedDrive(0.2, 8.0, 0.8, 1);
  EXPECT_NE(errorOf([&] { fitCommandDelay(short_run.commands, short_run.truth); }).find("at least 20 needed"),
            std::string::npos);
  const DelayedDrive late = delayedDrive(1.4, 100.0, 0.8, 1);
  EXPECT_NE(errorOf([&] { fitCommandDelay(late.commands, late.truth); }).find("edge of the search"), std::string::npos);
  CommandDelaySearch wide;
  wide.max_s = 2.0;
  EXPECT_NEAR(fitCommandDelay(late.commands, late.truth, wide).delay_s, 1.4, 0.01);
  CommandDelaySearch bad;
  bad.min_s = bad.max_s;
  EXPECT_NE(errorOf([&] { fitCommandDelay(late.commands, late.truth, bad); }).find("search"), std::string::npos);
}

TEST(MrclamParser, MalformedRowsNameFileAndLine) {
  test::TempDir dir("mrclam_parse");
  const std::string odo = writeFile(dir, "odo.dat", std::string(kHeader) + "1.0 0.1 0.2\n2.0 0.1\n");
  EXPECT_NE(errorOf([&] { readMrclamOdometry(odo); }).find("odo.dat:6: expected 3 fields"), std::string::npos)
      << errorOf([&] { readMrclamOdometry(odo); });
  const std::string nan = writeFile(dir, "nan.dat", std::string(kHeader) + "1.0 nan 0.2\n");
  EXPECT_NE(errorOf([&] { readMrclamOdometry(nan); }).find("nan.dat:5: forward velocity"), std::string::npos);
  const std::string text = writeFile(dir, "txt.dat", std::string(kHeader) + "1.0 0.1 0.2x\n");
  EXPECT_NE(errorOf([&] { readMrclamOdometry(text); }).find("txt.dat:5: angular velocity"), std::string::npos);
  const std::string back = writeFile(dir, "back.dat", std::string(kHeader) + "2.0 1 1 0\n1.0 1 1 0\n");
  EXPECT_NE(errorOf([&] { readMrclamGroundtruth(back); }).find("back.dat:6: time"), std::string::npos);
  const std::string blank = writeFile(dir, "blank.dat", std::string(kHeader) + "2.0 1 1 0\n\n3.0 1 1 0\n");
  EXPECT_NE(errorOf([&] { readMrclamGroundtruth(blank); }).find("blank.dat:6: blank line"), std::string::npos);
  const std::string empty = writeFile(dir, "empty.dat", kHeader);
  EXPECT_NE(errorOf([&] { readMrclamGroundtruth(empty); }).find("empty.dat: no data rows"), std::string::npos);
  const std::string barcode = writeFile(dir, "bc.dat", std::string(kHeader) + "5 1.5 2 0.1\n");
  EXPECT_NE(errorOf([&] { readMrclamMeasurements(barcode); }).find("bc.dat:5: barcode"), std::string::npos);
  const std::string range = writeFile(dir, "range.dat", std::string(kHeader) + "5 15 -2 0.1\n");
  EXPECT_NE(errorOf([&] { readMrclamMeasurements(range); }).find("range.dat:5: range"), std::string::npos);
  const std::string dup = writeFile(dir, "dup.dat", std::string(kHeader) + "1 5\n2 5\n");
  EXPECT_NE(errorOf([&] { readMrclamBarcodes(dup); }).find("dup.dat:6: barcode: duplicate"), std::string::npos);
  EXPECT_NE(errorOf([&] { readMrclamBarcodes(dir.file("missing.dat")); }).find("missing.dat: cannot open"),
            std::string::npos);
  // A truncated last line (no newline, missing fields) is an error, a final newline is not.
  const std::string trunc = writeFile(dir, "trunc.dat", std::string(kHeader) + "1.0 0.1 0.2\n2.0 0.1 0.");
  EXPECT_NO_THROW(readMrclamOdometry(trunc));
  const std::string trunc2 = writeFile(dir, "trunc2.dat", std::string(kHeader) + "1.0 0.1 0.2\n2.0 0.");
  EXPECT_NE(errorOf([&] { readMrclamOdometry(trunc2); }).find("trunc2.dat:6:"), std::string::npos);
}

// ---- a slice of the shared Dataset 6 ----

std::string sharedDir() { return std::string(STEREOLOC_SHARED_DIR) + "/data/mrclam6"; }

// Copies the header and the data rows of `src` whose first column (time) lies in [t0, t1],
// at most max_rows of them. Returns the number of data rows copied.
size_t copySlice(const std::string& src, const std::string& dst, double t0, double t1, size_t max_rows) {
  std::ifstream in(src);
  std::ofstream out(dst);
  std::string line;
  size_t n = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line[0] == '#') {
      out << line << "\n";
      continue;
    }
    const double t = std::stod(line);
    if (t < t0) continue;
    if (t > t1 || n >= max_rows) break;
    out << line << "\n";
    ++n;
  }
  return n;
}

class MrclamSlice : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::filesystem::exists(sharedDir() + "/Robot1_Odometry.dat"))
      GTEST_SKIP() << "shared MR.CLAM data not found at " << sharedDir();
    namespace fs = std::filesystem;
    fs::copy_file(sharedDir() + "/Barcodes.dat", dir_.file("Barcodes.dat"));
    fs::copy_file(sharedDir() + "/Landmark_Groundtruth.dat", dir_.file("Landmark_Groundtruth.dat"));
    // Robot 1: odometry from 1248444187.156; measurements start at 189.599. 20 s of odometry
    // (~1300 rows at 67 Hz), the measurements inside, and ground truth from just before.
    const double t0 = 1248444187.156, t1 = t0 + 20.0;
    odo_rows_ = copySlice(sharedDir() + "/Robot1_Odometry.dat", dir_.file("Robot1_Odometry.dat"), t0, t1, 2000);
    meas_rows_ = copySlice(sharedDir() + "/Robot1_Measurement.dat", dir_.file("Robot1_Measurement.dat"), t0, t1 - 1, 200);
    gt_rows_ = copySlice(sharedDir() + "/Robot1_Groundtruth.dat", dir_.file("Robot1_Groundtruth.dat"), t0 - 0.5,
                         t0 + 15.0, 2000);
    // What the slice should give, counted independently of the importer.
    std::ifstream in(dir_.file("Robot1_Measurement.dat"));
    std::string line;
    const std::set<int> robots = {5, 14, 41, 32, 23};  // barcodes of subjects 1-5
    while (std::getline(in, line)) {
      if (line[0] == '#') continue;
      std::istringstream ss(line);
      double t, r, b;
      int barcode;
      ss >> t >> barcode >> r >> b;
      meas_.push_back({t, barcode, 1000 * r, b, 0});
      if (robots.count(barcode)) ++robot_meas_;
    }
  }

  test::TempDir dir_{"mrclam_slice"};
  size_t odo_rows_ = 0, meas_rows_ = 0, gt_rows_ = 0, robot_meas_ = 0;
  std::vector<MrclamMeasurementRow> meas_;
};

TEST_F(MrclamSlice, RowCountsBarcodeMappingAndTimeAlignment) {
  ASSERT_GT(odo_rows_, 800u);
  ASSERT_GT(meas_rows_, 20u);
  MrclamImportConfig config;
  config.robot = 1;
  const MrclamImport imp = importMrclam(dir_.path(), config);
  const ImportReport& rep = imp.report;
  EXPECT_EQ(rep.odometry_rows, odo_rows_);
  EXPECT_EQ(rep.measurement_rows, meas_rows_);
  EXPECT_EQ(rep.groundtruth_rows, gt_rows_);
  EXPECT_GT(robot_meas_, 0u);
  EXPECT_EQ(rep.dropped_other_robot, robot_meas_);
  EXPECT_EQ(rep.observations + rep.dropped_other_robot + rep.dropped_unknown_barcode + rep.dropped_outside_odometry,
            meas_rows_);
  EXPECT_DOUBLE_EQ(rep.epoch_s, 1248444187.156);

  // Landmarks: 15, ids = subjects 6..20; barcode 90 is subject 15 at (1.54725918, 2.76939627) m.
  ASSERT_EQ(imp.map.landmarks().size(), 15u);
  EXPECT_NEAR(imp.map.at(15).position.x(), 1547.25918, 1e-6);
  EXPECT_NEAR(imp.map.at(15).position.y(), 2769.39627, 1e-6);
  EXPECT_TRUE(imp.map.at(15).unique);
  EXPECT_EQ(imp.map.find(5), nullptr);

  // Steps strictly increasing; the 10 Hz grid is present; every observation sits at its own
  // measurement time (within the 1.5 ms merge tolerance), in file order, with the mapped id.
  ASSERT_EQ(imp.steps.size(), imp.groundtruth.size());
  EXPECT_EQ(imp.steps.front().t, 0.0);
  EXPECT_EQ(imp.steps.front().d_left, 0.0);
  for (size_t i = 1; i < imp.steps.size(); ++i) {
    EXPECT_EQ(imp.steps[i].step, static_cast<long>(i));
    EXPECT_GT(imp.steps[i].t, imp.steps[i - 1].t);
    EXPECT_LE(imp.steps[i].t - imp.steps[i - 1].t, 0.1 + 2e-3);
  }
  const std::map<int, int> barcode_to_subject = readMrclamBarcodes(dir_.file("Barcodes.dat"));
  auto isLandmark = [&](int barcode) {
    const auto it = barcode_to_subject.find(barcode);
    return it != barcode_to_subject.end() && it->second > 5;
  };
  size_t k = 0, matched = 0;
  for (const Step& s : imp.steps) {
    for (const Observation& o : s.observations) {
      while (k < meas_.size() && !isLandmark(meas_[k].barcode)) ++k;
      ASSERT_LT(k, meas_.size());
      EXPECT_EQ(o.landmark_id, barcode_to_subject.at(meas_[k].barcode));
      EXPECT_NEAR(o.range, meas_[k].range, 1e-9);
      EXPECT_NEAR(s.t, meas_[k].t - rep.epoch_s, 1.5e-3 + 1e-9);
      EXPECT_NEAR(std::sqrt(o.covariance(0, 0)), rep.sigma_range_mm, 1e-9);
      ++k;
      ++matched;
    }
  }
  EXPECT_EQ(matched, rep.observations);
  EXPECT_EQ(rep.observations, meas_.size() - robot_meas_ - rep.dropped_unknown_barcode);
  EXPECT_LE(rep.max_time_shift_s, 1.5e-3);

  // Ground truth: only inside its span (t0 - 0.5 .. t0 + 15 s), equal to a direct interpolation.
  const std::vector<MrclamPoseRow> gt = readMrclamGroundtruth(dir_.file("Robot1_Groundtruth.dat"));
  size_t with_gt = 0;
  for (size_t i = 0; i < imp.steps.size(); ++i) {
    const double t = imp.steps[i].t;
    if (t > 15.0 + 1e-6) {
      EXPECT_FALSE(imp.groundtruth[i]) << t;
    }
    if (t < 14.9) {
      ASSERT_TRUE(imp.groundtruth[i]) << t;
    }
    if (imp.groundtruth[i]) {
      ++with_gt;
      const auto want = interpolateGroundtruth(gt, rep.epoch_s + t, 1.0);
      ASSERT_TRUE(want);
      EXPECT_NEAR(imp.groundtruth[i]->x, want->x, 1e-9);
    }
  }
  EXPECT_EQ(with_gt, rep.steps_with_groundtruth);
  ASSERT_TRUE(imp.initial_pose);
  EXPECT_NEAR(imp.initial_pose->y, interpolateGroundtruth(gt, rep.epoch_s, 1.0)->y, 1e-9);

  // Odometry: the sum of the step increments equals the integral of the commands.
  double left = 0;
  for (const Step& s : imp.steps) left += s.d_left;
  const WheelOdometer odo(readMrclamOdometry(dir_.file("Robot1_Odometry.dat")), config.wheel_base_mm);
  EXPECT_NEAR(left, odo.between(rep.epoch_s, rep.epoch_s + 100).d_left, 1e-6);

  // The sigmas are estimated and plausible for a camera reading barcodes metres away.
  EXPECT_TRUE(rep.sigmas_estimated);
  EXPECT_GT(rep.sigma_range_mm, 1.0);
  EXPECT_LT(rep.sigma_range_mm, 500.0);
  EXPECT_GT(rep.sigma_bearing_rad, 1e-3);
  EXPECT_LT(rep.sigma_bearing_rad, deg2rad(5.0));
  EXPECT_NE(rep.summary().find("of other robots"), std::string::npos);

  // MR.CLAM's odometry is velocity commands: its noise lives in the motion.
  EXPECT_EQ(imp.odometry.readings, OdometryReadings::Commands);

  // The odometry noise scale multiplies the fitted model and nothing else.
  ASSERT_GE(rep.odometry_fit.windows, 10u);
  MrclamImportConfig scaled = config;
  scaled.odometry_noise_scale = 4.0;
  const MrclamImport imp4 = importMrclam(dir_.path(), scaled);
  EXPECT_NEAR(imp4.odometry.k_left, 4.0 * imp.odometry.k_left, 1e-12);
  EXPECT_NEAR(imp4.odometry.control_variance_floor.x(), 4.0 * imp.odometry.control_variance_floor.x(), 1e-9);
  EXPECT_EQ(imp4.steps.size(), imp.steps.size());
}

TEST_F(MrclamSlice, CorrelatedErrorsInflateTheSigmasAndChangeNothingElse) {
  MrclamImportConfig config;
  config.robot = 1;
  const MrclamImport independent = importMrclam(dir_.path(), config);
  config.correlated_errors = true;
  const MrclamImport correlated = importMrclam(dir_.path(), config);
  const ImportReport& rep = correlated.report;
  // The fit is made either way and is the same; only the flag applies it.
  EXPECT_FALSE(independent.report.correlated_errors);
  EXPECT_TRUE(rep.correlated_errors);
  EXPECT_EQ(rep.range_same.pairs, independent.report.range_same.pairs);
  EXPECT_EQ(rep.range_same.correlation.at_zero, independent.report.range_same.correlation.at_zero);
  EXPECT_GT(rep.range_same.pairs, 10u);
  EXPECT_GT(rep.bearing_other.pairs, 10u);
  // Exactly the library's inflation of the independent import's steps, with the fitted model.
  std::vector<Step> want = independent.steps;
  inflateForCorrelatedErrors(want, rep.correlation());
  ASSERT_EQ(correlated.steps.size(), want.size());
  size_t inflated = 0;
  for (size_t i = 0; i < want.size(); ++i) {
    EXPECT_EQ(correlated.steps[i].d_left, independent.steps[i].d_left);
    ASSERT_EQ(correlated.steps[i].observations.size(), want[i].observations.size());
    for (size_t k = 0; k < want[i].observations.size(); ++k) {
      const Observation& o = correlated.steps[i].observations[k];
      const Observation& given = independent.steps[i].observations[k];
      EXPECT_EQ(o.range, given.range);
      EXPECT_EQ(o.covariance, want[i].observations[k].covariance);
      EXPECT_GE(o.covariance(0, 0), given.covariance(0, 0));
      EXPECT_GE(o.covariance(1, 1), given.covariance(1, 1));
      if (o.covariance(0, 0) > given.covariance(0, 0)) ++inflated;
    }
  }
  EXPECT_GT(inflated, rep.observations / 2);
  EXPECT_GT(rep.mean_range_variance_factor, 1.0);
  EXPECT_GT(rep.mean_bearing_variance_factor, 1.0);
  EXPECT_NE(rep.summary().find("sigmas inflated for it"), std::string::npos);
  config.correlation_max_lag_s = 0;
  EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("correlation_max_lag_s"), std::string::npos);
}

TEST_F(MrclamSlice, RangeCorrectionFittedOrGivenDividesEveryRange) {
  MrclamImportConfig config;
  config.robot = 1;
  const MrclamImport plain = importMrclam(dir_.path(), config);
  EXPECT_EQ(plain.report.range_correction_mode, CorrectionSource::None);
  EXPECT_EQ(plain.report.summary().find("range correction"), std::string::npos);

  config.range_correction = CorrectionSource::Fit;
  const MrclamImport fitted = importMrclam(dir_.path(), config);
  const ImportReport& rep = fitted.report;
  EXPECT_EQ(rep.range_correction_mode, CorrectionSource::Fit);
  EXPECT_TRUE(rep.range_correction.c.allFinite());
  // The errors before the correction are the plain import's errors.
  EXPECT_EQ(rep.range_error_uncorrected.count, plain.report.range_error.count);
  EXPECT_DOUBLE_EQ(rep.range_error_uncorrected.mad_sigma, plain.report.range_error.mad_sigma);
  // The fit is a calibration against the truth: the corrected errors are smaller.
  EXPECT_LT(rep.range_error.std, rep.range_error_uncorrected.std);
  EXPECT_NE(rep.summary().find("range correction (fitted against ground truth)"), std::string::npos);

  config.range_correction = CorrectionSource::Given;
  config.given_range_correction.c = Eigen::Vector3d(0.02, 0.01, -0.4);
  const MrclamImport given = importMrclam(dir_.path(), config);
  ASSERT_EQ(given.steps.size(), plain.steps.size());
  size_t n = 0;
  for (size_t i = 0; i < plain.steps.size(); ++i)
    for (size_t k = 0; k < plain.steps[i].observations.size(); ++k) {
      const Observation& o = plain.steps[i].observations[k];
      EXPECT_NEAR(given.steps[i].observations[k].range, o.range / config.given_range_correction.factor(o.bearing),
                  1e-9);
      EXPECT_EQ(given.steps[i].observations[k].bearing, o.bearing);
      ++n;
    }
  EXPECT_GT(n, 20u);
  EXPECT_NE(given.report.summary().find("range correction (given)"), std::string::npos);

  // A correction that would halve a range is refused, naming the file and line.
  config.given_range_correction.c = Eigen::Vector3d(-0.6, 0.0, 0.0);
  const std::string e = errorOf([&] { importMrclam(dir_.path(), config); });
  EXPECT_NE(e.find("Robot1_Measurement.dat:"), std::string::npos) << e;
  EXPECT_NE(e.find("outside [0.5, 2]"), std::string::npos) << e;
  config.given_range_correction.c(0) = std::nan("");
  EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("given_range_correction"), std::string::npos);
}

TEST_F(MrclamSlice, CommandDelayFittedOrGivenHoldsEachCommandFromItsTimePlusTheDelay) {
  MrclamImportConfig config;
  config.robot = 1;
  const MrclamImport plain = importMrclam(dir_.path(), config);
  EXPECT_EQ(plain.report.command_delay_mode, CorrectionSource::None);
  EXPECT_EQ(plain.report.command_delay.delay_s, 0.0);
  EXPECT_EQ(plain.report.summary().find("command delay"), std::string::npos);

  config.command_delay = CorrectionSource::Given;
  config.given_command_delay_s = 0.25;
  const MrclamImport given = importMrclam(dir_.path(), config);
  ASSERT_EQ(given.steps.size(), plain.steps.size());
  // Each step's wheel travel is the commands' over the step's interval 0.25 s earlier; the
  // observations and the step times are the plain import's.
  const std::vector<MrclamOdometryRow> rows = readMrclamOdometry(dir_.file("Robot1_Odometry.dat"));
  const WheelOdometer odometer(rows, config.wheel_base_mm);
  const double t0 = given.report.epoch_s;
  size_t moved = 0;
  for (size_t i = 1; i < given.steps.size(); ++i) {
    const Step& s = given.steps[i];
    EXPECT_EQ(s.t, plain.steps[i].t);
    EXPECT_EQ(s.observations.size(), plain.steps[i].observations.size());
    const WheelIncrements want = odometer.between(t0 + given.steps[i - 1].t - 0.25, t0 + s.t - 0.25);
    EXPECT_NEAR(s.d_left, want.d_left, 1e-9);
    EXPECT_NEAR(s.d_right, want.d_right, 1e-9);
    if (std::fabs(s.d_left - plain.steps[i].d_left) > 1e-3) ++moved;
  }
  EXPECT_GT(moved, given.steps.size() / 4);
  EXPECT_NE(given.report.summary().find("command delay (given): 0.250 s"), std::string::npos);

  // Fitted on the slice's 15 s of ground truth (too short to pin the latency down; the whole
  // run's fit is tested in tests/tools/test_cli_import.cpp): the import holds the commands by
  // the fitted delay, as if it had been given.
  config.command_delay = CorrectionSource::Fit;
  const MrclamImport fitted = importMrclam(dir_.path(), config);
  EXPECT_GE(fitted.report.command_delay.windows, 20u);
  EXPECT_NE(fitted.report.summary().find("command delay (fitted against ground truth over "), std::string::npos);
  config.command_delay = CorrectionSource::Given;
  config.given_command_delay_s = fitted.report.command_delay.delay_s;
  const MrclamImport refitted = importMrclam(dir_.path(), config);
  for (size_t i = 0; i < fitted.steps.size(); ++i) {
    EXPECT_EQ(fitted.steps[i].d_left, refitted.steps[i].d_left);
    EXPECT_EQ(fitted.steps[i].d_right, refitted.steps[i].d_right);
  }

  for (double bad : {2.5, -3.0, std::nan("")}) {
    config.given_command_delay_s = bad;
    EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("given_command_delay_s"), std::string::npos)
        << bad;
  }
}

TEST_F(MrclamSlice, DeadReckoningFollowsGroundTruthOverTheSlice) {
  MrclamImportConfig config;
  config.robot = 1;
  config.sigma_range_mm = 100.0;
  config.sigma_bearing_rad = 0.01;
  const MrclamImport imp = importMrclam(dir_.path(), config);
  EXPECT_FALSE(imp.report.sigmas_estimated);
  ASSERT_TRUE(imp.initial_pose);
  Pose2 p = *imp.initial_pose;
  double max_err = 0, path = 0;
  for (size_t i = 1; i < imp.steps.size() && imp.groundtruth[i]; ++i) {
    p = predictPose(p, Eigen::Matrix3d::Zero(), imp.steps[i].d_left, imp.steps[i].d_right, imp.odometry).pose;
    path += 0.5 * std::fabs(imp.steps[i].d_left + imp.steps[i].d_right);
    max_err = std::max(max_err, (p.translation() - imp.groundtruth[i]->translation()).norm());
  }
  // Commanded velocities drift, but over ~13 s (about a metre) the error stays well under it.
  EXPECT_GT(path, 500.0);
  EXPECT_LT(max_err, 0.3 * path);
}

TEST_F(MrclamSlice, MissingRobotFileAndBadConfigAreErrors) {
  MrclamImportConfig config;
  config.robot = 2;  // not copied
  EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("Robot2_Odometry.dat: cannot open"),
            std::string::npos);
  config.robot = 7;
  EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("robot"), std::string::npos);
  config.robot = 1;
  config.rate_hz = 0;
  EXPECT_NE(errorOf([&] { importMrclam(dir_.path(), config); }).find("rate_hz"), std::string::npos);
}

}  // namespace
}  // namespace stereoloc
