#pragma once
// Levenberg-Marquardt for a chain of 2D poses: the least-squares problem of the batch smoother
// (solvers/batch_smoother.h), where every factor touches one pose (prior, compass, landmark
// observation) or two consecutive poses (odometry). Its Gauss-Newton information is block
// tridiagonal, so each iteration costs O(N) time and memory: one pass evaluates the factors into
// the 3x3 blocks D_i = H(i, i), B_i = H(i-1, i) and the gradient g_i, and the damped system is
// solved by block forward elimination and back substitution (solveBlockTridiagonal). A general
// sparse solver (Ceres's SPARSE_NORMAL_CHOLESKY, BatchSolver::Ceres) reaches the same optimum
// with several times the work and memory per pose (tools/bench/bench_smoothers.cpp).
//
// The factors are Ceres cost functions (factors/), made on demand by a ChainFactorSource so that
// a million-step problem does not hold millions of them. Poses are (x, y, theta) in mm, mm, rad
// with the Plus of factors/pose_manifold.h; a robust loss applies to the factors marked robust.
// Damping, step acceptance and the three stopping tolerances are modelled on ceres::Solver's
// LEVENBERG_MARQUARDT (chain_solver.cpp says where they differ); both reach the same optimum.
#include <ceres/cost_function.h>
#include <ceres/loss_function.h>

#include <Eigen/Core>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace stereoloc {

struct ChainFactor {
  std::unique_ptr<ceres::CostFunction> cost;  // one parameter block of 3 (unary) or two (binary)
  bool robust = false;                        // the loss applies to it
};

// The factors of a chain of poses 0..size()-1.
class ChainFactorSource {
 public:
  virtual ~ChainFactorSource() = default;
  virtual size_t size() const = 0;
  // Appends the factors on pose i alone.
  virtual void unaryFactors(size_t i, std::vector<ChainFactor>* out) const = 0;
  // The factor between poses i-1 and i (parameter blocks in that order); nullptr when there is
  // none (i == 0, or the chain is cut there).
  virtual std::unique_ptr<ceres::CostFunction> binaryFactor(size_t i) const = 0;
};

struct ChainSolverOptions {
  int max_iterations = 100;           // steps tried (successful or not), as ceres::Solver counts
  double function_tolerance = 1e-10;  // stop when |cost change| <= this * cost
  double gradient_tolerance = 1e-12;  // stop when max |g| <= this
  double parameter_tolerance = 1e-10; // stop when |dx| <= this * (|x| + this)
  // Called after each iteration with (iteration, cost); may be empty.
  std::function<void(int, double)> progress;
};

struct ChainSolverSummary {
  bool usable = false;      // the factors could be evaluated at the start (x is the result)
  bool converged = false;   // a tolerance was reached (not the iteration limit)
  int iterations = 0;
  double initial_cost = 0;  // 1/2 sum rho(|r|^2) of the factors touching the range
  double final_cost = 0;
  std::string message;
};

// The factors touching poses [lo, hi): their unary factors, the binary factors inside, and the
// binary factors to the fixed neighbours lo-1 and hi when they exist.
class ChainProblem {
 public:
  ChainProblem(const ChainFactorSource& factors, const ceres::LossFunction* loss) : factors_(factors), loss_(loss) {}

  // Minimises over the poses [lo, hi) of x (3 doubles per pose of the whole chain), the other
  // poses held fixed. x keeps the best point found.
  ChainSolverSummary solve(size_t lo, size_t hi, std::vector<double>* x, const ChainSolverOptions& options) const;

  // 1/2 sum rho(|r|^2) of the factors touching [lo, hi) at x; false if one cannot be evaluated.
  bool cost(size_t lo, size_t hi, const std::vector<double>& x, double* cost) const;

  // The Gauss-Newton information at x restricted to [lo, hi): D[j] = H(lo+j, lo+j), B[j] =
  // H(lo+j-1, lo+j) (B[0] zero), g[j] the gradient; robust factors weighted by rho'(s) (no
  // second-order term). false if a factor cannot be evaluated.
  bool linearise(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                 std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, double* cost) const;

 private:
  const ChainFactorSource& factors_;
  const ceres::LossFunction* loss_;
};

// Solves the block tridiagonal system A dx = rhs with A(i,i) = D_i + damping diag(D_i) (the
// diagonal clamped to [1e-6, 1e32], as Ceres's Levenberg-Marquardt) and A(i-1,i) = B_i (B_0
// unused) by block forward elimination and back substitution in O(N); G is workspace. false
// when a pivot block is not positive definite.
bool solveBlockTridiagonal(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                           const std::vector<Eigen::Vector3d>& rhs, double damping, std::vector<Eigen::Matrix3d>* G,
                           std::vector<Eigen::Vector3d>* dx);

}  // namespace stereoloc
