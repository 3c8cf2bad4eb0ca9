// makeObservationFactor (solvers/smoother_common.h): the factor chosen by observation model and
// data, and the model names.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <cmath>
#include <fstream>
#include <memory>

#include "solvers/smoother_common.h"
#include "src/core/pose2.h"
#include "src/core/stereo_rig.h"
#include "src/core/types.h"
#include "src/core/numeric_diff.h"
#include "src/core/error.h"
#include "test_util.h"

#include <opencv2/calib3d.hpp>
#include "stereo_sighting.h"

namespace stereoloc {
namespace {

using test::evaluateResidual;
using test::sight;
using test::Sighting;

TEST(ObservationFactor, ChoosesTheFactorByModelAndData) {
  const StereoRig rig;
  const Pose2 pose(100, 200, 0.2);
  const Sighting s = sight(rig, pose, 0.0, 700, -0.2, 25.0);
  Landmark lm;
  lm.id = 4;
  lm.position = s.landmark;
  const Observation with_pixels = observationFromPixels(rig, 4, LandmarkType::GoalCorner, s.pixels, 0.0, 0.5);
  const Observation range_bearing = observationFromRangeBearing(4, LandmarkType::GoalCorner, 700, -0.2, 10, 0.01);
  const double p[3] = {pose.x, pose.y, pose.theta};
  for (ObservationModel m : {ObservationModel::RangeBearing, ObservationModel::PixelColumns, ObservationModel::Pixels}) {
    const ObservationModelConfig config{m, rig};
    std::unique_ptr<ceres::CostFunction> a(makeObservationFactor(with_pixels, lm, config));
    std::unique_ptr<ceres::CostFunction> b(makeObservationFactor(range_bearing, lm, config));
    EXPECT_EQ(a->num_residuals(), m == ObservationModel::Pixels ? 4 : 2) << toString(m);
    EXPECT_EQ(b->num_residuals(), 2) << toString(m);  // no pixels: range-bearing whatever the model
    EXPECT_LT(evaluateResidual(*a, p).norm(), 1e-6) << toString(m);
    EXPECT_EQ(observationModelFromString(toString(m)), m);
  }
  Observation no_sigma = with_pixels;
  no_sigma.pixel_covariance.setZero();
  EXPECT_THROW(makeObservationFactor(no_sigma, lm, {ObservationModel::Pixels, rig}), Error);
  EXPECT_THROW(observationModelFromString("pixel"), Error);
}

// The pixels of a point at normalised (x, y) of camera c through OpenCV's projection with
// distortion D (k1 k2 p1 p2) after rotating its ray by the rotation vector w (camera axes).
Eigen::Vector2d projectWithOpenCv(const StereoRig& rig, double x, double y, const Eigen::Vector4d& D,
                                  const Eigen::Vector3d& w) {
  const cv::Mat K = (cv::Mat_<double>(3, 3) << rig.focal(), 0, rig.principalU(), 0, rig.focal(), rig.principalV(), 0, 0, 1);
  std::vector<cv::Point2d> out;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(x, y, 1.0)}, cv::Vec3d(w.x(), w.y(), w.z()), cv::Vec3d(0, 0, 0),
                    K, cv::Mat(std::vector<double>{D[0], D[1], D[2], D[3]}), out);
  return Eigen::Vector2d(out[0].x, out[0].y);
}

TEST(UnmodelledNoise, PixelCovarianceIsTheLensAndVibrationJacobiansOfOpenCvsProjection) {
  const StereoRig rig;
  const double f = rig.focal(), ou = rig.principalU(), ov = rig.principalV();
  // A point off-centre in both images (left and right columns differ by the disparity).
  const StereoPixels px{ou + 120.0, ov + 70.0, ou + 104.0, ov + 70.0};
  UnmodelledNoise n;
  n.k1_sigma = 0.01;
  n.k2_sigma = 0.005;
  n.tangential_sigma = 3e-4;
  n.pitch_sigma_rad = 0.0035;
  n.roll_sigma_rad = 0.002;
  Eigen::Matrix4d expected = Eigen::Matrix4d::Zero();
  Eigen::Matrix<double, 4, 2> J_vib;
  const double u[2] = {px.u_left, px.u_right}, v[2] = {px.v_left, px.v_right};
  for (int c = 0; c < 2; ++c) {
    const double x = (u[c] - ou) / f, y = (v[c] - ov) / f;
    const auto lens = [&](const Eigen::Vector4d& D) { return projectWithOpenCv(rig, x, y, D, Eigen::Vector3d::Zero()); };
    const Eigen::Matrix<double, 2, 4> J_lens = numericJacobian<2, 4>(lens, Eigen::Vector4d::Zero(), 1e-6);
    const Eigen::Vector4d var(1e-4, 2.5e-5, 9e-8, 9e-8);
    expected.block<2, 2>(2 * c, 2 * c) += J_lens * var.asDiagonal() * J_lens.transpose();
    const auto rot = [&](const Eigen::Vector2d& a) {
      return projectWithOpenCv(rig, x, y, Eigen::Vector4d::Zero(), Eigen::Vector3d(a[0], 0.0, a[1]));
    };
    J_vib.block<2, 2>(2 * c, 0) = numericJacobian<2, 2>(rot, Eigen::Vector2d::Zero(), 1e-7);
  }
  expected += J_vib * Eigen::Vector2d(0.0035 * 0.0035, 0.002 * 0.002).asDiagonal() * J_vib.transpose();
  const Eigen::Matrix4d C = unmodelledPixelCovariance(rig, px, n);
  EXPECT_LT((C - expected).cwiseAbs().maxCoeff(), 1e-4 * expected.cwiseAbs().maxCoeff()) << C << "\n\n" << expected;
  // The vibration moves both cameras' pixels together: u_l and u_r are correlated.
  EXPECT_GT(C(0, 2), 0.0);
  EXPECT_TRUE(unmodelledPixelCovariance(rig, px, UnmodelledNoise()).isZero());
}

TEST(UnmodelledNoise, RelativeRotationIsTheRightCamerasRotationJacobianWithoutTheDisparityOffset) {
  const StereoRig rig;
  const double f = rig.focal(), ou = rig.principalU(), ov = rig.principalV();
  const StereoPixels px{ou + 120.0, ov + 70.0, ou + 104.0, ov + 70.0};
  UnmodelledNoise n;
  n.relative_rotation_sigma_rad = 0.0017;
  const double x = (px.u_right - ou) / f, y = (px.v_right - ov) / f;
  const auto rot = [&](const Eigen::Vector3d& w) { return projectWithOpenCv(rig, x, y, Eigen::Vector4d::Zero(), w); };
  Eigen::Matrix<double, 2, 3> J = numericJacobian<2, 3>(rot, Eigen::Vector3d::Zero(), 1e-7);
  EXPECT_NEAR(J(0, 1), f * (1 + x * x), 1e-3 * f);  // yaw: the column moves by f (1 + x^2) ...
  J(0, 1) -= f;  // ... of which f is the disparity offset, a calibration parameter
  Eigen::Matrix4d expected = Eigen::Matrix4d::Zero();
  expected.block<2, 2>(2, 2) = 0.0017 * 0.0017 * J * J.transpose();
  const Eigen::Matrix4d C = unmodelledPixelCovariance(rig, px, n);
  EXPECT_LT((C - expected).cwiseAbs().maxCoeff(), 1e-4 * expected.cwiseAbs().maxCoeff()) << C << "\n\n" << expected;
  EXPECT_TRUE((C.block<2, 2>(0, 0).isZero()));  // the left camera is the reference
  EXPECT_FALSE(n.isZero());
}

TEST(UnmodelledNoise, MarkingFeaturesGetTheirDisparityTermOnTheRightColumn) {
  const StereoRig rig;
  const Sighting s = sight(rig, Pose2(100, 200, 0.2), 0.0, 700, -0.3, 25.0);
  Landmark lm;
  lm.id = 4;
  lm.position = s.landmark;
  ObservationModelConfig config{ObservationModel::PixelColumns, rig};
  config.unmodelled.marking_disparity_sigma_px = 1.5;
  config.unmodelled.intersection_disparity_sigma_px = 0.6;
  EXPECT_FALSE(config.unmodelled.isZero());
  const Observation obs = observationFromPixels(rig, 4, LandmarkType::MarkingCorner, s.pixels, 0.0, 0.5);
  const Eigen::Matrix4d own = obs.pixel_covariance;
  for (LandmarkType type : {LandmarkType::MarkingCorner, LandmarkType::Junction, LandmarkType::Intersection,
                            LandmarkType::GoalCorner}) {
    lm.type = type;
    Eigen::Matrix4d expected = own;
    const double sigma = type == LandmarkType::Intersection ? 0.6 : type == LandmarkType::GoalCorner ? 0.0 : 1.5;
    expected(2, 2) += sigma * sigma;
    EXPECT_LT((pixelCovarianceFor(obs, lm, config) - expected).cwiseAbs().maxCoeff(), 1e-12) << toString(type);
  }
}

TEST(UnmodelledNoise, EntersThePixelCovarianceAndTheOdometry) {
  const StereoRig rig;
  const Sighting s = sight(rig, Pose2(100, 200, 0.2), 0.0, 700, -0.3, 25.0);
  Landmark lm;
  lm.id = 4;
  lm.position = s.landmark;
  const Observation obs = observationFromPixels(rig, 4, LandmarkType::GoalCorner, s.pixels, 0.0, 0.5);
  ObservationModelConfig config{ObservationModel::PixelColumns, rig};
  const Eigen::Matrix4d plain = pixelCovarianceFor(obs, lm, config);
  config.unmodelled.k1_sigma = 0.01;
  config.unmodelled.roll_sigma_rad = 0.0035;
  EXPECT_LT((pixelCovarianceFor(obs, lm, config) - plain - unmodelledPixelCovariance(rig, s.pixels, config.unmodelled))
                .cwiseAbs()
                .maxCoeff(),
            1e-12);
  EXPECT_GT(pixelCovarianceFor(obs, lm, config)(0, 0), plain(0, 0));

  OdometryParams p;
  const OdometryParams q = withSlip(p, 20.0, -30.0, 0.02);
  const Eigen::Matrix2d grown = wheelCovariance(20.0, -30.0, q) - wheelCovariance(20.0, -30.0, p);
  EXPECT_NEAR(grown(0, 0), 0.36, 1e-12);  // (0.02 * 30)^2 on both wheels
  EXPECT_NEAR(grown(1, 1), 0.36, 1e-12);
}

TEST(UnmodelledNoise, FileRoundTripAndBadValues) {
  test::TempDir dir;
  UnmodelledNoise n;
  n.k1_sigma = 0.01;
  n.pitch_sigma_rad = 0.0035;
  n.slip_rel_sigma = 0.02;
  n.marking_disparity_sigma_px = 1.63;
  n.row_offset_sigma_px = 1.49;
  n.marking_slide_residual_sigma_px = 0.57;
  n.marking_slide_residual_per_gain_px = 0.32;
  n.marking_feature_offset_sigma_px = 0.58;
  n.intersection_slide_residual_sigma_px = 0.65;
  n.intersection_feature_offset_sigma_px = 0.32;
  n.goal_feature_column_sigma_px = 0.12;
  n.marking_feature_column_sigma_px = 0.19;
  n.intersection_feature_column_sigma_px = 0.14;
  n.wheel_scale_drift = 0.002;
  n.wheel_base_drift = 0.004;
  n.save(dir.file("noise.yaml"));
  const UnmodelledNoise back = UnmodelledNoise::load(dir.file("noise.yaml"));
  EXPECT_EQ(back.k1_sigma, 0.01);
  EXPECT_EQ(back.pitch_sigma_rad, 0.0035);
  EXPECT_EQ(back.slip_rel_sigma, 0.02);
  EXPECT_EQ(back.marking_disparity_sigma_px, 1.63);
  EXPECT_EQ(back.row_offset_sigma_px, 1.49);
  EXPECT_EQ(back.marking_slide_residual_sigma_px, 0.57);
  EXPECT_EQ(back.marking_slide_residual_per_gain_px, 0.32);
  EXPECT_EQ(back.marking_feature_offset_sigma_px, 0.58);
  EXPECT_EQ(back.intersection_slide_residual_sigma_px, 0.65);
  EXPECT_EQ(back.intersection_feature_offset_sigma_px, 0.32);
  EXPECT_EQ(back.goal_feature_column_sigma_px, 0.12);
  EXPECT_EQ(back.marking_feature_column_sigma_px, 0.19);
  EXPECT_EQ(back.intersection_feature_column_sigma_px, 0.14);
  EXPECT_EQ(back.wheel_scale_drift, 0.002);
  EXPECT_EQ(back.wheel_base_drift, 0.004);
  EXPECT_TRUE(back.wheelsDrift());
  EXPECT_EQ(back.roll_sigma_rad, 0.0);
  {
    std::ofstream f(dir.file("bad.yaml"));
    f << "%YAML:1.0\n---\nroll_sigma_rad: -0.1\n";
  }
  try {
    UnmodelledNoise::load(dir.file("bad.yaml"));
    FAIL() << "a negative sigma was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("roll_sigma_rad"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("bad.yaml"), std::string::npos) << e.what();
  }
}

// addRandomWalk on a positive definite information is the covariance form: (H^-1 + E Q E^T)^-1,
// the mean H^-1 g unchanged; variables with zero variance do not walk.
TEST(RandomWalk, IsTheCovarianceGrownInInformationForm) {
  Eigen::MatrixXd A(5, 5);
  A << 4, 1, 0.5, 0, 0.2,  //
      1, 3, 0.3, 0.1, 0,   //
      0.5, 0.3, 2, 0.4, 0.1,  //
      0, 0.1, 0.4, 5, 0.7,  //
      0.2, 0, 0.1, 0.7, 1;
  const Eigen::MatrixXd H0 = A * A.transpose();
  const Eigen::VectorXd g0 = (Eigen::VectorXd(5) << 0.3, -1.2, 0.7, 2.0, -0.4).finished();
  Eigen::MatrixXd H = H0;
  Eigen::VectorXd g = g0;
  const Eigen::Vector3d q(0.5, 0.0, 2.0);  // variables 2, 3, 4; 3 does not walk
  addRandomWalk(H, g, 2, q);
  Eigen::MatrixXd Sigma = H0.inverse();
  Sigma.diagonal().tail<3>() += q;
  EXPECT_LT((H - Sigma.inverse()).cwiseAbs().maxCoeff(), 1e-9 * H0.cwiseAbs().maxCoeff());
  EXPECT_LT((H.ldlt().solve(g) - H0.ldlt().solve(g0)).cwiseAbs().maxCoeff(), 1e-9);
  // Zero variances leave it as it was.
  Eigen::MatrixXd H2 = H0;
  Eigen::VectorXd g2 = g0;
  addRandomWalk(H2, g2, 0, Eigen::Vector2d::Zero());
  EXPECT_EQ(H2, H0);
  EXPECT_EQ(g2, g0);
}

// A singular information (nothing known along one variable, as a wheel base the marginalised
// poses did not see) stays without information there, and the rest walks as in covariance form.
TEST(RandomWalk, ADirectionWithoutInformationStaysWithout) {
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3, 3);
  H.topLeftCorner<2, 2>() << 4, 1, 1, 2;
  Eigen::VectorXd g = Eigen::Vector3d(1, -1, 0);
  const Eigen::Matrix2d Sigma = H.topLeftCorner<2, 2>().inverse() + Eigen::Vector2d(0, 0.25).asDiagonal().toDenseMatrix();
  addRandomWalk(H, g, 1, Eigen::Vector2d(0.25, 3.0));
  EXPECT_LT((H.topLeftCorner<2, 2>() - Sigma.inverse()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(H.row(2).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_LT(std::fabs(g[2]), 1e-15);
  EXPECT_THROW(addRandomWalk(H, g, 2, Eigen::Vector2d(1, 1)), Error);       // past the end
  EXPECT_THROW(addRandomWalk(H, g, 0, Eigen::Vector2d(-1, 1)), Error);      // a negative variance
  EXPECT_THROW(addRandomWalk(H, g, 0, Eigen::Vector2d(NAN, 1)), Error);
}

}  // namespace
}  // namespace stereoloc
