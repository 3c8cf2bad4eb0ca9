// A fix considering its stereo calibration (solvers/considered_fix.h): on rigs whose true
// calibration differs from the given one by draws of the stated sigmas, the considered
// covariance is consistent where the fix's own is not.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <cmath>
#include <random>
#include <vector>

#include "solvers/considered_fix.h"
#include "src/core/angles.h"
#include "src/core/error.h"

namespace stereoloc {
namespace {

constexpr double kPixelSigma = 0.3;  // px

struct Scene {
  FieldMap map = FieldMap::miroSot();
  std::vector<const Landmark*> corners;  // the two goal corners at x = 0
  Pose2 truth;
};

Scene goalScene() {
  Scene s;
  for (const Landmark& l : s.map.landmarks())
    if (l.type == LandmarkType::GoalCorner && l.position.x() < 1) s.corners.push_back(&l);
  const Eigen::Vector2d mid = 0.5 * (s.corners[0]->xy() + s.corners[1]->xy());
  const Eigen::Vector2d at(600.0, mid.y() + 80.0);
  s.truth = Pose2(at.x(), at.y(), std::atan2(mid.y() - at.y(), mid.x() - at.x()));
  return s;
}

// The step a rig with true parameters `truth_params` and offsets dd (disparity, px) and du
// (columns, px) sees, as the given rig reads it; pixel noise from `rng`.
Step sightings(const Scene& s, const StereoRigParams& truth_params, double dd, double du, const StereoRig& given,
               std::mt19937_64& rng) {
  const StereoRig truth(truth_params);
  std::normal_distribution<double> noise(0.0, kPixelSigma);
  Step step;
  step.step = 1;
  for (const Landmark* l : s.corners) {
    const Eigen::Vector2d local = transformToLocal(s.truth, l->xy());
    std::optional<StereoPixels> px = truth.project(Eigen::Vector3d(local.x(), local.y(), l->position.z()), 0.0);
    EXPECT_TRUE(px && truth.inImages(*px));
    px->u_left += du + 0.5 * dd + noise(rng);
    px->u_right += du - 0.5 * dd + noise(rng);
    px->v_left += noise(rng);
    px->v_right += noise(rng);
    step.observations.push_back(observationFromPixels(given, l->id, l->type, *px, 0.0, kPixelSigma));
  }
  return step;
}

double nees(const Pose2& truth, const GlobalFix& fix) {
  const Eigen::Vector3d e(fix.pose.x - truth.x, fix.pose.y - truth.y, wrapAngle(fix.pose.theta - truth.theta));
  return e.dot(fix.covariance.ldlt().solve(e));
}

TEST(ConsideredFix, IsConsistentOnMiscalibratedRigs) {
  const Scene scene = goalScene();
  ASSERT_EQ(scene.corners.size(), 2u);
  const StereoRigParams given_params;
  const StereoRig given(given_params);
  // Stereo block order: tilt, baseline scale, disparity offset, column offset, focal ratio, focal scale.
  CalibrationEstimate::StereoVector sigma;
  sigma << deg2rad(0.5), 0.01, 1.0, 1.0, 0.0, 0.005;
  const CalibrationEstimate::StereoMatrix Cq = sigma.cwiseAbs2().asDiagonal();
  GlobalFixOptions options;
  options.allow_one_landmark = options.allow_multi = false;
  options.single_view_covariance = false;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> unit(0.0, 1.0);
  double plain_sum = 0, considered_sum = 0;
  int n = 0;
  for (int draw = 0; draw < 400; ++draw) {
    StereoRigParams p = given_params;
    p.tilt_rad += sigma[0] * unit(rng);
    p.baseline_mm *= 1.0 + sigma[1] * unit(rng);
    const double dd = sigma[2] * unit(rng), du = sigma[3] * unit(rng);
    p.focal_px = given.focal() * (1.0 + sigma[5] * unit(rng));
    const Step step = sightings(scene, p, dd, du, given, rng);
    const GlobalFix fix = globalFix(step, scene.map, options);
    ASSERT_EQ(fix.status, FixStatus::Ok) << "draw " << draw;
    const GlobalFix considered = considerStereoCalibration(fix, step, scene.map, options, given, Cq);
    ASSERT_EQ(considered.status, FixStatus::Ok) << "draw " << draw;
    EXPECT_EQ(considered.pose.x, fix.pose.x);
    plain_sum += nees(scene.truth, fix);
    considered_sum += nees(scene.truth, considered);
    ++n;
  }
  const double plain = plain_sum / n, considered = considered_sum / n;
  std::printf("mean 3-dof NEES over %d miscalibrated rigs: %.2f the fix's covariance, %.2f considered\n", n, plain,
              considered);
  // 400 draws: the mean of a chi-square(3) has a standard deviation of 0.12.
  EXPECT_GT(considered, 2.5);
  EXPECT_LT(considered, 3.6);
  EXPECT_GT(plain, 10.0);
}

TEST(ConsideredFix, LeavesWhatItCannotImproveAndRefusesBadCovariances) {
  const Scene scene = goalScene();
  const StereoRig given;
  std::mt19937_64 rng(1);
  const Step step = sightings(scene, StereoRigParams(), 0.0, 0.0, given, rng);
  GlobalFixOptions options;
  options.allow_one_landmark = options.allow_multi = false;
  const GlobalFix fix = globalFix(step, scene.map, options);
  ASSERT_EQ(fix.status, FixStatus::Ok);
  const CalibrationEstimate::StereoMatrix zero = CalibrationEstimate::StereoMatrix::Zero();
  EXPECT_EQ(considerStereoCalibration(fix, step, scene.map, options, given, zero).covariance, fix.covariance);
  GlobalFix none = fix;
  none.status = FixStatus::NotEnoughLandmarks;
  CalibrationEstimate::StereoMatrix Cq = zero;
  Cq(1, 1) = 1e-4;
  EXPECT_EQ(considerStereoCalibration(none, step, scene.map, options, given, Cq).covariance, fix.covariance);
  // The baseline scale alone: every stereo range scales with it, so the position moves along
  // the ranges and the heading hardly at all.
  const GlobalFix k = considerStereoCalibration(fix, step, scene.map, options, given, Cq);
  const Eigen::Matrix3d added = k.covariance - fix.covariance;
  const double position_variance = added.topLeftCorner<2, 2>().trace();
  EXPECT_GT(position_variance, 1.0);  // mm^2: 1 % of ~600 mm is 6 mm
  CalibrationEstimate::StereoMatrix bad = Cq;
  bad(2, 2) = -1.0;
  EXPECT_THROW(considerStereoCalibration(fix, step, scene.map, options, given, bad), Error);
  bad(2, 2) = std::nan("");
  EXPECT_THROW(considerStereoCalibration(fix, step, scene.map, options, given, bad), Error);
}

}  // namespace
}  // namespace stereoloc
