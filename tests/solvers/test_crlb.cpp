// Posterior Cramér–Rao bound: factor information against central differences, the filtering and
// smoothing bounds against the exact Kalman filter / smoother covariance on a linear-Gaussian
// case (the EKF and the batch smoother linearised at the truth) and against dense inverses,
// smoothing <= fixed lag <= filtering, information adds, Monte Carlo efficiency of the batch
// smoother, bad input.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "solvers/batch_smoother.h"
#include "solvers/crlb.h"
#include "solvers/ekf.h"
#include "solvers/smoother_common.h"
#include "src/core/measurement_model.h"
#include "src/core/numeric_diff.h"
#include "src/core/odometry_model.h"
#include "src/sim/scenario.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

const Eigen::Matrix3d kCrlbStartCovariance = Eigen::Vector3d(20.0, 20.0, 0.05).cwiseAbs2().asDiagonal();

double relError(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(1e-300, b.cwiseAbs().maxCoeff());
}

// Smallest eigenvalue of a symmetric matrix, relative to its scale.
double minEigenRelative(const Eigen::Matrix3d& M, double scale) {
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(0.5 * (M + M.transpose())).eigenvalues()(0) / scale;
}

// A problem whose measurements are exact (no odometry, compass or observation noise): every
// estimator started at the truth stays there, so it linearises at the truth, and its
// covariance is the Kalman covariance of the model linearised at the truth.
SyntheticProblem exactProblem(int steps, uint64_t seed) {
  SyntheticProblemOptions o;
  o.steps = steps;
  o.noisy_odometry = false;
  o.compass_sigma = 0.05;
  SyntheticProblem p = makeRandomWalkProblem(o, seed);
  for (size_t k = 0; k < p.steps.size(); ++k) {
    p.steps[k].compass = p.truth[k].theta;
    for (Observation& obs : p.steps[k].observations) {
      const Eigen::Vector2d z = predictRangeBearing(p.truth[k], p.map.at(obs.landmark_id).xy());
      obs.range = z(0);
      obs.bearing = z(1);
    }
  }
  return p;
}

TEST(Crlb, OdometryInformationMatchesCentralDifferences) {
  const Eigen::Matrix3d U = Eigen::Vector3d(1.5, 0.7, 0.01).cwiseAbs2().asDiagonal();
  for (const auto& ab : {std::pair<Pose2, Pose2>{Pose2(100, 200, 0.3), Pose2(120, 215, 0.5)},
                         std::pair<Pose2, Pose2>{Pose2(-50, 10, kPi - 1e-4), Pose2(-70, 12, -kPi + 2e-4)},
                         std::pair<Pose2, Pose2>{Pose2(0, 0, -kPi + 1e-5), Pose2(3, -25, kPi - 0.1)}}) {
    const Pose2 u = between(ab.first, ab.second);  // the residual vanishes at the truth
    const auto residual = [&](const Eigen::Matrix<double, 6, 1>& x) {
      const Pose2 a(x(0), x(1), x(2)), b(x(3), x(4), x(5));
      return minus(between(a, b), u);
    };
    Eigen::Matrix<double, 6, 1> x0;
    x0 << ab.first.x, ab.first.y, ab.first.theta, ab.second.x, ab.second.y, ab.second.theta;
    const Eigen::Matrix<double, 3, 6> J = numericJacobian<3, 6>(
        residual, x0, [](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
          return Eigen::Vector3d(a(0) - b(0), a(1) - b(1), angleDiff(a(2), b(2)));
        });
    const Eigen::Matrix<double, 6, 6> numeric = J.transpose() * U.inverse() * J;
    const Eigen::Matrix<double, 6, 6> analytic = odometryFactorInformation(ab.first, ab.second, U);
    EXPECT_LT(relError(analytic, numeric), 1e-6) << analytic << "\n\n" << numeric;
  }
}

TEST(Crlb, RangeBearingInformationMatchesCentralDifferences) {
  Eigen::Matrix2d R;
  R << 225.0, 0.1, 0.1, 4e-4;
  const Eigen::Vector2d landmark(750.0, 0.0);
  // Poses whose bearing to the landmark is near +-pi, and a heading near +-pi.
  for (const Pose2& p : {Pose2(400, 300, 0.2), Pose2(1200, 1e-3, 0.0), Pose2(1200, -1e-3, 0.0),
                         Pose2(300, 50, kPi - 1e-6), Pose2(900, 400, -kPi + 1e-6)}) {
    const auto h = [&](const Eigen::Vector3d& x) { return predictRangeBearing(Pose2(x(0), x(1), x(2)), landmark); };
    const Eigen::Matrix<double, 2, 3> H = numericJacobian<2, 3>(
        h, p.vector(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) { return rangeBearingInnovation(a, b); });
    const Eigen::Matrix3d numeric = H.transpose() * R.inverse() * H;
    EXPECT_LT(relError(rangeBearingInformation(p, landmark, R), numeric), 1e-6);
  }
  EXPECT_THROW(rangeBearingInformation(Pose2(750, 0, 0), landmark, R), GeometryError);
}

// For an untilted rig (u_l, u_r) and (range, bearing) are one-to-one, so the information of the
// pixel columns is the range-bearing information with R (5.32) evaluated at the TRUE pixels; the
// rows add range information from the known heights (a positive semi-definite difference,
// strictly positive along range). (A tilted rig's triangulation also uses v, so there the
// range-bearing form holds some of the rows' noise and information.)
TEST(Crlb, PixelInformationOfColumnsIsRangeBearingAtTheTruePixels) {
  StereoRigParams params;
  params.offset_x_mm = 15.0;
  const StereoRig rig(params);
  for (const Pose2& pose : {Pose2(400, 300, 0.2), Pose2(900, 400, kPi - 1e-6), Pose2(100, -200, -1.2)}) {
    for (double pan : {0.0, 0.3}) {
      for (double range : {300.0, 900.0, 1800.0}) {
        const double bearing = pan - 0.2;
        const Eigen::Vector2d local(range * std::cos(bearing), range * std::sin(bearing));
        const Eigen::Vector2d world = transformToWorld(pose, local);
        const std::optional<StereoPixels> px = rig.project(Eigen::Vector3d(local.x(), local.y(), 25.0), pan);
        ASSERT_TRUE(px.has_value());
        Landmark lm;
        lm.id = 0;
        lm.position = Eigen::Vector3d(world.x(), world.y(), 25.0);
        const Observation obs = observationFromPixels(rig, 0, LandmarkType::GoalCorner, *px, pan, 0.5);
        const Eigen::Matrix2d R_true = rig.rangeBearingCovariance(*px, pan, 0.5);
        const Eigen::Matrix3d rb = rangeBearingInformation(pose, world, R_true);
        const Eigen::Matrix3d cols = pixelInformation(pose, obs, lm, {ObservationModel::PixelColumns, rig});
        const Eigen::Matrix3d all = pixelInformation(pose, obs, lm, {ObservationModel::Pixels, rig});
        EXPECT_LT(relError(cols, rb), 1e-6) << range;
        const Eigen::Matrix3d extra = all - cols;
        EXPECT_GT(minEigenRelative(extra, extra.norm()), -1e-9) << range;
        const Eigen::Vector3d along_range(std::cos(pose.theta + bearing), std::sin(pose.theta + bearing), 0.0);
        EXPECT_GT(along_range.dot(extra * along_range), 1e-3 * along_range.dot(cols * along_range)) << range;
      }
    }
  }
}

TEST(Crlb, FilteringBoundEqualsTheKalmanFilterOnALinearGaussianCase) {
  const SyntheticProblem p = exactProblem(80, 3);
  EkfConfig c;
  c.init = knownBelief(p.truth[0], kCrlbStartCovariance);
  Ekf ekf(p.map, p.odometry, c);
  std::vector<Estimate> est;
  for (const Step& s : p.steps) est.push_back(ekf.process(s));
  const TrajectoryInformation info = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
  EXPECT_GT(info.observations_used, 80);
  EXPECT_EQ(info.compass_used, 80);
  const std::vector<Eigen::Matrix3d> bound = filteringBound(info);
  ASSERT_EQ(bound.size(), est.size());
  for (size_t k = 0; k < est.size(); ++k) {
    ASSERT_LT(minus(est[k].pose, p.truth[k]).norm(), 1e-6) << "the EKF left the truth at " << k;
    EXPECT_LT(relError(bound[k], est[k].covariance), 1e-6) << "pose " << k << "\n" << bound[k] << "\n\n" << est[k].covariance;
  }
}

TEST(Crlb, SmoothingBoundEqualsTheKalmanSmootherOnALinearGaussianCase) {
  const SyntheticProblem p = exactProblem(80, 4);
  const TrajectoryInformation info = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
  const std::vector<Eigen::Matrix3d> smooth = smoothingBound(info);
  const std::vector<Eigen::Matrix3d> filt = filteringBound(info);
  // The Rauch-Tung-Striebel smoother in covariance form, from the filter's covariances and the
  // compounding Jacobian J1 (B.18) at the truth: an independent route to the same numbers.
  const size_t n = p.steps.size();
  std::vector<Eigen::Matrix3d> rts(n);
  rts[n - 1] = filt[n - 1];
  for (size_t k = n - 1; k-- > 0;) {
    const Step& s = p.steps[k + 1];
    const Eigen::Vector3d u = controlVector(s.d_left, s.d_right, p.odometry.wheel_base_mm);
    Matrix3d J1;
    compose(p.truth[k], Pose2(u.x(), u.y(), u.z()), &J1);
    const Eigen::Matrix3d Ppred = predictPose(p.truth[k], filt[k], s.d_left, s.d_right, p.odometry).covariance;
    const Eigen::Matrix3d C = filt[k] * J1.transpose() * Ppred.inverse();
    rts[k] = filt[k] + C * (rts[k + 1] - Ppred) * C.transpose();
  }
  for (size_t k = 0; k < n; ++k) EXPECT_LT(relError(smooth[k], rts[k]), 1e-6) << "pose " << k;
  // The batch smoother started at the truth stays there; its chain covariance is the bound.
  BatchSmootherConfig bc;
  bc.init = knownBelief(p.truth[0], kCrlbStartCovariance);
  BatchSmoother batch(p.map, p.odometry, bc);
  for (const Step& s : p.steps) batch.process(s);
  const std::vector<Estimate> est = batch.finish();
  ASSERT_EQ(batch.summary().covariance_status, CovarianceStatus::Ok);
  for (size_t k = 0; k < n; ++k) {
    ASSERT_LT(minus(est[k].pose, p.truth[k]).norm(), 1e-6);
    EXPECT_LT(relError(smooth[k], est[k].covariance), 1e-6) << "pose " << k;
  }
}

TEST(Crlb, BoundsAreTheMarginalsOfTheDenseInverse) {
  SyntheticProblemOptions o;
  o.steps = 40;
  o.compass_sigma = 0.1;
  o.observation_probability = 0.4;  // some steps without observations
  const SyntheticProblem p = makeRandomWalkProblem(o, 8);
  const TrajectoryInformation info = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
  const Eigen::MatrixXd full_cov = info.dense().inverse();
  const std::vector<Eigen::Matrix3d> smooth = smoothingBound(info);
  std::vector<Eigen::Matrix3d> D, B, chain;
  info.chainBlocks(&D, &B);
  ASSERT_TRUE(chainMarginalCovariances(D, B, &chain));
  const std::vector<Eigen::Matrix3d> filt = filteringBound(info);
  for (int lag : {0, 1, 4, 39}) {
    const std::vector<Eigen::Matrix3d> fixed = fixedLagBound(info, lag);
    for (size_t k = 0; k < p.steps.size(); ++k) {
      // The bound of pose k from the data up to step m = k + lag: the inverse of the
      // information of the trajectory truncated at m.
      const size_t m = std::min(k + static_cast<size_t>(lag), p.steps.size() - 1);
      const std::vector<Step> head(p.steps.begin(), p.steps.begin() + static_cast<long>(m) + 1);
      const std::vector<Pose2> truth(p.truth.begin(), p.truth.begin() + static_cast<long>(m) + 1);
      const Eigen::MatrixXd cov = trajectoryInformation(head, truth, p.map, p.odometry, kCrlbStartCovariance).dense().inverse();
      EXPECT_LT(relError(fixed[k], cov.block<3, 3>(3 * static_cast<long>(k), 3 * static_cast<long>(k))), 1e-8)
          << "lag " << lag << " pose " << k;
    }
    if (lag == 0) {
      for (size_t k = 0; k < p.steps.size(); ++k) EXPECT_LT(relError(fixed[k], filt[k]), 1e-12);
    }
  }
  for (size_t k = 0; k < p.steps.size(); ++k) {
    const Eigen::Matrix3d block = full_cov.block<3, 3>(3 * static_cast<long>(k), 3 * static_cast<long>(k));
    EXPECT_LT(relError(smooth[k], block), 1e-8) << "pose " << k;
    EXPECT_LT(relError(chain[k], block), 1e-8) << "pose " << k;
  }
}

TEST(Crlb, SmoothingBoundIsBelowFixedLagBelowFiltering) {
  SyntheticProblemOptions o;
  o.steps = 150;
  const SyntheticProblem p = makeRandomWalkProblem(o, 21);
  const TrajectoryInformation info = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
  const std::vector<Eigen::Matrix3d> smooth = smoothingBound(info), filt = filteringBound(info);
  const std::vector<Eigen::Matrix3d> lag5 = fixedLagBound(info, 5), lag20 = fixedLagBound(info, 20);
  double smooth_trace = 0, filt_trace = 0;
  for (size_t k = 0; k < smooth.size(); ++k) {
    const double scale = filt[k].cwiseAbs().maxCoeff();
    EXPECT_GT(minEigenRelative(filt[k] - lag5[k], scale), -1e-9) << k;
    EXPECT_GT(minEigenRelative(lag5[k] - lag20[k], scale), -1e-9) << k;
    EXPECT_GT(minEigenRelative(lag20[k] - smooth[k], scale), -1e-9) << k;
    EXPECT_GT(minEigenRelative(smooth[k], scale), 0.0) << k;
    smooth_trace += smooth[k].topLeftCorner<2, 2>().trace();
    filt_trace += filt[k].topLeftCorner<2, 2>().trace();
  }
  // Not trivially equal: the future observations matter.
  EXPECT_LT(smooth_trace, 0.8 * filt_trace);
  // The last pose has no future: smoothing and filtering agree there.
  EXPECT_LT(relError(smooth.back(), filt.back()), 1e-9);
}

TEST(Crlb, InformationAdds) {
  SyntheticProblemOptions o;
  o.steps = 60;
  o.compass_sigma = 0.08;
  const SyntheticProblem p = makeRandomWalkProblem(o, 5);
  CrlbOptions motion, sensing;
  motion.observations = motion.compass = false;
  sensing.prior = sensing.odometry = false;
  TrajectoryInformation sum = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance, motion);
  const TrajectoryInformation obs = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance, sensing);
  EXPECT_EQ(obs.odometry_cross[10].norm(), 0.0);
  EXPECT_GT(obs.unary[10].norm(), 0.0);
  sum += obs;
  const TrajectoryInformation all = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
  EXPECT_LT(relError(sum.dense(), all.dense()), 1e-14);
  EXPECT_EQ(sum.observations_used, all.observations_used);
  EXPECT_EQ(sum.compass_used, all.compass_used);
  // More information never raises the bound: odometry alone (dead reckoning) bounds from above.
  const std::vector<Eigen::Matrix3d> dr = smoothingBound(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance, motion));
  const std::vector<Eigen::Matrix3d> full = smoothingBound(all);
  for (size_t k = 0; k < full.size(); ++k)
    EXPECT_GT(minEigenRelative(dr[k] - full[k], dr[k].cwiseAbs().maxCoeff()), -1e-9) << k;
  // Dead reckoning's bound is the propagated covariance (5.9) with U at the true increments.
  Eigen::Matrix3d P = kCrlbStartCovariance;
  for (size_t k = 1; k < p.steps.size(); ++k) {
    const Arc arc = arcBetween(p.truth[k - 1], p.truth[k]);
    const WheelIncrements w = wheelIncrementsForArc(arc.length, arc.dtheta, p.odometry.wheel_base_mm);
    P = predictPose(p.truth[k - 1], P, w.d_left, w.d_right, p.odometry).covariance;
  }
  EXPECT_LT(relError(filteringBound(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance, motion)).back(), P),
            1e-6);
  // Observations alone do not determine a pose that sees nothing: singular, reported.
  std::vector<Step> blind = p.steps;
  blind[10].observations.clear();
  CrlbOptions only_observations = sensing;
  only_observations.compass = false;
  try {
    smoothingBound(trajectoryInformation(blind, p.truth, p.map, p.odometry, kCrlbStartCovariance, only_observations));
    FAIL() << "a singular information was not reported";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("singular"), std::string::npos) << e.what();
  }
  TrajectoryInformation other = TrajectoryInformation::zero({0, 1});
  EXPECT_THROW(sum += other, Error);
}

TEST(Crlb, BatchSmootherAttainsTheSmoothingBoundInMonteCarlo) {
  // The efficiency targeted (RMSE / sqrt(CRLB) close to 1), on a small scale.
  SyntheticProblemOptions o;
  o.steps = 80;
  double se_batch = 0, bound_smooth = 0, se_ekf = 0, bound_filt = 0;
  const Eigen::Vector3d sigma0(20.0, 20.0, 0.05);
  for (uint64_t seed = 0; seed < 30; ++seed) {
    const SyntheticProblem p = makeRandomWalkProblem(o, 1000 + seed);
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> N(0.0, 1.0);
    const Pose2 start = plus(p.truth[0], Eigen::Vector3d(sigma0(0) * N(rng), sigma0(1) * N(rng), sigma0(2) * N(rng)));
    BatchSmootherConfig bc;
    bc.init = knownBelief(start, kCrlbStartCovariance);
    BatchSmoother batch(p.map, p.odometry, bc);
    EkfConfig ec;
    ec.init = bc.init;
    Ekf ekf(p.map, p.odometry, ec);
    std::vector<Estimate> filtered;
    for (const Step& s : p.steps) {
      batch.process(s);
      filtered.push_back(ekf.process(s));
    }
    const std::vector<Estimate> smoothed = batch.finish();
    const TrajectoryInformation info = trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance);
    const std::vector<Eigen::Matrix3d> sb = smoothingBound(info), fb = filteringBound(info);
    for (size_t k = 0; k < p.steps.size(); ++k) {
      se_batch += (smoothed[k].pose.translation() - p.truth[k].translation()).squaredNorm();
      se_ekf += (filtered[k].pose.translation() - p.truth[k].translation()).squaredNorm();
      bound_smooth += sb[k].topLeftCorner<2, 2>().trace();
      bound_filt += fb[k].topLeftCorner<2, 2>().trace();
    }
  }
  const double batch_ratio = std::sqrt(se_batch / bound_smooth), ekf_ratio = std::sqrt(se_ekf / bound_filt);
  std::printf("RMSE/sqrt(CRLB): batch %.3f (smoothing bound), EKF %.3f (filtering bound)\n", batch_ratio, ekf_ratio);
  EXPECT_GT(batch_ratio, 0.8);
  EXPECT_LT(batch_ratio, 1.2);
  EXPECT_GT(ekf_ratio, 0.8);
  EXPECT_LT(bound_smooth, bound_filt);
}

// The stereo pixel factors on simulated stereo (the `line` scenario, goal corners, 0.5 px):
// the batch smoother with pixel factors reaches its bound (target: RMSE / sqrt(CRLB) <= 1.15),
// each model against the bound of the data it uses, and the rows add information.
TEST(Crlb, BatchSmootherWithPixelFactorsAttainsThePixelBound) {
  const Eigen::Vector3d sigma0(20.0, 20.0, 0.05);
  const Eigen::Matrix3d P0 = sigma0.cwiseAbs2().asDiagonal();
  for (ObservationModel model : {ObservationModel::PixelColumns, ObservationModel::Pixels}) {
    double se = 0, bound = 0, bound_rb = 0;
    for (uint64_t seed = 0; seed < 25; ++seed) {
      const Dataset d = simulate("line", 0, SimulationConfig(), 500 + seed);
      std::mt19937_64 rng(seed);
      std::normal_distribution<double> N(0.0, 1.0);
      const Pose2 truth0 = *d.groundtruth[0];
      const Pose2 start = plus(truth0, Eigen::Vector3d(sigma0(0) * N(rng), sigma0(1) * N(rng), sigma0(2) * N(rng)));
      BatchSmootherConfig bc;
      bc.init = knownBelief(start, P0);
      bc.observation_model = {model, d.rig};
      BatchSmoother batch(d.map, d.odometry, bc);
      for (const Step& s : d.steps) batch.process(s);
      const std::vector<Estimate> smoothed = batch.finish();
      ASSERT_EQ(smoothed.size(), d.steps.size());
      CrlbOptions co;
      co.observation_model = bc.observation_model;
      const std::vector<Eigen::Matrix3d> sb = smoothingBound(trajectoryInformation(d, P0, co));
      const std::vector<Eigen::Matrix3d> rb = smoothingBound(trajectoryInformation(d, P0));
      for (size_t k = 0; k < d.steps.size(); ++k) {
        se += (smoothed[k].pose.translation() - d.groundtruth[k]->translation()).squaredNorm();
        bound += sb[k].topLeftCorner<2, 2>().trace();
        bound_rb += rb[k].topLeftCorner<2, 2>().trace();
      }
    }
    const double ratio = std::sqrt(se / bound);
    std::printf("%s: RMSE/sqrt(CRLB) %.3f, bound/range-bearing bound %.3f\n", toString(model).c_str(), ratio,
                std::sqrt(bound / bound_rb));
    EXPECT_GT(ratio, 0.8) << toString(model);
    EXPECT_LT(ratio, 1.15) << toString(model);
    if (model == ObservationModel::Pixels) {
      EXPECT_LT(bound, 0.8 * bound_rb);  // range from the known heights
    } else {
      EXPECT_NEAR(bound / bound_rb, 1.0, 0.1);  // the same data
    }
  }
}

TEST(Crlb, RejectsBadInput) {
  SyntheticProblemOptions o;
  o.steps = 10;
  SyntheticProblem p = makeRandomWalkProblem(o, 1);
  std::vector<Pose2> short_truth(p.truth.begin(), p.truth.end() - 1);
  EXPECT_THROW(trajectoryInformation(p.steps, short_truth, p.map, p.odometry, kCrlbStartCovariance), Error);
  EXPECT_THROW(trajectoryInformation({}, {}, p.map, p.odometry, kCrlbStartCovariance), Error);
  EXPECT_THROW(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, -kCrlbStartCovariance), Error);
  EXPECT_THROW(fixedLagBound(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance), -1), Error);
  p.steps[3].observations.push_back(observationFromRangeBearing(77, LandmarkType::Point, 500.0, 0.1, 10.0, 0.01));
  EXPECT_THROW(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance), Error);
  p.steps[3].observations.back().landmark_id = -1;  // unidentified: not information, counted
  EXPECT_EQ(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance).observations_skipped, 1);
  p.steps[5].step = p.steps[4].step;
  EXPECT_THROW(trajectoryInformation(p.steps, p.truth, p.map, p.odometry, kCrlbStartCovariance), Error);
  EXPECT_EQ(toString(odometryCovarianceAtFromString("measured")), "measured");
  EXPECT_THROW(odometryCovarianceAtFromString("bogus"), Error);
}

}  // namespace
}  // namespace stereoloc
