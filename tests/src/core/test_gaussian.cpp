#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <random>

#include "src/core/gaussian.h"

namespace stereoloc {

TEST(SqrtInformation, UpperFactorWhitensNonDiagonalCovariance) {
  Eigen::Matrix3d C;
  C << 400, 120, 1, 120, 100, -0.5, 1, -0.5, 0.035;  // = L L^T, L = [20 0 0; 6 8 0; .05 -.1 .15]
  const Eigen::Matrix3d S = sqrtInformationUpper<3>(C);
  // Upper triangular, and S^T S = C^-1.
  EXPECT_NEAR(S(1, 0), 0, 0);
  EXPECT_NEAR(S(2, 0), 0, 0);
  EXPECT_NEAR(S(2, 1), 0, 0);
  EXPECT_LT((S.transpose() * S - C.inverse()).norm() / C.inverse().norm(), 1e-12);
  // Whitened residuals of samples from N(0, C) have identity covariance.
  std::mt19937_64 rng(5);
  std::normal_distribution<double> N01;
  const Eigen::Matrix3d L = C.llt().matrixL();
  Eigen::Matrix3d acc = Eigen::Matrix3d::Zero();
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d e = L * Eigen::Vector3d(N01(rng), N01(rng), N01(rng));
    const Eigen::Vector3d w = S * e;
    acc += w * w.transpose();
  }
  EXPECT_LT((acc / n - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 0.02);
  // The lower factor of the information (Ceres pose_graph_2d's choice) does NOT whiten it.
  const Eigen::Matrix3d Lw = C.inverse().llt().matrixL();
  EXPECT_GT((Lw.transpose() * Lw - C.inverse()).norm() / C.inverse().norm(), 1e-3);
}

TEST(SqrtInformation, RejectsBadCovariances) {
  Eigen::Matrix2d C;
  C << 1, 2, 2, 1;  // indefinite
  EXPECT_THROW(sqrtInformationUpper<2>(C), Error);
  C << 1, 0.5, 0.4, 1;  // not symmetric
  EXPECT_THROW(sqrtInformationUpper<2>(C), Error);
  C << 1, 0, 0, std::nan("");
  EXPECT_THROW(sqrtInformationUpper<2>(C), Error);
}

TEST(ChiSquare, QuantilesMatchTables) {
  // Reference values from standard chi-square tables.
  EXPECT_NEAR(chi2Quantile(0.95, 1), 3.841458820694124, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.99, 1), 6.634896601021214, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.95, 2), 5.991464547107979, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.99, 2), 9.210340371976183, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.95, 3), 7.814727903251178, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.99, 3), 11.344866730144373, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.025, 3), 0.215795282623898, 1e-9);
  EXPECT_NEAR(chi2Quantile(0.975, 300), 349.874468829915, 1e-6);
}

TEST(ChiSquare, CdfInvertsQuantile) {
  for (int k = 1; k <= 30; ++k)
    for (double p : {0.001, 0.025, 0.5, 0.975, 0.999}) EXPECT_NEAR(chi2Cdf(chi2Quantile(p, k), k), p, 1e-10);
  EXPECT_THROW(chi2Quantile(1.0, 2), Error);
  EXPECT_THROW(chi2Quantile(0.5, 0), Error);
}

TEST(Mahalanobis, MatchesExplicitInverse) {
  Eigen::Matrix2d C;
  C << 4, 1, 1, 2;
  const Eigen::Vector2d e(1, -2);
  EXPECT_NEAR(mahalanobisSquared<2>(e, C), e.dot(C.inverse() * e), 1e-12);
}

}  // namespace stereoloc
