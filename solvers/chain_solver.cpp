#include "solvers/chain_solver.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "solvers/smoother_common.h"
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

// The damped diagonal entry of a pivot, as Ceres's Levenberg-Marquardt.
double dampedDiagonal(double d, double damping) { return damping * std::clamp(d, kMinDiagonal, kMaxDiagonal); }

// Y = T^-1 R for the block tridiagonal T = (D, B), damped, and the 3 n x m right-hand sides R,
// by block forward elimination and back substitution (the multi-column form of
// solveBlockTridiagonal).
bool solveTridiagonalColumns(const std::vector<Eigen::Matrix3d>& D, const std::vector<Eigen::Matrix3d>& B,
                             const Eigen::MatrixXd& R, double damping, Eigen::MatrixXd* Y) {
  const size_t n = D.size();
  const Eigen::Index m = R.cols();
  Y->resize(3 * static_cast<Eigen::Index>(n), m);
  std::vector<Eigen::Matrix3d> G(n);
  Eigen::LLT<Eigen::Matrix3d> llt;
  Eigen::MatrixXd r(3, m);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Index row = 3 * static_cast<Eigen::Index>(i);
    Eigen::Matrix3d lambda = D[i];
    if (damping > 0)
      for (int k = 0; k < 3; ++k) lambda(k, k) += dampedDiagonal(D[i](k, k), damping);
    r = R.middleRows(row, 3);
    if (i > 0) {
      lambda.noalias() -= B[i].transpose() * G[i - 1];
      r.noalias() -= B[i].transpose() * Y->middleRows(row - 3, 3);
    }
    llt.compute(0.5 * (lambda + lambda.transpose()));
    if (llt.info() != Eigen::Success) return false;
    Y->middleRows(row, 3) = llt.solve(r);
    G[i] = i + 1 < n ? Eigen::Matrix3d(llt.solve(B[i + 1])) : Eigen::Matrix3d::Zero();
    if (!G[i].allFinite()) return false;
  }
  for (size_t i = n - 1; n > 0 && i-- > 0;) {
    const Eigen::Index row = 3 * static_cast<Eigen::Index>(i);
    Y->middleRows(row, 3).noalias() -= G[i] * Y->middleRows(row + 3, 3);
  }
  return Y->allFinite();
}

}  // namespace

ChainProblem::ChainProblem(const ChainFactorSource& factors, const ceres::LossFunction* loss,
                           std::vector<double>* globals)
    : factors_(factors), loss_(loss), globals_(globals), global_sizes_(factors.globalBlockSizes()) {
  for (int size : global_sizes_) {
    global_offsets_.push_back(global_size_);
    global_size_ += size;
  }
  if (global_size_ > 0 && (!globals_ || static_cast<int>(globals_->size()) != global_size_))
    throw std::invalid_argument("ChainProblem: the global blocks need their values");
}

// Visits every factor touching [lo, hi), then the global-only factors: f(factor, a, b) with
// b == SIZE_MAX for a unary factor on pose a, a == b == SIZE_MAX for a global-only factor,
// else a binary factor on poses a = b - 1 and b.
template <typename F>
bool ChainProblem::forEachFactor(size_t lo, size_t hi, F&& f) const {
  std::vector<ChainFactor> unary;
  const size_t n = factors_.size();
  for (size_t i = lo; i < hi; ++i) {
    unary.clear();
    factors_.unaryFactors(i, &unary);
    for (const ChainFactor& u : unary)
      if (!f(u, i, SIZE_MAX)) return false;
    if (i > 0) {
      const ChainFactor b = factors_.binaryFactor(i);
      if (b.cost && !f(b, i - 1, i)) return false;
    }
  }
  if (hi < n && hi > lo) {
    const ChainFactor b = factors_.binaryFactor(hi);
    if (b.cost && !f(b, hi - 1, hi)) return false;
  }
  if (global_size_ > 0) {
    unary.clear();
    factors_.globalFactors(&unary);
    for (const ChainFactor& u : unary)
      if (!f(u, SIZE_MAX, SIZE_MAX)) return false;
  }
  return true;
}

bool ChainProblem::cost(size_t lo, size_t hi, const std::vector<double>& x, double* total) const {
  double sum = 0;
  double r[8];
  const bool ok = forEachFactor(lo, hi, [&](const ChainFactor& factor, size_t a, size_t b) {
    const ceres::CostFunction& c = *factor.cost;
    const bool robust = factor.robust;
    const double* params[3] = {nullptr, nullptr, nullptr};
    int np = 0;
    if (a != SIZE_MAX) params[np++] = &x[3 * a];
    if (b != SIZE_MAX) params[np++] = &x[3 * b];
    if (factor.global >= 0) params[np++] = globals_->data() + global_offsets_[static_cast<size_t>(factor.global)];
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

// Where one factor's Gauss-Newton blocks go; null pointers for blocks outside the system.
struct Targets {
  Eigen::Matrix3d *Da = nullptr, *Db = nullptr, *Bab = nullptr;
  Eigen::Vector3d *ga = nullptr, *gb = nullptr;
  // The global block: its values, offset and size in the concatenated globals, and the bordered
  // parts (E rows of poses a and b, -1 outside), or E == nullptr when the globals are held.
  const double* pg = nullptr;
  int g_offset = 0, g_size = 0;
  Eigen::MatrixXd *E = nullptr, *C = nullptr;
  Eigen::VectorXd* gc = nullptr;
  Eigen::Index Ea_row = -1, Eb_row = -1;
};

// Adds one factor's weighted Gauss-Newton blocks, with fixed-size Jacobians for the factor
// sizes of the smoothers (M = 1..4 residuals): dynamic-size products cost several times more.
template <int M>
bool accumulate(const ceres::CostFunction& c, const ceres::LossFunction* loss, bool robust, const double* pa,
                const double* pb, const Targets& t, double* sum) {
  using Jac = Eigen::Matrix<double, M, 3, Eigen::RowMajor>;
  using JacG = Eigen::Matrix<double, M, Eigen::Dynamic, Eigen::RowMajor>;
  const int m = c.num_residuals();
  Jac Ja, Jb;
  Eigen::Matrix<double, M, 1> r;
  if constexpr (M == Eigen::Dynamic) {
    Ja.resize(m, 3);
    Jb.resize(m, 3);
    r.resize(m);
  }
  const bool global_jacobian = t.pg && t.E;
  JacG Jg;
  if (global_jacobian) Jg.resize(m, t.g_size);
  const double* params[3] = {nullptr, nullptr, nullptr};
  double* jac[3] = {nullptr, nullptr, nullptr};
  int np = 0;
  if (pa) {
    params[np] = pa;
    jac[np++] = Ja.data();
  }
  if (pb) {
    params[np] = pb;
    jac[np++] = Jb.data();
  }
  if (t.pg) {
    params[np] = t.pg;
    jac[np++] = global_jacobian ? Jg.data() : nullptr;
  }
  if (!c.Evaluate(params, r.data(), jac) || !r.allFinite() || (pa && !Ja.allFinite()) || (pb && !Jb.allFinite()) ||
      (global_jacobian && !Jg.allFinite()))
    return false;
  double w = 1.0;
  *sum += lossOf(loss, robust, r.squaredNorm(), &w);
  // IRLS weighting: the gradient rho' J^T r is exact; the information drops rho''.
  if (t.Da) {
    t.Da->noalias() += w * (Ja.transpose() * Ja);
    t.ga->noalias() += w * (Ja.transpose() * r);
  }
  if (t.Db) {
    t.Db->noalias() += w * (Jb.transpose() * Jb);
    t.gb->noalias() += w * (Jb.transpose() * r);
    if (t.Bab) t.Bab->noalias() += w * (Ja.transpose() * Jb);
  }
  if (global_jacobian) {
    t.C->block(t.g_offset, t.g_offset, t.g_size, t.g_size).noalias() += w * (Jg.transpose() * Jg);
    t.gc->segment(t.g_offset, t.g_size).noalias() += w * (Jg.transpose() * r);
    if (t.Ea_row >= 0) t.E->block(t.Ea_row, t.g_offset, 3, t.g_size).noalias() += w * (Ja.transpose() * Jg);
    if (t.Eb_row >= 0) t.E->block(t.Eb_row, t.g_offset, 3, t.g_size).noalias() += w * (Jb.transpose() * Jg);
  }
  return true;
}

}  // namespace

bool ChainProblem::linearise(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                             std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, double* total) const {
  return lineariseImpl(lo, hi, x, D, B, g, nullptr, nullptr, nullptr, total);
}

bool ChainProblem::linearise(size_t lo, size_t hi, const std::vector<double>& x, BorderedSystem* system,
                             double* total) const {
  return lineariseImpl(lo, hi, x, &system->D, &system->B, &system->g, &system->E, &system->C, &system->gc, total);
}

bool ChainProblem::lineariseImpl(size_t lo, size_t hi, const std::vector<double>& x, std::vector<Eigen::Matrix3d>* D,
                                 std::vector<Eigen::Matrix3d>* B, std::vector<Eigen::Vector3d>* g, Eigen::MatrixXd* E,
                                 Eigen::MatrixXd* C, Eigen::VectorXd* gc, double* total) const {
  const size_t len = hi - lo;
  D->assign(len, Eigen::Matrix3d::Zero());
  B->assign(len, Eigen::Matrix3d::Zero());
  g->assign(len, Eigen::Vector3d::Zero());
  if (E) {
    E->setZero(3 * static_cast<Eigen::Index>(len), global_size_);
    C->setZero(global_size_, global_size_);
    gc->setZero(global_size_);
  }
  double sum = 0;
  const bool ok = forEachFactor(lo, hi, [&](const ChainFactor& factor, size_t a, size_t b) {
    const ceres::CostFunction& c = *factor.cost;
    const bool has_a = a != SIZE_MAX;
    const bool binary = b != SIZE_MAX;
    const bool a_in = has_a && a >= lo && a < hi;
    const bool b_in = binary && b >= lo && b < hi;
    Targets t;
    t.Da = a_in ? &(*D)[a - lo] : nullptr;
    t.ga = a_in ? &(*g)[a - lo] : nullptr;
    t.Db = b_in ? &(*D)[b - lo] : nullptr;
    t.gb = b_in ? &(*g)[b - lo] : nullptr;
    t.Bab = a_in && b_in ? &(*B)[b - lo] : nullptr;
    if (factor.global >= 0) {
      const size_t k = static_cast<size_t>(factor.global);
      t.g_offset = global_offsets_[k];
      t.g_size = global_sizes_[k];
      t.pg = globals_->data() + t.g_offset;
      if (E) {
        t.E = E;
        t.C = C;
        t.gc = gc;
        t.Ea_row = a_in ? 3 * static_cast<Eigen::Index>(a - lo) : -1;
        t.Eb_row = b_in ? 3 * static_cast<Eigen::Index>(b - lo) : -1;
      }
    }
    const double* pa = has_a ? &x[3 * a] : nullptr;
    const double* pb = binary ? &x[3 * b] : nullptr;
    switch (c.num_residuals()) {
      case 1: return accumulate<1>(c, loss_, factor.robust, pa, pb, t, &sum);
      case 2: return accumulate<2>(c, loss_, factor.robust, pa, pb, t, &sum);
      case 3: return accumulate<3>(c, loss_, factor.robust, pa, pb, t, &sum);
      case 4: return accumulate<4>(c, loss_, factor.robust, pa, pb, t, &sum);
      default: return accumulate<Eigen::Dynamic>(c, loss_, factor.robust, pa, pb, t, &sum);
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

bool solveBorderedBlockTridiagonal(const BorderedSystem& h, const Eigen::VectorXd& rhs_x, const Eigen::VectorXd& rhs_c,
                                   double damping, Eigen::VectorXd* dx, Eigen::VectorXd* dc) {
  const Eigen::Index K = h.C.rows();
  const Eigen::Index rows = 3 * static_cast<Eigen::Index>(h.D.size());
  // W = T^-1 [rhs_x, E]: one elimination pass for the K + 1 columns.
  Eigen::MatrixXd R(rows, K + 1), W;
  R.col(0) = rhs_x;
  R.rightCols(K) = h.E;
  if (!solveTridiagonalColumns(h.D, h.B, R, damping, &W)) return false;
  Eigen::MatrixXd S = h.C;
  if (damping > 0)
    for (Eigen::Index k = 0; k < K; ++k) S(k, k) += dampedDiagonal(h.C(k, k), damping);
  S.noalias() -= h.E.transpose() * W.rightCols(K);
  const Eigen::VectorXd r = rhs_c - h.E.transpose() * W.col(0);
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (S + S.transpose()));
  if (llt.info() != Eigen::Success) return false;
  *dc = llt.solve(r);
  *dx = W.col(0) - W.rightCols(K) * *dc;
  return dx->allFinite() && dc->allFinite();
}

bool borderedMarginalCovariances(const BorderedSystem& h, std::vector<Eigen::Matrix3d>* pose_covariances,
                                 Eigen::MatrixXd* global_covariance) {
  // H^-1 = [T^-1 + W S^-1 W^T, -W S^-1; -S^-1 W^T, S^-1] with W = T^-1 E, S = C - E^T W.
  if (!chainMarginalCovariances(h.D, h.B, pose_covariances)) return false;
  const Eigen::Index K = h.C.rows();
  if (K == 0) {
    global_covariance->resize(0, 0);
    return true;
  }
  Eigen::MatrixXd W;
  if (!solveTridiagonalColumns(h.D, h.B, h.E, 0.0, &W)) return false;
  Eigen::MatrixXd S = h.C;
  S.noalias() -= h.E.transpose() * W;
  S = 0.5 * (S + S.transpose());
  const Eigen::LLT<Eigen::MatrixXd> llt(S);
  const double scale = std::max(h.C.cwiseAbs().maxCoeff(), std::numeric_limits<double>::min());
  if (llt.info() != Eigen::Success) return false;
  Eigen::MatrixXd Sinv = llt.solve(Eigen::MatrixXd::Identity(K, K));
  Sinv = 0.5 * (Sinv + Sinv.transpose());
  if (!Sinv.allFinite() || !(1.0 / Sinv.norm() > 1e-14 * scale)) return false;
  for (size_t i = 0; i < pose_covariances->size(); ++i) {
    const auto Wi = W.middleRows(3 * static_cast<Eigen::Index>(i), 3);
    const Eigen::Matrix3d add = Wi * Sinv * Wi.transpose();
    (*pose_covariances)[i] += 0.5 * (add + add.transpose());
  }
  *global_covariance = Sinv;
  return true;
}

namespace {

// The largest absolute entry of the system's gradient (the global blocks' too with `globals`).
double gradientMax(const BorderedSystem& h, bool globals) {
  double gmax = 0;
  for (const Eigen::Vector3d& gi : h.g) gmax = std::max(gmax, gi.cwiseAbs().maxCoeff());
  if (globals) gmax = std::max(gmax, h.gc.cwiseAbs().maxCoeff());
  return gmax;
}

// The Levenberg-Marquardt step at `damping`: the poses' dx (len of them) and, with `globals`, the
// global blocks' dc (dxv: the poses' step stacked). False when the damped system is singular.
bool dampedStep(BorderedSystem& h, size_t len, bool globals, double damping, std::vector<Eigen::Matrix3d>* G,
                std::vector<Eigen::Vector3d>* dx, Eigen::VectorXd* rhs_x, Eigen::VectorXd* dxv, Eigen::VectorXd* dc) {
  if (globals) {
    rhs_x->resize(3 * static_cast<Eigen::Index>(len));
    for (size_t j = 0; j < len; ++j) rhs_x->segment<3>(3 * static_cast<Eigen::Index>(j)) = -h.g[j];
    const bool ok = solveBorderedBlockTridiagonal(h, *rhs_x, -h.gc, damping, dxv, dc);
    if (ok) {
      dx->resize(len);
      for (size_t j = 0; j < len; ++j) (*dx)[j] = dxv->segment<3>(3 * static_cast<Eigen::Index>(j));
    }
    return ok;
  }
  for (Eigen::Vector3d& gi : h.g) gi = -gi;  // the right-hand side, restored below
  const bool ok = solveBlockTridiagonal(h.D, h.B, h.g, damping, G, dx);
  for (Eigen::Vector3d& gi : h.g) gi = -gi;
  return ok;
}

// The decrease of the undamped quadratic model, -(g^T dx + 1/2 dx^T H dx), and the squared norms
// of the step and of the point it starts from (`saved`: the poses' values, `saved_globals` the
// global blocks').
double modelDecrease(const BorderedSystem& h, size_t len, bool globals, const std::vector<Eigen::Vector3d>& dx,
                     const Eigen::VectorXd& dxv, const Eigen::VectorXd& dc, const std::vector<double>& saved,
                     const std::vector<double>& saved_globals, double* dx_norm2, double* x_norm2) {
  double quad = 0, lin = 0;
  for (size_t j = 0; j < len; ++j) {
    lin += h.g[j].dot(dx[j]);
    quad += dx[j].dot(h.D[j] * dx[j]);
    if (j > 0) quad += 2.0 * dx[j - 1].dot(h.B[j] * dx[j]);
    *dx_norm2 += dx[j].squaredNorm();
    for (int k = 0; k < 3; ++k) *x_norm2 += saved[3 * j + k] * saved[3 * j + k];
  }
  if (globals) {
    lin += h.gc.dot(dc);
    quad += 2.0 * dxv.dot(h.E * dc) + dc.dot(h.C * dc);
    *dx_norm2 += dc.squaredNorm();
    for (double v : saved_globals) *x_norm2 += v * v;
  }
  return -(lin + 0.5 * quad);
}

}  // namespace

ChainSolverSummary ChainProblem::solve(size_t lo, size_t hi, std::vector<double>* xp,
                                       const ChainSolverOptions& options) const {
  ChainSolverSummary s;
  std::vector<double>& x = *xp;
  const size_t len = hi - lo;
  const bool globals = options.solve_globals && global_size_ > 0;
  const Eigen::Index K = globals ? global_size_ : 0;
  BorderedSystem h;
  std::vector<Eigen::Matrix3d> G;
  std::vector<Eigen::Vector3d> dx;
  Eigen::VectorXd rhs_x, dxv, dc;
  double cost = 0;
  if (len == 0 && !globals) {
    s.usable = s.converged = this->cost(lo, hi, x, &cost);
    s.initial_cost = s.final_cost = cost;
    s.message = "no free poses";
    return s;
  }
  auto relinearise = [&] {
    return globals ? linearise(lo, hi, x, &h, &cost) : linearise(lo, hi, x, &h.D, &h.B, &h.g, &cost);
  };
  if (!relinearise()) {
    s.message = "a factor cannot be evaluated at the initial guess";
    return s;
  }
  s.usable = true;
  s.initial_cost = s.final_cost = cost;
  double damping = kInitialDamping, factor = 2.0;
  // The range's current values, while x holds a trial step (the fixed neighbours stay in x).
  std::vector<double> saved(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi));
  const std::vector<double> no_globals;
  std::vector<double> saved_globals = globals ? *globals_ : no_globals;
  while (true) {
    if (gradientMax(h, globals) <= options.gradient_tolerance) {
      s.converged = true;
      s.message = "gradient tolerance reached";
      break;
    }
    if (s.iterations >= options.max_iterations) {
      s.message = "maximum number of iterations reached";
      break;
    }
    ++s.iterations;
    bool step_ok = dampedStep(h, len, globals, damping, &G, &dx, &rhs_x, &dxv, &dc);
    double model_decrease = 0, dx_norm2 = 0, x_norm2 = 0;
    if (step_ok) {
      model_decrease = modelDecrease(h, len, globals, dx, dxv, dc, saved, saved_globals, &dx_norm2, &x_norm2);
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
      if (globals)
        for (Eigen::Index k = 0; k < K; ++k) (*globals_)[static_cast<size_t>(k)] = saved_globals[static_cast<size_t>(k)] + dc(k);
      step_ok = this->cost(lo, hi, x, &new_cost) && std::isfinite(new_cost);
    }
    const double rho = step_ok ? (cost - new_cost) / model_decrease : -1.0;
    if (step_ok && rho > kMinRelativeDecrease) {
      const double change = cost - new_cost;
      std::copy(x.begin() + static_cast<long>(3 * lo), x.begin() + static_cast<long>(3 * hi), saved.begin());
      if (globals) saved_globals = *globals_;
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
      if (!relinearise()) {
        s.message = "a factor cannot be evaluated";
        break;
      }
    } else {
      std::copy(saved.begin(), saved.end(), x.begin() + static_cast<long>(3 * lo));
      if (globals) *globals_ = saved_globals;
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
