#include "solvers/chain_solver.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>

#include "src/core/angles.h"

namespace stereoloc {
namespace {

// As ceres::Solver's LEVENBERG_MARQUARDT: diagonal of J^T J clamped to [1e-6, 1e32], a step
// accepted when it achieves 1e-3 of the predicted decrease, damping times max(1/3, 1 - (2 rho -
// 1)^3) after a success and times 2, 4, 8, ... after failures. The initial damping differs:
// Ceres's 1e-4 (radius 1e4) is far above the smallest eigenvalues of a long chain's
// information relative to its diagonal (the slow, rigid modes of long stretches), so those
// converge linearly, ~0.2 per iteration; from the filter's guess the Gauss-Newton step is
// already good, and 1e-8 halves the iterations (100,000 random-walk steps: 12 -> 6) while a
// failed step still raises the damping.
constexpr double kInitialDamping = 1e-8;
constexpr double kMinDiagonal = 1e-6;
constexpr double kMaxDiagonal = 1e32;
constexpr double kMinRelativeDecrease = 1e-3;
constexpr double kMaxDamping = 1e32;

// Visits every factor touching [lo, hi): f(cost, robust, a, b) with b == SIZE_MAX for a unary
// factor on pose a, else a binary factor on poses a = b - 1 and b.
template <typename F>
bool forEachFactor(const ChainFactorSource& source, size_t lo, size_t hi, F&& f) {
  std::vector<ChainFactor> unary;
  const size_t n = source.size();
  for (size_t i = lo; i < hi; ++i) {
    unary.clear();
    source.unaryFactors(i, &unary);
    for (const ChainFactor& u : unary)
      if (!f(*u.cost, u.robust, i, SIZE_MAX)) return false;
    if (i > 0) {
      const std::unique_ptr<ceres::CostFunction> b = source.binaryFactor(i);
      if (b && !f(*b, false, i - 1, i)) return false;
    }
  }
  if (hi < n && hi > lo) {
    const std::unique_ptr<ceres::CostFunction> b = source.binaryFactor(hi);
    if (b && !f(*b, false, hi - 1, hi)) return false;
  }
  return true;
}

double lossOf(const ceres::LossFunction* loss, bool robust, double s, double* weight) {
  if (!robust || !loss) {
    if (weight) *weight = 1.0;
    return s;
  }
  double rho[3];
  loss->Evaluate(s, rho);
  if (weight) *weight = std::max(rho[1], 0.0);
  return rho[0];
}

}  // namespace

bool ChainProblem::cost(size_t lo, size_t hi, const std::vector<double>& x, double* total) const {
  double sum = 0;
  double r[8];
  const bool ok = forEachFactor(factors_, lo, hi, [&](const ceres::CostFunction& c, bool robust, size_t a, size_t b) {
    const double* params[2] = {&x[3 * a], b == SIZE_MAX ? nullptr : &x[3 * b]};
    const int m = c.num_residuals();
    Eigen::VectorXd big;
    double* res = r;
    if (m > 8) {
      big.resize(m);
      res = big.data();
    }
    if (!c.Evaluate(params, res, nullptr)) return false;
    double s = 0;
    for (int k = 0; k < m; ++k) s += res[k] * res[k];
    if (!std::isfinite(s)) return false;
    sum += lossOf(loss_, robust, s, nullptr);
    return true;
  });
  *total = 0.5 * sum;
  return ok;
}

namespace {

// Adds one factor's weighted Gauss-Newton blocks, with fixed-size Jacobians for the factor
// sizes of the smoothers (M = 1..4 residuals): dynamic-size products cost several times more.
template <int M>
bool accumulate(const ceres::CostFunction& c, const ceres::LossFunction* loss, bool robust, const double* pa,
                const double* pb, Eigen::Matrix3d* Da, Eigen::Vector3d* ga, Eigen::Matrix3d* Db, Eigen::Vector3d* gb,
                Eigen::Matrix3d* Bab, double* sum) {
  using Jac = Eigen::Matrix<double, M, 3, Eigen::RowMajor>;
  Jac Ja, Jb;
  Eigen::Matrix<double, M, 1> r;
  if constexpr (M == Eigen::Dynamic) {
    Ja.resize(c.num_residuals(), 3);
    Jb.resize(c.num_residuals(), 3);
    r.resize(c.num_residuals());
  }
  const double* params[2] = {pa, pb};
  double* jac[2] = {Ja.data(), pb ? Jb.data() : nullptr};
  if (!c.Evaluate(params, r.data(), jac) || !r.allFinite() || !Ja.allFinite() || (pb && !Jb.allFinite())) return false;
  double w = 1.0;
  *sum += lossOf(loss, robust, r.squaredNorm(), &w);
  // IRLS weighting: the gradient rho' J^T r is exact; the information drops rho''.
  if (Da) {
    Da->noalias() += w * (Ja.transpose() * Ja);
    ga->noalias() += w * (Ja.transpose() * r);
  }
  if (Db) {
    Db->noalias() += w * (Jb.transpose() * Jb);
    gb->noalias() += w * (Jb.transpose() * r);
    if (Bab) Bab->noalias() += w * (Ja.transpose() * Jb);
  }
  return true;
}

}  // namespace

bool ChainProblem::linearise(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                             std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, double* total) const {
  const size_t len = hi - lo;
  D->assign(len, Eigen::Matrix3d::Zero());
  B->assign(len, Eigen::Matrix3d::Zero());
  g->assign(len, Eigen::Vector3d::Zero());
  double sum = 0;
  const bool ok = forEachFactor(factors_, lo, hi, [&](const ceres::CostFunction& c, bool robust, size_t a, size_t b) {
    const bool binary = b != SIZE_MAX;
    const bool a_in = a >= lo && a < hi;
    const bool b_in = binary && b >= lo && b < hi;
    Eigen::Matrix3d* Da = a_in ? &(*D)[a - lo] : nullptr;
    Eigen::Vector3d* ga = a_in ? &(*g)[a - lo] : nullptr;
    Eigen::Matrix3d* Db = b_in ? &(*D)[b - lo] : nullptr;
    Eigen::Vector3d* gb = b_in ? &(*g)[b - lo] : nullptr;
    Eigen::Matrix3d* Bab = a_in && b_in ? &(*B)[b - lo] : nullptr;
    const double* pa = &x[3 * a];
    const double* pb = binary ? &x[3 * b] : nullptr;
    switch (c.num_residuals()) {
      case 1: return accumulate<1>(c, loss_, robust, pa, pb, Da, ga, Db, gb, Bab, &sum);
      case 2: return accumulate<2>(c, loss_, robust, pa, pb, Da, ga, Db, gb, Bab, &sum);
      case 3: return accumulate<3>(c, loss_, robust, pa, pb, Da, ga, Db, gb, Bab, &sum);
      case 4: return accumulate<4>(c, loss_, robust, pa, pb, Da, ga, Db, gb, Bab, &sum);
      default: return accumulate<Eigen::Dynamic>(c, loss_, robust, pa, pb, Da, ga, Db, gb, Bab, &sum);
    }
  });
  *total = 0.5 * sum;
  return ok;
}

bool solveBlockTridiagonal(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                           const std::vector<Eigen::Vector3d>& rhs, double damping, std::vector<Eigen::Matrix3d>* G,
                           std::vector<Eigen::Vector3d>* dx) {
  // A_i = D_i + damping diag(D_i) (clamped). Eliminating dx_{i-1} = c_{i-1} - G_{i-1} dx_i from row i leaves the pivot
  // Lambda_i = A_i - B_i^T G_{i-1} with G_{i-1} = Lambda_{i-1}^-1 B_i and right-hand side
  // rhs_i - B_i^T c_{i-1}; c_i = Lambda_i^-1 (that right-hand side). Back substitution:
  // dx_{N-1} = c_{N-1}, dx_i = c_i - G_i dx_{i+1}.
  const size_t n = D.size();
  G->resize(n);
  dx->resize(n);
  Eigen::LLT<Eigen::Matrix3d> llt;
  for (size_t i = 0; i < n; ++i) {
    Eigen::Matrix3d lambda = D[i];
    if (damping > 0)
      for (int k = 0; k < 3; ++k) lambda(k, k) += damping * std::clamp(D[i](k, k), kMinDiagonal, kMaxDiagonal);
    Eigen::Vector3d r = rhs[i];
    if (i > 0) {
      lambda.noalias() -= B[i].transpose() * (*G)[i - 1];
      r.noalias() -= B[i].transpose() * (*dx)[i - 1];
    }
    llt.compute(0.5 * (lambda + lambda.transpose()));
    if (llt.info() != Eigen::Success) return false;
    (*dx)[i] = llt.solve(r);
    (*G)[i] = i + 1 < n ? Eigen::Matrix3d(llt.solve(B[i + 1])) : Eigen::Matrix3d::Zero();
    if (!(*dx)[i].allFinite() || !(*G)[i].allFinite()) return false;
  }
  for (size_t i = n - 1; i-- > 0;) (*dx)[i] -= (*G)[i] * (*dx)[i + 1];
  return true;
}

ChainSolverSummary ChainProblem::solve(size_t lo, size_t hi, std::vector<double>* xp,
                                       const ChainSolverOptions& options) const {
  ChainSolverSummary s;
  std::vector<double>& x = *xp;
  const size_t len = hi - lo;
  std::vector<Eigen::Matrix3d> D, B, G;
  std::vector<Eigen::Vector3d> g, dx;
  double cost = 0;
  if (len == 0) {
    s.usable = s.converged = this->cost(lo, hi, x, &cost);
    s.initial_cost = s.final_cost = cost;
    s.message = "no free poses";
    return s;
  }
  if (!linearise(lo, hi, x, &D, &B, &g, &cost)) {
    s.message = "a factor cannot be evaluated at the initial guess";
    return s;
  }
  s.usable = true;
  s.initial_cost = s.final_cost = cost;
  double damping = kInitialDamping, factor = 2.0;
  // The range's current values, while x holds a trial step (the fixed neighbours stay in x).
  std::vector<double> saved(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
  while (true) {
    double gmax = 0;
    for (const Eigen::Vector3d& gi : g) gmax = std::max(gmax, gi.cwiseAbs().maxCoeff());
    if (gmax <= options.gradient_tolerance) {
      s.converged = true;
      s.message = "gradient tolerance reached";
      break;
    }
    if (s.iterations >= options.max_iterations) {
      s.message = "maximum number of iterations reached";
      break;
    }
    ++s.iterations;
    for (Eigen::Vector3d& gi : g) gi = -gi;  // the right-hand side, restored below
    bool step_ok = solveBlockTridiagonal(D, B, g, damping, &G, &dx);
    for (Eigen::Vector3d& gi : g) gi = -gi;
    double model_decrease = 0, dx_norm2 = 0, x_norm2 = 0;
    if (step_ok) {
      // Decrease of the undamped quadratic model: -(g^T dx + 1/2 dx^T H dx).
      double quad = 0, lin = 0;
      for (size_t j = 0; j < len; ++j) {
        lin += g[j].dot(dx[j]);
        quad += dx[j].dot(D[j] * dx[j]);
        if (j > 0) quad += 2.0 * dx[j - 1].dot(B[j] * dx[j]);
        dx_norm2 += dx[j].squaredNorm();
        for (int k = 0; k < 3; ++k) x_norm2 += saved[3 * j + k] * saved[3 * j + k];
      }
      model_decrease = -(lin + 0.5 * quad);
      if (std::sqrt(dx_norm2) <= options.parameter_tolerance * (std::sqrt(x_norm2) + options.parameter_tolerance)) {
        s.converged = true;
        s.message = "parameter tolerance reached";
        break;
      }
      step_ok = model_decrease > 0 && std::isfinite(model_decrease);
    }
    double new_cost = 0;
    if (step_ok) {
      for (size_t j = 0; j < len; ++j) {
        const size_t i = 3 * (lo + j);
        x[i] = saved[3 * j] + dx[j].x();
        x[i + 1] = saved[3 * j + 1] + dx[j].y();
        x[i + 2] = wrapAngle(saved[3 * j + 2] + dx[j].z());  // Plus of factors/pose_manifold.h
      }
      step_ok = this->cost(lo, hi, x, &new_cost) && std::isfinite(new_cost);
    }
    const double rho = step_ok ? (cost - new_cost) / model_decrease : -1.0;
    if (step_ok && rho > kMinRelativeDecrease) {
      const double change = cost - new_cost;
      std::copy(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi), saved.begin());
      cost = new_cost;
      s.final_cost = cost;
      damping *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
      factor = 2.0;
      if (options.progress) options.progress(s.iterations, cost);
      if (std::fabs(change) <= options.function_tolerance * (cost + change)) {
        s.converged = true;
        s.message = "function tolerance reached";
        break;
      }
      if (!linearise(lo, hi, x, &D, &B, &g, &cost)) {
        s.message = "a factor cannot be evaluated";
        break;
      }
    } else {
      std::copy(saved.begin(), saved.end(), x.begin() + static_cast<long>(3 * lo));
      damping *= factor;
      factor *= 2.0;
      if (options.progress) options.progress(s.iterations, cost);
      if (damping > kMaxDamping) {
        s.converged = true;  // no step can decrease the cost any more: a minimum to machine precision
        s.message = "no further decrease possible";
        break;
      }
    }
  }
  return s;
}

}  // namespace stereoloc
