#include "solvers/chain_solver.h"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>
#include <random>

#include "factors/compass_factor.h"
#include "factors/odometry_factor.h"
#include "factors/pose_prior_factor.h"
#include "factors/range_bearing_factor.h"
#include "solvers/smoother_common.h"

namespace stereoloc {
namespace {

TEST(ChainSolver, BlockTridiagonalSolveEqualsDenseSolve) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> N(0.0, 1.0);
  const size_t n = 7;
  // A random SPD block tridiagonal matrix: J^T J of random "factors" on 1 or 2 consecutive poses.
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(3 * n, 3 * n);
  std::vector<Eigen::Matrix3d> D(n, Eigen::Matrix3d::Zero()), B(n, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Vector3d> rhs(n);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Matrix3d Ju;
    for (int k = 0; k < 9; ++k) Ju(k) = N(rng);
    H.block<3, 3>(3 * i, 3 * i) += Ju.transpose() * Ju;
    if (i > 0) {
      Eigen::Matrix<double, 3, 6> J;
      for (int k = 0; k < 18; ++k) J(k) = N(rng);
      H.block<6, 6>(3 * i - 3, 3 * i - 3) += J.transpose() * J;
    }
    for (int k = 0; k < 3; ++k) rhs[i](k) = N(rng);
  }
  for (size_t i = 0; i < n; ++i) {
    D[i] = H.block<3, 3>(3 * i, 3 * i);
    if (i > 0) B[i] = H.block<3, 3>(3 * i - 3, 3 * i);
  }
  Eigen::VectorXd b(3 * n);
  for (size_t i = 0; i < n; ++i) b.segment<3>(3 * i) = rhs[i];
  for (const double damping : {0.0, 1e-3, 10.0}) {
    Eigen::MatrixXd A = H;
    for (int k = 0; k < A.rows(); ++k) A(k, k) += damping * std::max(H(k, k), 1e-6);
    const Eigen::VectorXd expected = A.llt().solve(b);
    std::vector<Eigen::Matrix3d> G;
    std::vector<Eigen::Vector3d> dx;
    ASSERT_TRUE(solveBlockTridiagonal(D, B, rhs, damping, &G, &dx));
    for (size_t i = 0; i < n; ++i) EXPECT_LT((dx[i] - expected.segment<3>(3 * i)).norm(), 1e-9 * expected.norm()) << damping;
  }
  // A singular pivot is reported, not solved.
  std::vector<Eigen::Matrix3d> Z(n, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Matrix3d> G;
  std::vector<Eigen::Vector3d> dx;
  EXPECT_FALSE(solveBlockTridiagonal(Z, Z, rhs, 0.0, &G, &dx));
}

// The bordered (arrow) system of a chain with global columns, against the dense solve and the
// dense inverse.
TEST(ChainSolver, BorderedSolveAndCovariancesEqualDense) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> N(0.0, 1.0);
  const size_t n = 9;
  const int K = 4;
  const int m = 3 * static_cast<int>(n) + K;
  // J^T J of random factors on one pose, two consecutive poses, a pose and the globals, the globals alone.
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(m, m);
  auto add = [&](const std::vector<int>& columns) {
    Eigen::MatrixXd J(3, columns.size());
    for (int k = 0; k < J.size(); ++k) J(k) = N(rng);
    const Eigen::MatrixXd h = J.transpose() * J;
    for (size_t a = 0; a < columns.size(); ++a)
      for (size_t b = 0; b < columns.size(); ++b) H(columns[a], columns[b]) += h(a, b);
  };
  for (size_t i = 0; i < n; ++i) {
    const int p = 3 * static_cast<int>(i);
    add({p, p + 1, p + 2});
    if (i > 0) add({p - 3, p - 2, p - 1, p, p + 1, p + 2});
    add({p, p + 1, p + 2, m - 4, m - 3, m - 2, m - 1});
  }
  add({m - 4, m - 3, m - 2, m - 1});
  BorderedSystem h;
  h.D.assign(n, Eigen::Matrix3d::Zero());
  h.B.assign(n, Eigen::Matrix3d::Zero());
  for (size_t i = 0; i < n; ++i) {
    h.D[i] = H.block<3, 3>(3 * i, 3 * i);
    if (i > 0) h.B[i] = H.block<3, 3>(3 * i - 3, 3 * i);
  }
  h.E = H.topRightCorner(3 * n, K);
  h.C = H.bottomRightCorner(K, K);
  Eigen::VectorXd b(m);
  for (int k = 0; k < m; ++k) b(k) = N(rng);
  for (const double damping : {0.0, 1e-3, 10.0}) {
    Eigen::MatrixXd A = H;
    for (int k = 0; k < m; ++k) A(k, k) += damping * std::max(H(k, k), 1e-6);
    const Eigen::VectorXd expected = A.llt().solve(b);
    Eigen::VectorXd dx, dc;
    ASSERT_TRUE(solveBorderedBlockTridiagonal(h, b.head(3 * n), b.tail(K), damping, &dx, &dc));
    EXPECT_LT((dx - expected.head(3 * n)).norm(), 1e-9 * expected.norm()) << damping;
    EXPECT_LT((dc - expected.tail(K)).norm(), 1e-9 * expected.norm()) << damping;
  }
  const Eigen::MatrixXd inverse = H.inverse();
  std::vector<Eigen::Matrix3d> cov;
  Eigen::MatrixXd global_cov;
  ASSERT_TRUE(borderedMarginalCovariances(h, &cov, &global_cov));
  for (size_t i = 0; i < n; ++i)
    EXPECT_LT((cov[i] - inverse.block<3, 3>(3 * i, 3 * i)).norm(), 1e-9 * inverse.norm()) << i;
  EXPECT_LT((global_cov - inverse.bottomRightCorner(K, K)).norm(), 1e-9 * inverse.norm());
  // Globals no factor determines: rank deficient, reported.
  h.E.setZero();
  h.C.setZero();
  EXPECT_FALSE(borderedMarginalCovariances(h, &cov, &global_cov));
}

// A small chain: a prior, odometry, a compass on every third pose and range-bearing observations
// of two landmarks; cut_at can remove one odometry factor.
class TestChain : public ChainFactorSource {
 public:
  explicit TestChain(size_t n) : n_(n) {
    std::mt19937_64 rng(11);
    std::normal_distribution<double> N(0.0, 1.0);
    Pose2 p;
    for (size_t i = 0; i < n; ++i) {
      if (i > 0) {
        const Pose2 u(20.0 + N(rng), 0.5 * N(rng), 0.05 * N(rng));
        p = compose(p, u);
        u_.push_back(Eigen::Vector3d(u.x + 0.3 * N(rng), u.y + 0.3 * N(rng), u.theta + 0.003 * N(rng)));
      } else {
        u_.push_back(Eigen::Vector3d::Zero());
      }
      truth_.push_back(p);
      for (const Eigen::Vector2d& l : landmarks_) {
        const Eigen::Vector2d d = l - p.translation();
        z_.push_back(Eigen::Vector2d(d.norm() + 5.0 * N(rng), wrapAngle(std::atan2(d.y(), d.x()) - p.theta + 0.01 * N(rng))));
      }
    }
  }
  size_t size() const override { return n_; }
  void unaryFactors(size_t i, std::vector<ChainFactor>* out) const override {
    if (i == 0)
      out->push_back({std::unique_ptr<ceres::CostFunction>(PosePriorFactor::Create(truth_[0], Eigen::Matrix3d::Identity())), false});
    if (i % 3 == 0)
      out->push_back({std::unique_ptr<ceres::CostFunction>(CompassFactor::Create(truth_[i].theta + 0.01, 0.05)), false});
    for (size_t l = 0; l < landmarks_.size(); ++l)
      out->push_back({std::unique_ptr<ceres::CostFunction>(RangeBearingFactor::Create(
                          landmarks_[l], z_[landmarks_.size() * i + l], Eigen::Vector2d(25.0, 1e-4).asDiagonal())),
                      true});
  }
  ChainFactor binaryFactor(size_t i) const override {
    if (i == 0 || i == cut_at) return {};
    return {std::unique_ptr<ceres::CostFunction>(OdometryFactor::Create(u_[i], Eigen::Vector3d(0.09, 0.09, 1e-5).asDiagonal())),
            false};
  }
  const std::vector<Pose2>& truth() const { return truth_; }
  size_t cut_at = 0;

 private:
  size_t n_;
  std::vector<Eigen::Vector2d> landmarks_ = {Eigen::Vector2d(500, 800), Eigen::Vector2d(1500, -600)};
  std::vector<Eigen::Vector3d> u_;
  std::vector<Eigen::Vector2d> z_;
  std::vector<Pose2> truth_;
};

std::vector<double> perturbed(const std::vector<Pose2>& poses, double sigma) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> N(0.0, 1.0);
  std::vector<double> x;
  for (const Pose2& p : poses) {
    x.push_back(p.x + sigma * N(rng));
    x.push_back(p.y + sigma * N(rng));
    x.push_back(wrapAngle(p.theta + 0.01 * sigma * N(rng)));
  }
  return x;
}

TEST(ChainSolver, ConvergesToAStationaryPointAndLinearisationMatchesCost) {
  const TestChain chain(60);
  const std::unique_ptr<ceres::LossFunction> loss = makeLossFunction({RobustLoss::Huber, 1.345});
  const ChainProblem problem(chain, loss.get());
  std::vector<double> x = perturbed(chain.truth(), 30.0);
  ChainSolverOptions o;
  o.function_tolerance = 0;
  o.gradient_tolerance = 1e-9;
  o.parameter_tolerance = 1e-16;
  const ChainSolverSummary s = problem.solve(0, chain.size(), &x, o);
  ASSERT_TRUE(s.usable);
  EXPECT_TRUE(s.converged) << s.message;
  EXPECT_LT(s.final_cost, s.initial_cost);
  std::vector<Eigen::Matrix3d> D, B;
  std::vector<Eigen::Vector3d> g;
  double cost = 0, cost2 = 0;
  ASSERT_TRUE(problem.linearise(0, chain.size(), x, &D, &B, &g, &cost));
  ASSERT_TRUE(problem.cost(0, chain.size(), x, &cost2));
  EXPECT_DOUBLE_EQ(cost, cost2);
  EXPECT_DOUBLE_EQ(cost, s.final_cost);
  for (const Eigen::Vector3d& gi : g) EXPECT_LT(gi.cwiseAbs().maxCoeff(), 1e-6);
  // The gradient is the central difference of the cost.
  std::vector<double> y = perturbed(chain.truth(), 3.0);
  ASSERT_TRUE(problem.linearise(0, chain.size(), y, &D, &B, &g, &cost));
  for (size_t i : {0ul, 17ul, 59ul})
    for (int k = 0; k < 3; ++k) {
      const double h = k == 2 ? 1e-7 : 1e-4;
      std::vector<double> yp = y, ym = y;
      yp[3 * i + k] += h;
      ym[3 * i + k] -= h;
      double cp = 0, cm = 0;
      ASSERT_TRUE(problem.cost(0, chain.size(), yp, &cp));
      ASSERT_TRUE(problem.cost(0, chain.size(), ym, &cm));
      EXPECT_NEAR(g[i](k), (cp - cm) / (2 * h), 1e-4 * std::max(1.0, std::fabs(g[i](k)))) << i << " " << k;
    }
}

TEST(ChainSolver, WindowWithFixedNeighboursKeepsTheOptimumAndSolvesItsPart) {
  TestChain chain(80);
  const ChainProblem problem(chain, nullptr);
  std::vector<double> x = perturbed(chain.truth(), 10.0);
  ChainSolverOptions o;
  o.function_tolerance = 1e-16;
  o.parameter_tolerance = 1e-15;
  ASSERT_TRUE(problem.solve(0, 80, &x, o).converged);
  const std::vector<double> optimum = x;
  // Disturb poses 30..49 and solve only them, neighbours 29 and 50 held: back to the optimum.
  for (size_t i = 30; i < 50; ++i) x[3 * i] += 7.0;
  const ChainSolverSummary s = problem.solve(30, 50, &x, o);
  ASSERT_TRUE(s.converged);
  for (size_t i = 0; i < 3 * 80; ++i) EXPECT_NEAR(x[i], optimum[i], 1e-6) << i;
  // Cost of a range = the factors touching it: with the chain cut at 40, the two halves add up.
  chain.cut_at = 40;
  double a = 0, b = 0, all = 0;
  ASSERT_TRUE(problem.cost(0, 40, x, &a));
  ASSERT_TRUE(problem.cost(40, 80, x, &b));
  ASSERT_TRUE(problem.cost(0, 80, x, &all));
  EXPECT_NEAR(a + b, all, 1e-9 * all);
}

}  // namespace
}  // namespace stereoloc
