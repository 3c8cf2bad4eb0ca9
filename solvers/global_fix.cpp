#include "solvers/global_fix.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>

#include "src/core/error.h"
#include "src/core/measurement_model.h"

namespace stereoloc {

std::string toString(FixStatus status) {
  switch (status) {
    case FixStatus::Ok: return "ok";
    case FixStatus::ApproximateNoIntersection: return "approximate";
    case FixStatus::NotEnoughLandmarks: return "not_enough_landmarks";
    case FixStatus::Degenerate: return "degenerate";
    case FixStatus::Ambiguous: return "ambiguous";
  }
  return "degenerate";
}

FixStatus fixStatusFromString(const std::string& name) {
  for (FixStatus s : {FixStatus::Ok, FixStatus::ApproximateNoIntersection, FixStatus::NotEnoughLandmarks,
                      FixStatus::Degenerate, FixStatus::Ambiguous})
    if (toString(s) == name) return s;
  throw Error("unknown fix status '" + name + "' (expected ok, approximate, not_enough_landmarks, degenerate or ambiguous)");
}

std::string toString(FixMethod method) {
  switch (method) {
    case FixMethod::OneLandmarkCompass: return "fix1";
    case FixMethod::TwoLandmarks: return "fix2";
    case FixMethod::RunningFix: return "running";
    case FixMethod::MultiLandmark: return "multi";
  }
  return "fix2";
}

FixMethod fixMethodFromString(const std::string& name) {
  for (FixMethod m : {FixMethod::OneLandmarkCompass, FixMethod::TwoLandmarks, FixMethod::RunningFix,
                      FixMethod::MultiLandmark})
    if (toString(m) == name) return m;
  throw Error("unknown fix method '" + name + "' (expected fix1, fix2, running or multi)");
}

std::string toString(FixCovariance model) {
  switch (model) {
    case FixCovariance::FirstOrder: return "first_order";
    case FixCovariance::SecondOrder: return "second_order";
    case FixCovariance::SigmaPoints: return "sigma_points";
  }
  return "sigma_points";
}

FixCovariance fixCovarianceFromString(const std::string& name) {
  for (FixCovariance m : {FixCovariance::FirstOrder, FixCovariance::SecondOrder, FixCovariance::SigmaPoints})
    if (toString(m) == name) return m;
  throw Error("unknown fix covariance '" + name + "' (expected first_order, second_order or sigma_points)");
}

namespace {

void checkObservation(const Observation& o, const char* what) {
  if (!(std::isfinite(o.range) && std::isfinite(o.bearing) && o.covariance.allFinite()))
    throw Error(std::string(what) + ": observation of landmark " + std::to_string(o.landmark_id) +
                " has a non-finite range, bearing or covariance");
}

Eigen::Matrix3d symmetrize(const Eigen::Matrix3d& m) { return 0.5 * (m + m.transpose()); }

bool positiveDefinite(const Eigen::Matrix3d& m) {
  if (!m.allFinite()) return false;
  Eigen::LLT<Eigen::Matrix3d> llt(m);
  return llt.info() == Eigen::Success;
}

// d atan2(q_y, q_x) / d q for q = c - p (so d/dp is its negative).
Eigen::RowVector2d atan2Gradient(const Eigen::Vector2d& q) {
  const double rho2 = q.squaredNorm();
  return Eigen::RowVector2d(-q.y() / rho2, q.x() / rho2);
}

// ---- Sigma points (FixCovariance::SigmaPoints).
//
// We want P = E[(f(y_hat - n) - f(y_hat))(...)^T], n ~ N(0, C): the spread of the closed form f
// about the estimate over the measurement noise, i.e. the mean squared error of the estimate when
// the truth is y_hat - n. With y - y_hat = S u, C = S S^T, u ~ N(0, I_m), the symmetric rule
//   u = +-sqrt(3) e_k               weight (4 - m) / 18   (2m points)
//   u = +-sqrt(3) e_k +- sqrt(3) e_l  weight 1 / 36        (2m(m-1) points, k < l)
// (plus the centre, which contributes nothing about f(y_hat)) reproduces the Gaussian moments
// E[u_k^2] = 1, E[u_k^4] = 3, E[u_k^2 u_l^2] = 1 and all odd ones (0): it integrates every
// polynomial of degree <= 5 exactly. (f - f_hat)(f - f_hat)^T of a quadratic f has degree 4, so P
// is exact for quadratic f, cross-curvatures and squared bias included. For m <= 4 the weights
// are non-negative (m = 4: the axis points drop out; fix2 has m = 4, fix1 m = 3); for m > 4
// (the running fix with odometry noise) the axis weight is negative and P may come out
// indefinite, which the caller detects.
struct SigmaPointMse {
  bool ok = false;
  Eigen::Matrix3d mse = Eigen::Matrix3d::Zero();
  Eigen::Vector3d bias = Eigen::Vector3d::Zero();  // E[f(y + n)] - f(y) to second order
};

// S (n x m) with S S^T = cov, dropping null directions (landmark positions, exact inputs);
// returns m. Pivoted LDL^T: cov = P^T L D L^T P.
template <int N>
int covarianceSquareRoot(const Eigen::Matrix<double, N, N>& cov, Eigen::Matrix<double, N, N>* S) {
  const Eigen::LDLT<Eigen::Matrix<double, N, N>> ldlt(cov);
  const Eigen::Matrix<double, N, 1> D = ldlt.vectorD();
  const double dmax = D.maxCoeff();
  if (!(dmax > 0.0)) return 0;
  Eigen::Matrix<double, N, N> L = ldlt.matrixL();
  L = ldlt.transpositionsP().transpose() * L;
  int m = 0;
  for (int k = 0; k < N; ++k)
    if (D(k) > 1e-14 * dmax) S->col(m++) = L.col(k) * std::sqrt(D(k));
  return m;
}

// f(y, &pose) returns false outside its domain (the rule is then unusable).
template <int N, typename F>
SigmaPointMse sigmaPointMse(const Eigen::Matrix<double, N, 1>& y0, const Eigen::Matrix<double, N, N>& cov,
                            const Pose2& f0, const F& f) {
  SigmaPointMse res;
  Eigen::Matrix<double, N, N> S;
  const int m = covarianceSquareRoot<N>(cov, &S);
  if (m == 0) return res;
  const double s3 = std::sqrt(3.0);
  bool inside = true;
  auto add = [&](const Eigen::Matrix<double, N, 1>& dy, double w) {
    Pose2 g;
    if (!inside || !f(Eigen::Matrix<double, N, 1>(y0 + dy), &g)) {
      inside = false;
      return;
    }
    const Eigen::Vector3d d(g.x - f0.x, g.y - f0.y, angleDiff(g.theta, f0.theta));
    res.mse += w * d * d.transpose();
    res.bias += w * d;
  };
  const double w_axis = (4.0 - m) / 18.0, w_pair = 1.0 / 36.0;
  if (w_axis != 0.0)
    for (int k = 0; k < m; ++k)
      for (double sk : {-s3, s3}) add(sk * S.col(k), w_axis);
  for (int k = 0; k < m; ++k)
    for (int l = k + 1; l < m; ++l)
      for (double sk : {-s3, s3})
        for (double sl : {-s3, s3}) add(sk * S.col(k) + sl * S.col(l), w_pair);
  if (!inside) return res;
  res.mse = symmetrize(res.mse);
  res.ok = positiveDefinite(res.mse);
  return res;
}

// |P_xy^-1/2 b_xy| (GlobalFix::nonlinearity), position only: with stereo bearings the heading is
// nearly a function of the position along a curved arc, so the 3-dof value is large for every
// fix (the arc's sagitta is many thin-direction sigmas) although the sigma points capture exactly
// that curvature; the position block says whether the circle intersection itself is close to
// linear over the noise. P - b b^T is the sigma points' covariance about their mean, positive
// semi-definite for non-negative weights, so the value lies in [0, 1).
double nonlinearityOf(const SigmaPointMse& sp) {
  const Eigen::Matrix2d P = sp.mse.topLeftCorner<2, 2>();
  const Eigen::Vector2d b = sp.bias.head<2>();
  const Eigen::LLT<Eigen::Matrix2d> llt(P);
  if (llt.info() != Eigen::Success) return 1.0;
  return std::min(1.0, std::sqrt(std::max(0.0, b.dot(llt.solve(b)))));
}

// fix1's mean squared error about the estimate f0 over Gaussian noise of y = (q, psi, theta),
// q the range or its inverse (`inverse`), exact in the angles: phi = theta + psi and theta given
// q are Gaussian, and E[cos phi], E[theta sin phi], ... have closed forms (E[e^{i phi}] =
// e^{i m - s^2/2}; Stein's lemma for the theta products); q by a 7-point Gauss-Hermite rule. The
// fifth-degree sigma points miss the arc's sixth-order terms in the direction the bearing alone
// fixes when the compass is far wider than the bearing (fixstudy on 0.06 px pixels at a 10 deg
// compass: mean 3-dof NEES 3.8-10.7). Not ok when a node leaves the domain (q <= 0).
SigmaPointMse oneLandmarkMse(const Eigen::Vector3d& y, const Eigen::Matrix3d& y_cov, bool inverse,
                             const Eigen::Vector2d& landmark, const Pose2& f0) {
  SigmaPointMse res;
  // z = (q, phi, theta) = T y.
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T(1, 2) = 1.0;
  const Eigen::Vector3d z = T * y;
  const Eigen::Matrix3d Z = T * y_cov * T.transpose();
  const double var_q = Z(0, 0);
  // (phi, theta) given q: mean z.tail + gain (q - q_hat), covariance C.
  const Eigen::Vector2d gain = var_q > 0.0 ? Eigen::Vector2d(Z.block<2, 1>(1, 0) / var_q) : Eigen::Vector2d::Zero();
  const Eigen::Matrix2d C = Z.block<2, 2>(1, 1) - gain * Z.block<1, 2>(0, 1);
  const double s2 = std::max(0.0, C(0, 0)), c_pt = C(0, 1), v_t = std::max(0.0, C(1, 1));
  const double e1 = std::exp(-0.5 * s2), e2 = std::exp(-2.0 * s2);
  const Eigen::Vector2d a = landmark - f0.translation();
  static constexpr double kNodes[7] = {-3.7504397177257425, -2.3667594107345415, -1.1544053947399682, 0.0,
                                       1.1544053947399682,  2.3667594107345415,  3.7504397177257425};
  static constexpr double kWeights[7] = {0.00054826885597221875, 0.030757123967586497, 0.24012317860501275,
                                         0.45714285714285713,    0.24012317860501275,  0.030757123967586497,
                                         0.00054826885597221875};
  for (int k = 0; k < 7; ++k) {
    const double dq = kNodes[k] * std::sqrt(std::max(0.0, var_q));
    const double q = z(0) + dq;
    const double r = inverse ? (q > 0.0 ? 1.0 / q : -1.0) : q;
    if (!(r > 0.0)) return res;
    // The mean of phi, and of theta about the estimate's heading, given q.
    const double m = z(1) + gain(0) * dq, mt = angleDiff(z(2), f0.theta) + gain(1) * dq;
    const double cm = std::cos(m), sm = std::sin(m), c2m = std::cos(2.0 * m), s2m = std::sin(2.0 * m);
    const double Ec = cm * e1, Es = sm * e1;                              // E[cos phi], E[sin phi]
    const double Ecc = 0.5 * (1.0 + c2m * e2), Ess = 0.5 * (1.0 - c2m * e2), Esc = 0.5 * s2m * e2;
    const double Etc = mt * Ec - c_pt * Es, Ets = mt * Es + c_pt * Ec;  // E[dtheta cos phi], E[dtheta sin phi]
    // d = (a_x - r cos phi, a_y - r sin phi, dtheta).
    Eigen::Matrix3d M;
    M(0, 0) = a.x() * a.x() - 2.0 * a.x() * r * Ec + r * r * Ecc;
    M(1, 1) = a.y() * a.y() - 2.0 * a.y() * r * Es + r * r * Ess;
    M(0, 1) = M(1, 0) = a.x() * a.y() - a.x() * r * Es - a.y() * r * Ec + r * r * Esc;
    M(0, 2) = M(2, 0) = a.x() * mt - r * Etc;
    M(1, 2) = M(2, 1) = a.y() * mt - r * Ets;
    M(2, 2) = v_t + mt * mt;
    res.mse += kWeights[k] * M;
    res.bias += kWeights[k] * Eigen::Vector3d(a.x() - r * Ec, a.y() - r * Es, mt);
  }
  res.mse = symmetrize(res.mse);
  res.ok = positiveDefinite(res.mse);
  return res;
}

// The two-circle closed form without derivatives, at one sigma point: p as in solveTwoCircles
// with h = sqrt(max(h^2, 0)) (circles that no longer meet continue to the baseline point), theta
// the fixed combination w of the two headings (4.6). False where it is undefined.
bool twoCirclePose(const Vector8d& x, int side, const Eigen::Vector2d& w, Pose2* pose) {
  const Eigen::Vector2d c1 = x.segment<2>(0), c2 = x.segment<2>(4);
  const double r1 = x(2), r2 = x(6);
  if (!(r1 > 0.0 && r2 > 0.0)) return false;
  const Eigen::Vector2d baseline = c2 - c1;
  const double d = baseline.norm();
  if (!(d > 0.0)) return false;
  const Eigen::Vector2d e = baseline / d;
  const Eigen::Vector2d n(-e.y(), e.x());
  const double a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d);
  const double h = std::sqrt(std::max(0.0, r1 * r1 - a * a));
  const Eigen::Vector2d p = c1 + a * e + side * h * n;
  double th[2];
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d q = x.segment<2>(4 * i) - p;
    if (!(q.squaredNorm() > 0.0)) return false;
    th[i] = std::atan2(q.y(), q.x()) - x(4 * i + 3);
  }
  *pose = Pose2(p.x(), p.y(), wrapAngle(th[0] + w(1) * angleDiff(th[1], th[0])));
  return pose->translation().allFinite();
}

// Ranges propagated as inverse range (GlobalFixOptions::stereo_inverse_range), per circle.
using InverseRange = std::array<bool, 2>;

// Covariance of a pose from the measurements' information when the closed form has no usable
// Jacobian (tangent or non-intersecting circles): the residuals z_i - h(pose, c_i), whose noise
// is G dx with G = [dh/dp_xy, I] per centre (h depends on c - p), give W = G Sigma_x G^T and the
// Gauss-Newton covariance (H^T W^-1 H)^-1, H = dh/dpose.
// Also returns the residuals' chi-square r^T W^-1 r (1 dof: 4 measurements, 3 pose parameters).
bool informationCovariance(const Pose2& pose, const Vector8d& x, const Matrix8d& x_cov, Eigen::Matrix3d* cov,
                           double* chi2) {
  Eigen::Vector4d residual;
  Eigen::Matrix<double, 4, 3> H;
  Eigen::Matrix<double, 4, 8> G = Eigen::Matrix<double, 4, 8>::Zero();
  for (int i = 0; i < 2; ++i) {
    Matrix23d Hi;
    try {
      predictRangeBearing(pose, x.segment<2>(4 * i), &Hi);
    } catch (const GeometryError&) {
      return false;
    }
    const Eigen::Vector2d zi = predictRangeBearing(pose, x.segment<2>(4 * i));
    residual.segment<2>(2 * i) = rangeBearingInnovation(x.segment<2>(4 * i + 2), zi);
    H.block<2, 3>(2 * i, 0) = Hi;
    G.block<2, 2>(2 * i, 4 * i) = Hi.leftCols<2>();
    G.block<2, 2>(2 * i, 4 * i + 2) = Eigen::Matrix2d::Identity();
  }
  const Eigen::Matrix4d W = G * x_cov * G.transpose();
  Eigen::LDLT<Eigen::Matrix4d> ldlt(0.5 * (W + W.transpose()));
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || ldlt.vectorD().minCoeff() <= 0) return false;
  *chi2 = residual.dot(ldlt.solve(residual));
  const Eigen::Matrix3d info = H.transpose() * ldlt.solve(H);
  Eigen::LLT<Eigen::Matrix3d> llt(symmetrize(info));
  if (llt.info() != Eigen::Success) return false;
  *cov = symmetrize(llt.solve(Eigen::Matrix3d::Identity()));
  return positiveDefinite(*cov);
}

// The point on the line c1 + t e closest (in the weighted sense) to both circles, for circles
// that do not meet: minimises (|t| - r1)^2 / v1 + (|t - d| - r2)^2 / v2 over the four sign
// branches. Returns t and the minimal cost (chi-square with 1 dof when the circles should meet).
std::pair<double, double> closestOnBaseline(double d, double r1, double r2, double v1, double v2) {
  const double w1 = 1.0 / v1, w2 = 1.0 / v2;
  double best_t = 0.0, best_cost = std::numeric_limits<double>::infinity();
  for (int s1 : {-1, 1}) {
    for (int s2 : {-1, 1}) {
      const double t = (w1 * s1 * r1 + w2 * (d + s2 * r2)) / (w1 + w2);
      const double e1 = std::fabs(t) - r1, e2 = std::fabs(t - d) - r2;
      const double cost = e1 * e1 * w1 + e2 * e2 * w2;
      if (cost < best_cost) {
        best_cost = cost;
        best_t = t;
      }
    }
  }
  return {best_t, best_cost};
}

GlobalFix toFix(const TwoCircleSolution& sol, FixMethod method, std::vector<int> ids) {
  GlobalFix f;
  f.status = sol.status;
  f.method = method;
  f.pose = sol.pose;
  f.covariance = sol.covariance;
  f.nonlinearity = sol.nonlinearity;
  f.landmark_ids = std::move(ids);
  return f;
}

struct TwoLandmarkProblem {
  Vector8d x;
  Matrix8d x_cov;
  int side = 1;
  double significance = 0.0;
  InverseRange inverse_range{false, false};
};

TwoLandmarkProblem makeTwoLandmarkProblem(const Observation& a, const Observation& b, const Eigen::Vector2d& la,
                                          const Eigen::Vector2d& lb, const GlobalFixOptions& options) {
  checkObservation(a, "fix2");
  checkObservation(b, "fix2");
  if (!la.allFinite() || !lb.allFinite()) throw Error("fix2: landmark position is not finite");
  TwoLandmarkProblem p;
  p.x << la.x(), la.y(), a.range, a.bearing, lb.x(), lb.y(), b.range, b.bearing;
  p.x_cov.setZero();
  p.x_cov.block<2, 2>(2, 2) = a.covariance;
  p.x_cov.block<2, 2>(6, 6) = b.covariance;
  p.inverse_range = {options.stereo_inverse_range && a.pixels.has_value(),
                     options.stereo_inverse_range && b.pixels.has_value()};
  p.side = orderingSide(a.bearing, b.bearing);
  p.significance =
      orderingSignificance(a.bearing, b.bearing, std::sqrt(std::max(0.0, a.covariance(1, 1) + b.covariance(1, 1))));
  return p;
}

// Ambiguous when the bearing order is not significant AND the mirror solution is further away
// than the position uncertainty across the baseline (otherwise the choice does not matter).
bool orderingAmbiguous(const TwoCircleSolution& sol, const Vector8d& x, double significance,
                       const GlobalFixOptions& options) {
  if (sol.status != FixStatus::Ok || significance >= options.ordering_min_sigma) return false;
  const Eigen::Vector2d e = (x.segment<2>(4) - x.segment<2>(0)).normalized();
  const Eigen::Vector2d n(-e.y(), e.x());
  const double sigma_n = std::sqrt(std::max(0.0, n.dot(sol.covariance.topLeftCorner<2, 2>() * n)));
  return sol.half_chord > sigma_n;
}

}  // namespace

int orderingSide(double psi1, double psi2) { return angleDiff(psi2, psi1) >= 0.0 ? 1 : -1; }

double orderingSignificance(double psi1, double psi2, double sigma_difference) {
  const double delta = std::fabs(angleDiff(psi2, psi1));
  const double distance = std::min(delta, kPi - delta);
  if (!(sigma_difference > 0.0)) return distance > 0.0 ? std::numeric_limits<double>::infinity() : 0.0;
  return distance / sigma_difference;
}

namespace {

// The two circles' geometry in the baseline frame c1 -> c2 (4.3, 4.4): the intersections are
// c1 + a e +- h n with h^2 = h2.
struct BaselineFrame {
  Eigen::Vector2d c1, c2, e, n;
  double r1 = 0, r2 = 0, d = 0, a = 0, h2 = 0;
  double scale = 1;        // the geometry's size, for the degeneracy tolerances (mm)
  double tangent_tol = 0;  // |h| below it: tangent circles (mm)
};

// d p / d x at the intersection p: implicit differentiation of |p - c_i|^2 = r_i^2,
// (p - c_i)^T (dp - dc_i) = r_i dr_i; |det A| = d h > 0.
Eigen::Matrix<double, 2, 8> intersectionJacobian(const BaselineFrame& g, const Eigen::Vector2d& p) {
  Eigen::Matrix2d A;
  A.row(0) = (p - g.c1).transpose();
  A.row(1) = (p - g.c2).transpose();
  Eigen::Matrix<double, 2, 8> B = Eigen::Matrix<double, 2, 8>::Zero();
  B.block<1, 2>(0, 0) = (p - g.c1).transpose();
  B(0, 2) = g.r1;
  B.block<1, 2>(1, 4) = (p - g.c2).transpose();
  B(1, 6) = g.r2;
  return A.inverse() * B;
}

// The best linear unbiased weights of the two (correlated) headings with covariance C; equal
// weights when C is not positive definite.
// Measured (fixstudy, lines with fixed orientation, linear subset, 36000 fixes): these
// weights are evaluated at the noisy estimate, where both headings are dominated by the same
// position error, so they vary from fix to fix with the noise (|w - 1/2| ~ 0.4); that makes
// the 3-dof mean NEES 3.055 (the fix-averaged covariance gives 2.95: the excess is the
// correlation of each fix's heading variance with its error, not a biased covariance).
// Weights under the bearing noise alone (the heading given the position) give 2.94 but a
// larger heading error, RMS 3.38 -> 3.66 deg there and 11.0 -> 16.4 deg over all fixes;
// recomputing the weights at each sigma point gives 3.14. The BLUE weights are kept.
Eigen::Vector2d headingWeights(const Eigen::Matrix2d& C) {
  Eigen::Vector2d w(0.5, 0.5);
  Eigen::LDLT<Eigen::Matrix2d> ldlt(0.5 * (C + C.transpose()));
  if (ldlt.info() == Eigen::Success && ldlt.isPositive() && ldlt.vectorD().minCoeff() > 0) {
    const Eigen::Vector2d ci1 = ldlt.solve(Eigen::Vector2d::Ones());
    const double sum = ci1.sum();
    if (std::isfinite(sum) && sum > 0) w = ci1 / sum;
  }
  return w;
}

// The second-order term of the heading's variance: the Hessian H of theta = sum_i w_i
// atan2(c_i - p) with respect to p gives 1/2 tr(H P H P), P = cov(p).
double secondOrderHeadingVariance(const Vector8d& x, const Eigen::Vector2d& p, const Eigen::Vector2d& w,
                                  const Eigen::Matrix2d& P) {
  Eigen::Matrix2d H = Eigen::Matrix2d::Zero();
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d q = x.segment<2>(4 * i) - p;
    const double rho4 = q.squaredNorm() * q.squaredNorm();
    Eigen::Matrix2d Hi;
    Hi << 2 * q.x() * q.y(), q.y() * q.y() - q.x() * q.x(),  //
        q.y() * q.y() - q.x() * q.x(), -2 * q.x() * q.y();
    H += w(i) * Hi / rho4;
  }
  return 0.5 * (H * P * H * P).trace();
}

// The sigma-point covariance of the fix (heading weights w held), propagated in the space of x
// with the flagged ranges replaced by 1 / r (covariance T x_cov T^T). Sets sol.covariance and
// sol.nonlinearity, or only the nonlinearity (1: keep the second-order covariance) when a sigma
// point has no fix.
void sigmaPointCovariance(const Vector8d& x, const Matrix8d& x_cov, int side, const Eigen::Vector2d& w,
                          const InverseRange& inverse_range, TwoCircleSolution* sol) {
  Vector8d y = x;
  Matrix8d T = Matrix8d::Identity();
  for (int i = 0; i < 2; ++i) {
    if (!inverse_range[i]) continue;
    const int k = 4 * i + 2;
    y(k) = 1.0 / x(k);
    T(k, k) = -1.0 / (x(k) * x(k));
  }
  const auto f = [&](const Vector8d& yy, Pose2* pose) {
    Vector8d xx = yy;
    for (int i = 0; i < 2; ++i) {
      if (!inverse_range[i]) continue;
      const int k = 4 * i + 2;
      if (!(yy(k) > 0.0)) return false;  // the sigma point's range went through infinity
      xx(k) = 1.0 / yy(k);
    }
    return twoCirclePose(xx, side, w, pose);
  };
  const SigmaPointMse sp = sigmaPointMse<8>(y, Matrix8d(T * x_cov * T.transpose()), sol->pose, f);
  if (sp.ok) {
    sol->covariance = sp.mse;
    sol->nonlinearity = nonlinearityOf(sp);
  } else {
    sol->nonlinearity = 1.0;
  }
}

// Circles that meet (h2 above the tangent tolerance): the intersection on `side`, (4.6)'s
// headings combined, the covariance (4.18) and its refinements.
TwoCircleSolution intersectingFix(const BaselineFrame& g, const Vector8d& x, const Matrix8d& x_cov, int side,
                                  const GlobalFixOptions& options, const InverseRange& inverse_range) {
  TwoCircleSolution sol;
  const double h = std::sqrt(g.h2);
  const Eigen::Vector2d p = g.c1 + g.a * g.e + side * h * g.n;
  const Eigen::Matrix<double, 2, 8> J_p_x = intersectionJacobian(g, p);

  // (4.6) for each landmark: theta_i = atan2(c_i - p) - psi_i.
  Eigen::Matrix<double, 2, 8> J_t_x = Eigen::Matrix<double, 2, 8>::Zero();
  double theta_i[2];
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d ci = x.segment<2>(4 * i);
    const Eigen::Vector2d q = ci - p;
    const Eigen::RowVector2d grad = atan2Gradient(q);
    theta_i[i] = wrapAngle(std::atan2(q.y(), q.x()) - x(4 * i + 3));
    J_t_x.row(i) = -grad * J_p_x;
    J_t_x.block<1, 2>(i, 4 * i) += grad;
    J_t_x(i, 4 * i + 3) -= 1.0;
  }
  const Eigen::Vector2d w = headingWeights(J_t_x * x_cov * J_t_x.transpose());
  const double theta = wrapAngle(theta_i[0] + w(1) * angleDiff(theta_i[1], theta_i[0]));

  sol.pose = Pose2(p.x(), p.y(), theta);
  sol.J_pose_x.topRows<2>() = J_p_x;
  sol.J_pose_x.row(2) = w(0) * J_t_x.row(0) + w(1) * J_t_x.row(1);
  sol.covariance = symmetrize(sol.J_pose_x * x_cov * sol.J_pose_x.transpose());  // (4.18)
  if (options.covariance != FixCovariance::FirstOrder)
    sol.covariance(2, 2) += secondOrderHeadingVariance(x, p, w, sol.covariance.topLeftCorner<2, 2>());
  if (options.covariance == FixCovariance::SigmaPoints && !x_cov.isZero(0.0))
    sigmaPointCovariance(x, x_cov, side, w, inverse_range, &sol);
  sol.half_chord = h;
  sol.status = positiveDefinite(sol.covariance) ? FixStatus::Ok : FixStatus::Degenerate;
  // A singular covariance (noise-free inputs) is still a valid pose; keep it Ok when the
  // inputs carry no noise at all, so that exact recovery can be tested.
  if (sol.status == FixStatus::Degenerate && x_cov.isZero(0.0)) sol.status = FixStatus::Ok;
  return sol;
}

// Tangent or non-intersecting circles, where the closed-form Jacobian is singular (dp/dr ~ 1/h):
// the tangent point, or the weighted closest point on the baseline, with the heading the
// circular mean of (4.6) and the covariance from the information of the measurements.
TwoCircleSolution tangentOrApartFix(const BaselineFrame& g, const Vector8d& x, const Matrix8d& x_cov,
                                    const GlobalFixOptions& options) {
  TwoCircleSolution sol;
  Eigen::Vector2d p;
  if (g.h2 >= -g.tangent_tol * g.tangent_tol) {
    p = g.c1 + g.a * g.e;  // tangent: one intersection, on the baseline
    sol.status = FixStatus::Ok;
  } else {
    const double v_centres = g.e.dot((x_cov.block<2, 2>(0, 0) + x_cov.block<2, 2>(4, 4)) * g.e);
    const double floor = 1e-12 * g.scale * g.scale;
    const double v1 = std::max(floor, x_cov(2, 2) + 0.5 * v_centres);
    const double v2 = std::max(floor, x_cov(6, 6) + 0.5 * v_centres);
    const auto [t, cost] = closestOnBaseline(g.d, g.r1, g.r2, v1, v2);
    p = g.c1 + t * g.e;
    sol.gap_sigma = std::sqrt(cost);
    sol.status = sol.gap_sigma > options.max_gap_sigma ? FixStatus::Degenerate : FixStatus::ApproximateNoIntersection;
    // Circles that do not meet: the noise is as large as the geometry, far from linear.
    if (options.covariance == FixCovariance::SigmaPoints) sol.nonlinearity = 1.0;
  }
  // Heading: circular mean of (4.6) over the landmarks the point is not on top of.
  double sum_s = 0.0, sum_c = 0.0;
  for (int i = 0; i < 2; ++i) {
    const Eigen::Vector2d q = x.segment<2>(4 * i) - p;
    if (q.norm() <= 1e-9 * g.scale) continue;
    const double th = std::atan2(q.y(), q.x()) - x(4 * i + 3);
    sum_s += std::sin(th);
    sum_c += std::cos(th);
  }
  if (sum_s == 0.0 && sum_c == 0.0) {
    sol.status = FixStatus::Degenerate;
    return sol;
  }
  sol.pose = Pose2(p.x(), p.y(), std::atan2(sum_s, sum_c));
  Eigen::Matrix3d cov;
  if (sol.status != FixStatus::Degenerate) {
    double chi2 = 0.0;
    if (informationCovariance(sol.pose, x, x_cov, &cov, &chi2)) {
      sol.covariance = cov;
      // The closest point ignores the bearings; when they contradict it (e.g. nested circles
      // whose closest point lies on the far side of a landmark), there is no fix.
      if (chi2 > options.max_gap_sigma * options.max_gap_sigma) sol.status = FixStatus::Degenerate;
      sol.gap_sigma = std::max(sol.gap_sigma, std::sqrt(chi2));
    } else if (!x_cov.isZero(0.0)) {
      sol.status = FixStatus::Degenerate;
    }
  }
  return sol;
}

TwoCircleSolution solveTwoCirclesImpl(const Vector8d& x, const Matrix8d& x_cov, int side,
                                      const GlobalFixOptions& options, const InverseRange& inverse_range) {
  if (!x.allFinite() || !x_cov.allFinite()) throw Error("two-circle fix: input is not finite");
  if (side != 1 && side != -1) throw Error("two-circle fix: side must be +1 or -1");
  BaselineFrame g;
  g.c1 = x.segment<2>(0);
  g.c2 = x.segment<2>(4);
  g.r1 = x(2);
  g.r2 = x(6);
  if (!(g.r1 > 0.0 && g.r2 > 0.0)) return {};  // Degenerate: a range must be positive
  g.scale = std::max({1.0, g.r1, g.r2});
  const Eigen::Vector2d baseline = g.c2 - g.c1;
  g.d = baseline.norm();
  if (g.d <= 1e-9 * g.scale) return {};  // Degenerate: concentric circles / coincident landmarks
  g.e = baseline / g.d;
  g.n = Eigen::Vector2d(-g.e.y(), g.e.x());
  // (4.3), (4.4) in the baseline frame: p = c1 + a e + side h n.
  g.a = (g.r1 * g.r1 - g.r2 * g.r2 + g.d * g.d) / (2.0 * g.d);
  g.h2 = g.r1 * g.r1 - g.a * g.a;
  g.tangent_tol = 1e-9 * g.scale;
  if (g.h2 > g.tangent_tol * g.tangent_tol) return intersectingFix(g, x, x_cov, side, options, inverse_range);
  return tangentOrApartFix(g, x, x_cov, options);
}

}  // namespace

TwoCircleSolution solveTwoCircles(const Vector8d& x, const Matrix8d& x_cov, int side, const GlobalFixOptions& options) {
  return solveTwoCirclesImpl(x, x_cov, side, options, InverseRange{false, false});
}

GlobalFixOptions trackerFixOptions() {
  GlobalFixOptions o;
  o.single_view_covariance = false;
  return o;
}

Observation fixSighting(const Observation& o, const GlobalFixOptions& options) {
  Observation out = o;
  if (options.single_view_covariance && o.single_view_share != 1.0) {
    out.covariance *= o.single_view_share;
    out.pixel_covariance *= o.single_view_share;
    out.single_view_share = 1.0;
  }
  return out;
}

GlobalFix fixFromTwoLandmarks(const Observation& a_stated, const Observation& b_stated,
                              const Eigen::Vector2d& landmark_a, const Eigen::Vector2d& landmark_b,
                              const GlobalFixOptions& options) {
  const Observation a = fixSighting(a_stated, options), b = fixSighting(b_stated, options);
  const TwoLandmarkProblem prob = makeTwoLandmarkProblem(a, b, landmark_a, landmark_b, options);
  const TwoCircleSolution sol = solveTwoCirclesImpl(prob.x, prob.x_cov, prob.side, options, prob.inverse_range);
  GlobalFix f = toFix(sol, FixMethod::TwoLandmarks, {a.landmark_id, b.landmark_id});
  if (orderingAmbiguous(sol, prob.x, prob.significance, options)) f.status = FixStatus::Ambiguous;
  return f;
}

GlobalFix fixFromOneLandmark(const Observation& o_stated, const Eigen::Vector2d& landmark, double compass_theta,
                             double compass_sigma, const GlobalFixOptions& options) {
  checkObservation(o_stated, "fix1");
  const Observation o = fixSighting(o_stated, options);
  if (!landmark.allFinite()) throw Error("fix1: landmark position is not finite");
  if (!std::isfinite(compass_theta)) throw Error("fix1: compass heading is not finite");
  if (!(std::isfinite(compass_sigma) && compass_sigma >= 0.0)) throw Error("fix1: compass sigma must be >= 0");
  GlobalFix f;
  f.method = FixMethod::OneLandmarkCompass;
  f.landmark_ids = {o.landmark_id};
  if (!(o.range > 0.0)) {
    f.status = FixStatus::Degenerate;
    return f;
  }
  const double sigma = std::max(compass_sigma, options.compass_sigma_floor);
  // (4.10): p = l - r (cos phi, sin phi), phi = theta + psi.
  const double phi = compass_theta + o.bearing;
  const double c = std::cos(phi), s = std::sin(phi), r = o.range;
  f.pose = Pose2(landmark.x() - r * c, landmark.y() - r * s, compass_theta);
  // (4.15) with the input (r, psi, theta) instead of (u_l, u_r, theta): J_i of 4.4.1.
  Eigen::Matrix3d J;
  J << -c, r * s, r * s,  //
      -s, -r * c, -r * c,  //
      0.0, 0.0, 1.0;
  Eigen::Matrix3d input_cov = Eigen::Matrix3d::Zero();
  input_cov.topLeftCorner<2, 2>() = o.covariance;
  input_cov(2, 2) = sigma * sigma;  // (4.14)
  f.covariance = symmetrize(J * input_cov * J.transpose());
  if (options.covariance != FixCovariance::FirstOrder) {
    // Hessians of x, y of (4.10) w.r.t. (r, psi, theta); theta is linear.
    Eigen::Matrix3d Hx, Hy;
    Hx << 0.0, s, s, s, r * c, r * c, s, r * c, r * c;
    Hy << 0.0, -c, -c, -c, r * s, r * s, -c, r * s, r * s;
    const Eigen::Matrix3d A = Hx * input_cov, B = Hy * input_cov;
    f.covariance(0, 0) += 0.5 * (A * A).trace();
    f.covariance(1, 1) += 0.5 * (B * B).trace();
    f.covariance(0, 1) += 0.5 * (A * B).trace();
    f.covariance(1, 0) = f.covariance(0, 1);
  }
  if (options.covariance == FixCovariance::SigmaPoints) {
    // (4.10) over y = (r or 1/r, psi, theta); see sigmaPointMse.
    const bool inverse = options.stereo_inverse_range && o.pixels.has_value();
    Eigen::Vector3d y(inverse ? 1.0 / r : r, o.bearing, compass_theta);
    Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
    if (inverse) T(0, 0) = -1.0 / (r * r);
    const Eigen::Matrix3d y_cov = T * input_cov * T.transpose();
    const SigmaPointMse sp = oneLandmarkMse(y, y_cov, inverse, landmark, f.pose);
    if (sp.ok) {
      f.covariance = sp.mse;
      f.nonlinearity = nonlinearityOf(sp);
    } else {
      f.nonlinearity = 1.0;  // keep the second-order covariance
    }
  }
  f.status = positiveDefinite(f.covariance) ? FixStatus::Ok : FixStatus::Degenerate;
  return f;
}

RunningFixResult runningFix(const Observation& earlier, const Observation& later, const Eigen::Vector2d& landmark,
                            const Eigen::Vector3d& motion_world, const Eigen::Matrix3d& motion_covariance,
                            const std::optional<Eigen::Vector2d>& coarse_prior, const GlobalFixOptions& options) {
  checkObservation(earlier, "running fix");
  checkObservation(later, "running fix");
  if (earlier.landmark_id >= 0 && later.landmark_id >= 0 && earlier.landmark_id != later.landmark_id)
    throw Error("running fix: the two observations are of different landmarks (" +
                std::to_string(earlier.landmark_id) + ", " + std::to_string(later.landmark_id) + ")");
  if (!landmark.allFinite() || !motion_world.allFinite() || !motion_covariance.allFinite())
    throw Error("running fix: landmark or motion is not finite");
  // Inputs y = (r1, psi1, r2, psi2, dx, dy, dtheta); the virtual landmark is l + (dx, dy), seen
  // from the later pose at bearing psi1 - dtheta (the earlier direction to l, re-expressed).
  Eigen::Matrix<double, 7, 7> y_cov = Eigen::Matrix<double, 7, 7>::Zero();
  y_cov.block<2, 2>(0, 0) = earlier.covariance;
  y_cov.block<2, 2>(2, 2) = later.covariance;
  y_cov.block<3, 3>(4, 4) = motion_covariance;
  Eigen::Matrix<double, 8, 7> M = Eigen::Matrix<double, 8, 7>::Zero();
  M(0, 4) = 1.0;
  M(1, 5) = 1.0;
  M(2, 0) = 1.0;
  M(3, 1) = 1.0;
  M(3, 6) = -1.0;
  M(6, 2) = 1.0;
  M(7, 3) = 1.0;
  Vector8d x;
  const double psi_virtual = wrapAngle(earlier.bearing - motion_world.z());
  x << landmark.x() + motion_world.x(), landmark.y() + motion_world.y(), earlier.range, psi_virtual, landmark.x(),
      landmark.y(), later.range, later.bearing;
  const Matrix8d x_cov = M * y_cov * M.transpose();

  RunningFixResult res;
  const int side = orderingSide(psi_virtual, later.bearing);
  const double var_diff = x_cov(3, 3) + x_cov(7, 7) - 2.0 * x_cov(3, 7);
  const double significance = orderingSignificance(psi_virtual, later.bearing, std::sqrt(std::max(0.0, var_diff)));
  const std::vector<int> ids{later.landmark_id, later.landmark_id};
  // x(2) is the earlier range (virtual landmark), x(6) the later one.
  const InverseRange inverse{options.stereo_inverse_range && earlier.pixels.has_value(),
                             options.stereo_inverse_range && later.pixels.has_value()};
  const TwoCircleSolution s0 = solveTwoCirclesImpl(x, x_cov, side, options, inverse);
  const TwoCircleSolution s1 = solveTwoCirclesImpl(x, x_cov, -side, options, inverse);
  res.candidates[0] = toFix(s0, FixMethod::RunningFix, ids);
  res.candidates[1] = toFix(s1, FixMethod::RunningFix, ids);
  if (!res.candidates[0].hasPose()) {
    res.status = s0.status;
    return res;
  }
  res.status = s0.status;  // Ok or ApproximateNoIntersection
  if (s0.status != FixStatus::Ok || s0.half_chord == 0.0) {
    res.preferred = 0;  // tangent / closest point: both candidates coincide
  } else if (coarse_prior) {
    const double d0 = (res.candidates[0].pose.translation() - *coarse_prior).norm();
    const double d1 = (res.candidates[1].pose.translation() - *coarse_prior).norm();
    res.preferred = d0 <= d1 ? 0 : 1;
  } else if (!orderingAmbiguous(s0, x, significance, options)) {
    res.preferred = 0;
  } else {
    res.status = FixStatus::Ambiguous;
    res.preferred = -1;
  }
  return res;
}

namespace {

// Preference among usable fixes: Ok before flagged ones, then the smaller position covariance.
bool better(const GlobalFix& a, const GlobalFix& b) {
  if (!b.hasPose()) return a.hasPose();
  if (!a.hasPose()) return false;
  const bool a_ok = a.status == FixStatus::Ok, b_ok = b.status == FixStatus::Ok;
  if (a_ok != b_ok) return a_ok;
  return a.covariance.topLeftCorner<2, 2>().trace() < b.covariance.topLeftCorner<2, 2>().trace();
}

// fix2 with the map bounds as the tie-breaker of an ambiguous ordering.
GlobalFix twoLandmarkFixInMap(const Observation& a, const Observation& b, const Eigen::Vector2d& la,
                              const Eigen::Vector2d& lb, const Bounds& bounds, const GlobalFixOptions& options) {
  GlobalFix f = fixFromTwoLandmarks(a, b, la, lb, options);
  if (f.status != FixStatus::Ambiguous) return f;
  const TwoLandmarkProblem prob = makeTwoLandmarkProblem(a, b, la, lb, options);
  const TwoCircleSolution mirror = solveTwoCirclesImpl(prob.x, prob.x_cov, -prob.side, options, prob.inverse_range);
  const bool in0 = bounds.contains(f.pose.translation(), options.bounds_margin_mm);
  const bool in1 = mirror.status == FixStatus::Ok && bounds.contains(mirror.pose.translation(), options.bounds_margin_mm);
  if (in0 && !in1) {
    f.status = FixStatus::Ok;
  } else if (in1 && !in0) {
    f = toFix(mirror, FixMethod::TwoLandmarks, {a.landmark_id, b.landmark_id});
  }
  return f;
}

// The step's associated sightings, as the fix takes them, and their landmarks.
struct Sightings {
  std::vector<Observation> obs;
  std::vector<Eigen::Vector2d> lms;
  std::vector<Eigen::Vector3d> lms3;  // with heights, for the multi fix's pixel residual
};

Sightings associatedSightings(const Step& step, const FieldMap& map, const GlobalFixOptions& options) {
  Sightings s;
  for (size_t i = 0; i < step.observations.size(); ++i) {
    const Observation& o = step.observations[i];
    if (o.landmark_id < 0) continue;
    const Landmark* l = map.find(o.landmark_id);
    if (!l)
      throw Error("global fix: step " + std::to_string(step.step) + ": observations[" + std::to_string(i) +
                  "]: landmark id " + std::to_string(o.landmark_id) + " is not in map '" + map.name() + "'");
    s.obs.push_back(fixSighting(o, options));
    s.lms.push_back(l->xy());
    s.lms3.push_back(l->position);
  }
  return s;
}

// The best usable fix considered so far (better), and the first failure while none is usable.
struct FixSelection {
  GlobalFix best;
  FixStatus first_failure = FixStatus::NotEnoughLandmarks;

  FixSelection() { best.status = FixStatus::NotEnoughLandmarks; }
  void consider(const GlobalFix& f) {
    if (f.hasPose()) {
      if (better(f, best)) best = f;
    } else if (first_failure == FixStatus::NotEnoughLandmarks) {
      first_failure = f.status;
    }
  }
};

// The pair whose circles cross at the widest angle (the inscribed angle |psi_j - psi_i|:
// dp/dr ~ 1 / sin of it), an Ok fix before a flagged one. Not the pair with the smallest
// covariance, which would select on the range noise (see considerOneLandmarkFix); bearings are ~100x
// more precise than ranges and, for stereo, independent of them. The pairs without a pose go
// to `selection`.
GlobalFix widestTwoLandmarkFix(const Sightings& s, const Bounds& bounds, const GlobalFixOptions& options,
                               FixSelection* selection) {
  const size_t n = s.obs.size();
  std::vector<std::pair<size_t, size_t>> pairs;
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j) pairs.emplace_back(i, j);
  const auto crossing = [&](const std::pair<size_t, size_t>& p) {
    return std::fabs(std::sin(angleDiff(s.obs[p.second].bearing, s.obs[p.first].bearing)));
  };
  std::stable_sort(pairs.begin(), pairs.end(), [&](const auto& a, const auto& b) { return crossing(a) > crossing(b); });
  GlobalFix best;
  best.status = FixStatus::NotEnoughLandmarks;
  for (const auto& [i, j] : pairs) {
    GlobalFix f = twoLandmarkFixInMap(s.obs[i], s.obs[j], s.lms[i], s.lms[j], bounds, options);
    if (!f.hasPose()) {
      selection->consider(f);
      continue;
    }
    if (!best.hasPose() || (f.status == FixStatus::Ok && best.status != FixStatus::Ok)) best = f;
    if (best.status == FixStatus::Ok) break;
  }
  return best;
}

// One landmark of several: the one seen closest to the optical axis (smallest |psi - pan|),
// not the one with the smallest covariance. The covariance grows with the MEASURED range
// (R_rr ~ r^4), so picking by it picks the landmark whose noise shortened its range: the
// chosen fixes are biased towards it and their covariances too small (fixstudy: mean 3-dof
// NEES 0.05-0.13 above the band). A stereo bearing depends on u_l + u_r only, whose noise is
// independent of the disparity's (equal sigmas), so this choice does not select on the
// range noise. (With a compass and n >= 2, allow_multi fuses all landmarks instead.)
void considerOneLandmarkFix(const Sightings& s, double compass, double compass_sigma, const GlobalFixOptions& options,
                            FixSelection* selection) {
  std::vector<size_t> order(s.obs.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return std::fabs(angleDiff(s.obs[a].bearing, s.obs[a].head_pan)) < std::fabs(angleDiff(s.obs[b].bearing, s.obs[b].head_pan));
  });
  for (size_t i : order) {
    const GlobalFix f = fixFromOneLandmark(s.obs[i], s.lms[i], compass, compass_sigma, options);
    selection->consider(f);
    if (f.hasPose()) break;
  }
}

}  // namespace

GlobalFix globalFix(const Step& step, const FieldMap& map, const GlobalFixOptions& options) {
  const Sightings s = associatedSightings(step, map, options);
  const size_t n = s.obs.size();
  const bool has_compass = step.compass.has_value();
  if (has_compass && !std::isfinite(*step.compass))
    throw Error("global fix: step " + std::to_string(step.step) + ": compass is not finite");
  const double compass_sigma = step.compass_sigma > 0.0 ? step.compass_sigma : options.compass_sigma_default;

  FixSelection selection;
  if (options.allow_multi && (n >= 3 || (n >= 2 && has_compass))) {
    GlobalFix f = fixFromLandmarks(s.obs, s.lms3, step.compass, compass_sigma, options);
    if (f.status == FixStatus::Ok) return f;
    selection.consider(f);
  }
  if (options.allow_two_landmarks && n >= 2) {
    const GlobalFix f = widestTwoLandmarkFix(s, map.bounds(), options, &selection);
    if (f.status == FixStatus::Ok && !(selection.best.status == FixStatus::Ok)) return f;
    selection.consider(f);
  }
  if (options.allow_one_landmark && has_compass && n >= 1 && selection.best.status != FixStatus::Ok)
    considerOneLandmarkFix(s, *step.compass, compass_sigma, options, &selection);
  if (!selection.best.hasPose()) selection.best.status = selection.first_failure;
  return selection.best;
}

}  // namespace stereoloc
