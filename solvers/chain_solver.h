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
// a million-step problem does not hold millions of them.
//
// A few global parameter blocks (self-calibration: wheel scales, stereo corrections) may join
// the chain: factors then also touch one global block, and the information becomes bordered
// (an arrow): H = [T E; E^T C], T block tridiagonal over the poses, E dense 3N x K, C K x K.
// Each iteration eliminates the poses' tridiagonal part for the K + 1 right-hand sides
// [g_x, E] in one O(N K^2) pass, solves the Schur complement S = C - E^T T^-1 E for the global
// step, and back-substitutes (solveBorderedBlockTridiagonal); docs/estimators.md has the
// derivation. Poses are (x, y, theta) in mm, mm, rad
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
  // Parameter blocks: the pose (unary) or the two poses (binary) of 3, then the global block
  // `global` when it is >= 0. A global-only factor (ChainFactorSource::globalFactors) has the
  // global block alone.
  std::unique_ptr<ceres::CostFunction> cost;
  bool robust = false;                        // the loss applies to it
  int global = -1;                            // index into ChainFactorSource::globalBlockSizes(), -1: none
};

// The factors of a chain of poses 0..size()-1.
class ChainFactorSource {
 public:
  virtual ~ChainFactorSource() = default;
  virtual size_t size() const = 0;
  // Appends the factors on pose i alone.
  virtual void unaryFactors(size_t i, std::vector<ChainFactor>* out) const = 0;
  // The factor between poses i-1 and i (parameter blocks in that order); cost nullptr when
  // there is none (i == 0, or the chain is cut there).
  virtual ChainFactor binaryFactor(size_t i) const = 0;
  // Sizes of the global parameter blocks; none by default. Their values are held by the caller
  // of ChainProblem, concatenated in this order.
  virtual std::vector<int> globalBlockSizes() const { return {}; }
  // Appends the factors on a global block alone (its prior).
  virtual void globalFactors(std::vector<ChainFactor>* /*out*/) const {}
};

struct ChainSolverOptions {
  int max_iterations = 100;           // steps tried (successful or not), as ceres::Solver counts
  double function_tolerance = 1e-10;  // stop when |cost change| <= this * cost
  double gradient_tolerance = 1e-12;  // stop when max |g| <= this
  double parameter_tolerance = 1e-10; // stop when |dx| <= this * (|x| + this)
  bool solve_globals = true;          // also estimate the global blocks (else held at their values)
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
// The Gauss-Newton system of a chain with global blocks (ChainProblem::linearise): the pose
// blocks as for a plain chain, E the 3 len x K coupling of the poses with the globals (K the sum
// of the global block sizes), C and gc the globals' information and gradient.
struct BorderedSystem {
  std::vector<Eigen::Matrix3d> D, B;
  std::vector<Eigen::Vector3d> g;
  Eigen::MatrixXd E, C;
  Eigen::VectorXd gc;
};

class ChainProblem {
 public:
  // globals: the values of the source's global blocks, concatenated (read by every evaluation,
  // written by solve()); may be null when the source has none. Must outlive the problem.
  ChainProblem(const ChainFactorSource& factors, const ceres::LossFunction* loss, std::vector<double>* globals = nullptr);

  // Minimises over the poses [lo, hi) of x (3 doubles per pose of the whole chain), the other
  // poses held fixed, and over the global blocks with options.solve_globals. x (and the
  // globals) keep the best point found.
  ChainSolverSummary solve(size_t lo, size_t hi, std::vector<double>* x, const ChainSolverOptions& options) const;

  // 1/2 sum rho(|r|^2) of the factors touching [lo, hi) at x (and of the global-only factors);
  // false if one cannot be evaluated.
  bool cost(size_t lo, size_t hi, const std::vector<double>& x, double* cost) const;

  // The bordered system at x over the poses [lo, hi) and every global block.
  bool linearise(size_t lo, size_t hi, const std::vector<double>& x, BorderedSystem* system, double* cost) const;

  // The sum of the global block sizes (K).
  int globalSize() const { return global_size_; }

  // The Gauss-Newton information at x restricted to [lo, hi): D[j] = H(lo+j, lo+j), B[j] =
  // H(lo+j-1, lo+j) (B[0] zero), g[j] the gradient; robust factors weighted by rho'(s) (no
  // second-order term). false if a factor cannot be evaluated.
  bool linearise(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                 std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, double* cost) const;

 private:
  bool lineariseImpl(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                     std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, Eigen::MatrixXd* E,
                     Eigen::MatrixXd* C, Eigen::VectorXd* gc, double* cost) const;
  template <typename F>
  bool forEachFactor(size_t lo, size_t hi, F&& f) const;

  const ChainFactorSource& factors_;
  const ceres::LossFunction* loss_;
  std::vector<double>* globals_;
  std::vector<int> global_offsets_;  // of each global block in *globals_
  std::vector<int> global_sizes_;
  int global_size_ = 0;
};

// Solves the block tridiagonal system A dx = rhs with A(i,i) = D_i + damping diag(D_i) (the
// diagonal clamped to [1e-6, 1e32], as Ceres's Levenberg-Marquardt) and A(i-1,i) = B_i (B_0
// unused) by block forward elimination and back substitution in O(N); G is workspace. false
// when a pivot block is not positive definite.
bool solveBlockTridiagonal(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                           const std::vector<Eigen::Vector3d>& rhs, double damping, std::vector<Eigen::Matrix3d>* G,
                           std::vector<Eigen::Vector3d>* dx);

// Solves the bordered system [T E; E^T C] (dx, dc) = (rhs_x, rhs_c), T the block tridiagonal
// (D, B) and both T and C damped as in solveBlockTridiagonal: W = T^-1 [rhs_x, E] in one pass
// (O(N K^2)), dc from the Schur complement S = C - E^T T^-1 E, dx = T^-1 rhs_x - T^-1 E dc.
// dx: 3 len values. false when a pivot or S is not positive definite.
bool solveBorderedBlockTridiagonal(const BorderedSystem& system, const Eigen::VectorXd& rhs_x,
                                   const Eigen::VectorXd& rhs_c, double damping, Eigen::VectorXd* dx,
                                   Eigen::VectorXd* dc);

// Marginal covariances of the undamped bordered system: per pose the diagonal 3x3 block of
// H^-1 ([T^-1]_ii + (T^-1 E)_i S^-1 (T^-1 E)_i^T) and the globals' S^-1, in O(N K^2). false
// (rank deficient) as chainMarginalCovariances (solvers/smoother_common.h), or when S is not
// positive definite.
bool borderedMarginalCovariances(const BorderedSystem& system, std::vector<Eigen::Matrix3d>* pose_covariances,
                                 Eigen::MatrixXd* global_covariance);

}  // namespace stereoloc
