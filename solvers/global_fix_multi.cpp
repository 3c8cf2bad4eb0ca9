// The n-landmark global fix (thesis 4.2.8): nonlinear least squares on range and bearing,
// solved with Ceres from closed-form starting points, covariance from the Jacobian.
#include <ceres/autodiff_cost_function.h>
#include <ceres/problem.h>
#include <ceres/solver.h>

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include "factors/stereo_pixel_factor.h"
#include "solvers/global_fix.h"
#include "src/core/error.h"
#include "src/core/gaussian.h"
#include "src/core/measurement_model.h"

namespace stereoloc {
namespace {

// r = S (h(p, l) [-] z), h = predictRangeBearingT (5.27); p = (x, y, theta) world (mm, rad),
// l landmark (mm), z = (range mm, bearing rad) in C0, S the upper square-root information of R.
// With `inverse` (stereo observations, GlobalFixOptions::stereo_inverse_range) the range row is
// in inverse range, 1/h_r - 1/z_r (1/mm), and S whitens T R T^T, T = diag(-1/z_r^2, 1): stereo
// range is f b / disparity (3.4, 3.6), so the inverse range is linear in the pixels and its noise
// Gaussian, whereas the range's is skewed and R(0,0) ~ r^4 is evaluated at the noisy range.
// (The same residual as the smoothers' range-bearing factor; kept local so that the solvers
// library does not depend on a factors/ header for one functor.)
struct FixRangeBearingResidual {
  FixRangeBearingResidual(const Eigen::Vector2d& l, const Eigen::Vector2d& z, const Eigen::Matrix2d& S, bool inverse)
      : l_(l), z_(z), S_(S), inverse_(inverse) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    const T dx = T(l_[0]) - pose[0], dy = T(l_[1]) - pose[1];
    if (dx * dx + dy * dy < T(1e-12)) return false;  // bearing undefined on the landmark
    const T l[2] = {T(l_[0]), T(l_[1])};
    T h[2];
    predictRangeBearingT(pose, l, h);
    const T e0 = inverse_ ? T(1.0) / h[0] - T(1.0 / z_[0]) : h[0] - T(z_[0]);
    const T e1 = wrapAngle<T>(h[1] - T(z_[1]));
    residual[0] = T(S_(0, 0)) * e0 + T(S_(0, 1)) * e1;
    residual[1] = T(S_(1, 1)) * e1;
    return true;
  }
  Eigen::Vector2d l_, z_;
  Eigen::Matrix2d S_;
  bool inverse_;
};

// r = wrap(theta - theta_compass) / sigma: the compass as an absolute heading measurement (4.3.2).
struct CompassResidual {
  CompassResidual(double theta, double sigma) : theta_(theta), sigma_(sigma) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    residual[0] = wrapAngle<T>(pose[2] - T(theta_)) / T(sigma_);
    return true;
  }
  double theta_, sigma_;
};

struct Solved {
  bool ok = false;
  Pose2 pose;
  double chi2 = std::numeric_limits<double>::infinity();  // 2 * Ceres cost = sum of squared whitened residuals
};

// One residual block per observation: the stereo pixel factor or the range-bearing residual.
struct ObservationCost {
  bool pixels = false;  // StereoPixelFactor on (u_l, u_r) (GlobalFixOptions::rig)
  Eigen::Vector2d l2;
  Eigen::Vector3d l3;
  Eigen::Vector2d z;
  Eigen::Matrix2d S;  // range-bearing: upper square-root information (of T R T^T when inverse)
  bool inverse = false;
  const Observation* obs = nullptr;
  // The cost with the measurement moved by `u` in whitened units (u = 0: as measured): pixels
  // (u_l, u_r) += L u with L L^T their covariance; range-bearing (or inverse range-bearing) += S^-1 u, the square root of
  // its covariance. nullptr when the moved range is not positive.
  ceres::CostFunction* create(const std::optional<StereoRig>& rig, const Eigen::Vector2d& u = Eigen::Vector2d::Zero()) const {
    if (pixels) {
      StereoPixels px = *obs->pixels;
      const Eigen::Matrix4d& C = obs->pixel_covariance;
      Eigen::Matrix2d C2;
      C2 << C(0, 0), C(0, 2), C(2, 0), C(2, 2);
      const Eigen::Vector2d du = Eigen::LLT<Eigen::Matrix2d>(C2).matrixL() * u;
      px.u_left += du(0);
      px.u_right += du(1);
      return StereoPixelFactor::Create(*rig, l3, px, obs->head_pan, C, PixelResiduals::Columns);
    }
    Eigen::Vector2d zz = z;
    if (!u.isZero(0.0)) {
      const Eigen::Vector2d dz = S.triangularView<Eigen::Upper>().solve(u);
      if (inverse) {
        const double rho = 1.0 / z(0) + dz(0);
        if (!(rho > 0.0)) return nullptr;
        zz(0) = 1.0 / rho;
      } else {
        zz(0) = z(0) + dz(0);
        if (!(zz(0) > 0.0)) return nullptr;
      }
      zz(1) = z(1) + dz(1);
    }
    return new ceres::AutoDiffCostFunction<FixRangeBearingResidual, 2, 3>(new FixRangeBearingResidual(l2, zz, S, inverse));
  }
};

// Gauss-Newton on the (whitened) residuals from `start`, for the sigma points of the covariance:
// each moves the measurements a little, so the optimum moves a little and a few undamped steps
// from the measured optimum converge. False when a residual cannot be evaluated or it does not
// converge in 50 steps.
bool gaussNewton(const std::vector<std::unique_ptr<ceres::CostFunction>>& costs, const std::optional<double>& compass,
                 double compass_sigma, Pose2* pose) {
  double x[3] = {pose->x, pose->y, pose->theta};
  for (int it = 0; it < 50; ++it) {
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    Eigen::Vector3d g = Eigen::Vector3d::Zero();
    const double* params[] = {x};
    for (const auto& c : costs) {
      Eigen::Vector2d r;
      Eigen::Matrix<double, 2, 3, Eigen::RowMajor> J;
      double* jac[] = {J.data()};
      if (!c->Evaluate(params, r.data(), jac)) return false;
      H += J.transpose() * J;
      g += J.transpose() * r;
    }
    if (compass) {
      H(2, 2) += 1.0 / (compass_sigma * compass_sigma);
      g(2) += angleDiff(x[2], *compass) / (compass_sigma * compass_sigma);
    }
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(H);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return false;
    const Eigen::Vector3d dx = -ldlt.solve(g);
    if (!dx.allFinite()) return false;
    x[0] += dx(0);
    x[1] += dx(1);
    x[2] = wrapAngle(x[2] + dx(2));
    // Converged when the step is negligible against the estimate's own uncertainty (its
    // Mahalanobis length under the information H below 1e-6 sigma).
    if (dx.dot(H * dx) < 1e-12) {
      *pose = Pose2(x[0], x[1], x[2]);
      return true;
    }
  }
  return false;
}

// Covariance of the least-squares fix by sigma points, like the closed forms' (FixCovariance::
// SigmaPoints, global_fix.cpp): the mean squared error E[(f(z - n) - f(z))(...)^T] of the
// estimator f = argmin about the estimate, over the measurement noise n, by the symmetric
// fifth-degree rule in the m whitened noise coordinates (2 per observation, 1 for the compass):
// points at +-sqrt(3) along each axis (weight (4 - m) / 18) and each pair of axes (1 / 36).
// Why: with stereo the bearings are ~100x more precise than the ranges, so the bearing
// difference pins the position to a thin band along the arc of constant inscribed angle
// (4.2.3) whose curvature over the range uncertainty (sagitta ~ 1-2 mm at 0.5 m) exceeds the
// band's width; (J^T W J)^-1 treats the arc as straight and is over-confident (fixstudy: mean
// 2-dof NEES 3.9-4.8, 3-dof 5.9-8.7). False when a point fails or P is not positive definite.
bool leastSquaresSigmaPoints(const std::vector<ObservationCost>& costs, const std::optional<StereoRig>& rig,
                             const std::optional<double>& compass, double compass_sigma, const Pose2& estimate,
                             Eigen::Matrix3d* mse) {
  const int n = static_cast<int>(costs.size());
  const int m = 2 * n + (compass ? 1 : 0);
  const double s3 = std::sqrt(3.0);
  Eigen::Matrix3d P = Eigen::Matrix3d::Zero();
  Eigen::VectorXd u(m);
  auto add = [&](double w) {
    std::vector<std::unique_ptr<ceres::CostFunction>> moved;
    for (int i = 0; i < n; ++i) {
      moved.emplace_back(costs[i].create(rig, u.segment<2>(2 * i)));
      if (!moved.back()) return false;
    }
    std::optional<double> c;
    if (compass) c = *compass + compass_sigma * u(m - 1);
    Pose2 g = estimate;
    if (!gaussNewton(moved, c, compass_sigma, &g)) return false;
    const Eigen::Vector3d d = minus(g, estimate);
    P += w * d * d.transpose();
    return true;
  };
  const double w_axis = (4.0 - m) / 18.0, w_pair = 1.0 / 36.0;
  for (int k = 0; k < m; ++k)
    for (double sk : {-s3, s3}) {
      u.setZero();
      u(k) = sk;
      if (!add(w_axis)) return false;
    }
  for (int k = 0; k < m; ++k)
    for (int l = k + 1; l < m; ++l)
      for (double sk : {-s3, s3})
        for (double sl : {-s3, s3}) {
          u.setZero();
          u(k) = sk;
          u(l) = sl;
          if (!add(w_pair)) return false;
        }
  P = 0.5 * (P + P.transpose());
  Eigen::LLT<Eigen::Matrix3d> llt(P);
  if (!P.allFinite() || llt.info() != Eigen::Success) return false;
  *mse = P;
  return true;
}

Solved solveFrom(const Pose2& start, const std::vector<ObservationCost>& costs, const std::optional<StereoRig>& rig,
                 const std::optional<double>& compass, double compass_sigma, int max_iterations) {
  double pose[3] = {start.x, start.y, start.theta};
  ceres::Problem problem;
  const double* params[] = {pose};
  for (const ObservationCost& c : costs) {
    ceres::CostFunction* cost = c.create(rig);
    problem.AddResidualBlock(cost, nullptr, pose);
    // A start where a residual is undefined (a landmark behind the cameras, e.g. the mirror
    // candidate with the pixel residual) is skipped rather than handed to Ceres.
    double r[2];
    if (!cost->Evaluate(params, r, nullptr)) return Solved{};
  }
  if (compass)
    problem.AddResidualBlock(
        new ceres::AutoDiffCostFunction<CompassResidual, 1, 3>(new CompassResidual(*compass, compass_sigma)), nullptr,
        pose);
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = max_iterations;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-12;
  so.parameter_tolerance = 1e-12;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  Solved s;
  if (!summary.IsSolutionUsable() || !std::isfinite(pose[0]) || !std::isfinite(pose[1]) || !std::isfinite(pose[2]))
    return s;
  s.ok = true;
  s.pose = Pose2(pose[0], pose[1], pose[2]);
  s.chi2 = 2.0 * summary.final_cost;
  return s;
}

// Each sighting's cost: the pixel factor where a rig and the landmark's height are known and the
// sighting has pixels, else range-bearing (inverse range for stereo with
// GlobalFixOptions::stereo_inverse_range) whitened by its covariance.
std::vector<ObservationCost> observationCosts(const std::vector<Observation>& observations,
                                              const std::vector<Eigen::Vector3d>& landmarks3, bool heights_known,
                                              const GlobalFixOptions& options) {
  const size_t n = observations.size();
  std::vector<ObservationCost> costs(n);
  for (size_t i = 0; i < n; ++i) {
    const Observation& o = observations[i];
    ObservationCost& c = costs[i];
    c.l2 = landmarks3[i].head<2>();
    if (!(std::isfinite(o.range) && std::isfinite(o.bearing)) || !c.l2.allFinite())
      throw Error("multi fix: observation " + std::to_string(i) + " is not finite");
    c.inverse = options.stereo_inverse_range && o.pixels.has_value() && o.range > 0.0;
    Eigen::Matrix2d T = Eigen::Matrix2d::Identity();
    if (c.inverse) T(0, 0) = -1.0 / (o.range * o.range);
    c.S = sqrtInformationUpper<2>(Eigen::Matrix2d(T * o.covariance * T.transpose()),
                                  "multi fix: observation covariance R");
  }
  for (size_t i = 0; i < n; ++i) {
    const Observation& o = observations[i];
    ObservationCost& c = costs[i];
    c.pixels = options.rig.has_value() && heights_known && o.pixels.has_value() &&
               o.pixel_covariance.diagonal().minCoeff() > 0.0;
    if (c.pixels && !(landmarks3[i].allFinite() && std::isfinite(o.head_pan)))
      throw Error("multi fix: observation " + std::to_string(i) + ": landmark or head pan is not finite");
    c.l3 = landmarks3[i];
    c.z = o.z();
    c.obs = &o;
  }
  return costs;
}

// Starting points: both intersections of the best-conditioned pair (so the ordering rule is
// not needed: the bearings of all landmarks decide), and the best one-landmark fix.
std::vector<Pose2> startingPoses(const std::vector<Observation>& observations,
                                 const std::vector<Eigen::Vector2d>& landmarks,
                                 const std::optional<double>& compass_theta, double sigma_c,
                                 const GlobalFixOptions& options) {
  const size_t n = observations.size();
  std::vector<Pose2> starts;
  double best_trace = std::numeric_limits<double>::infinity();
  Pose2 pair_pose, mirror_pose;
  bool have_pair = false;
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j) {
      Vector8d x;
      x << landmarks[i].x(), landmarks[i].y(), observations[i].range, observations[i].bearing, landmarks[j].x(),
          landmarks[j].y(), observations[j].range, observations[j].bearing;
      Matrix8d x_cov = Matrix8d::Zero();
      x_cov.block<2, 2>(2, 2) = observations[i].covariance;
      x_cov.block<2, 2>(6, 6) = observations[j].covariance;
      const int side = orderingSide(observations[i].bearing, observations[j].bearing);
      const TwoCircleSolution s = solveTwoCircles(x, x_cov, side, options);
      if (s.status != FixStatus::Ok && s.status != FixStatus::ApproximateNoIntersection) continue;
      const double tr = s.covariance.topLeftCorner<2, 2>().trace();
      if (tr < best_trace) {
        best_trace = tr;
        pair_pose = s.pose;
        const TwoCircleSolution m = solveTwoCircles(x, x_cov, -side, options);
        mirror_pose = m.status == FixStatus::Degenerate ? s.pose : m.pose;
        have_pair = true;
      }
    }
  if (have_pair) {
    starts.push_back(pair_pose);
    starts.push_back(mirror_pose);
  }
  if (compass_theta) {
    GlobalFix best1;
    for (size_t i = 0; i < n; ++i) {
      const GlobalFix g = fixFromOneLandmark(observations[i], landmarks[i], *compass_theta, sigma_c, options);
      if (g.status == FixStatus::Ok &&
          (best1.status != FixStatus::Ok ||
           g.covariance.topLeftCorner<2, 2>().trace() < best1.covariance.topLeftCorner<2, 2>().trace()))
        best1 = g;
    }
    if (best1.status == FixStatus::Ok) starts.push_back(best1.pose);
  }
  return starts;
}

// The information J^T W J of the pose at `pose`, with the analytic Jacobian of (5.27) (an
// inverse-range row is d(1/h_r) = -dh_r / h_r^2) and a pixel residual's Jacobian from its cost
// function (automatic differentiation of the projection, tested against central differences in
// tests/factors), plus the compass's. False where a sighting cannot be evaluated at `pose`.
bool fixInformation(const std::vector<ObservationCost>& costs, const std::optional<StereoRig>& rig, const Pose2& pose,
                    bool compass, double sigma_c, Eigen::Matrix3d* info_out) {
  Eigen::Matrix3d info = Eigen::Matrix3d::Zero();
  for (const ObservationCost& c : costs) {
    if (c.pixels) {
      const std::unique_ptr<ceres::CostFunction> cost(c.create(rig));
      const double x[3] = {pose.x, pose.y, pose.theta};
      const double* params[] = {x};
      Eigen::Vector2d r;
      Eigen::Matrix<double, 2, 3, Eigen::RowMajor> J;
      double* jac[] = {J.data()};
      if (!cost->Evaluate(params, r.data(), jac)) return false;
      info += J.transpose() * J;
      continue;
    }
    Matrix23d H;
    try {
      const Eigen::Vector2d h = predictRangeBearing(pose, c.l2, &H);
      if (c.inverse) H.row(0) *= -1.0 / (h(0) * h(0));
    } catch (const GeometryError&) {
      return false;
    }
    const Matrix23d SH = c.S * H;
    info += SH.transpose() * SH;
  }
  if (compass) info(2, 2) += 1.0 / (sigma_c * sigma_c);
  *info_out = 0.5 * (info + info.transpose());
  return true;
}

GlobalFix fixFromLandmarksImpl(const std::vector<Observation>& observations,
                               const std::vector<Eigen::Vector3d>& landmarks3, bool heights_known,
                               const std::optional<double>& compass_theta, double compass_sigma,
                               const GlobalFixOptions& options) {
  if (observations.size() != landmarks3.size())
    throw Error("multi fix: " + std::to_string(observations.size()) + " observations but " +
                std::to_string(landmarks3.size()) + " landmark positions");
  std::vector<Eigen::Vector2d> landmarks;
  for (const Eigen::Vector3d& l : landmarks3) landmarks.push_back(l.head<2>());
  GlobalFix f;
  f.method = FixMethod::MultiLandmark;
  for (const Observation& o : observations) f.landmark_ids.push_back(o.landmark_id);
  const size_t n = observations.size();
  if (n < 2 || (n < 3 && !compass_theta)) return f;  // NotEnoughLandmarks
  if (compass_theta && !std::isfinite(*compass_theta)) throw Error("multi fix: compass heading is not finite");
  if (!(std::isfinite(compass_sigma) && compass_sigma >= 0.0)) throw Error("multi fix: compass sigma must be >= 0");
  const double sigma_c = std::max(compass_sigma, options.compass_sigma_floor);
  const std::vector<ObservationCost> costs = observationCosts(observations, landmarks3, heights_known, options);

  const std::vector<Pose2> starts = startingPoses(observations, landmarks, compass_theta, sigma_c, options);
  if (starts.empty()) {
    f.status = FixStatus::Degenerate;
    return f;
  }
  std::vector<Solved> solved;
  for (const Pose2& s : starts) {
    Solved r = solveFrom(s, costs, options.rig, compass_theta, sigma_c, options.multi_max_iterations);
    if (r.ok) solved.push_back(r);
  }
  if (solved.empty()) {
    f.status = FixStatus::Degenerate;
    return f;
  }
  std::sort(solved.begin(), solved.end(), [](const Solved& a, const Solved& b) { return a.chi2 < b.chi2; });
  const Solved& best = solved.front();

  // Covariance (J^T W J)^-1 at the optimum.
  Eigen::Matrix3d info;
  if (!fixInformation(costs, options.rig, best.pose, compass_theta.has_value(), sigma_c, &info)) {
    f.status = FixStatus::Degenerate;
    return f;
  }
  Eigen::LLT<Eigen::Matrix3d> llt(info);
  // Rank check relative to the largest eigenvalue (e.g. all landmarks on one line through the robot).
  const double max_diag = info.diagonal().maxCoeff();
  if (llt.info() != Eigen::Success || !(max_diag > 0) ||
      llt.matrixL().toDenseMatrix().diagonal().minCoeff() <= 1e-9 * std::sqrt(max_diag)) {
    f.status = FixStatus::Degenerate;
    return f;
  }
  f.pose = best.pose;
  f.covariance = llt.solve(Eigen::Matrix3d::Identity());
  f.covariance = 0.5 * (f.covariance + f.covariance.transpose());
  f.status = FixStatus::Ok;
  if (options.covariance == FixCovariance::SigmaPoints) {
    Eigen::Matrix3d mse;
    if (leastSquaresSigmaPoints(costs, options.rig, compass_theta, sigma_c, best.pose, &mse)) {
      f.covariance = mse;
    } else {
      f.nonlinearity = 1.0;  // keep (J^T W J)^-1
    }
  }
  // A second, clearly different optimum that fits almost as well: the data do not decide.
  for (size_t k = 1; k < solved.size(); ++k) {
    const Eigen::Vector3d dpose = minus(solved[k].pose, best.pose);
    const double separation = mahalanobisSquared<3>(dpose, f.covariance);
    if (separation > 9.0 && solved[k].chi2 - best.chi2 < 4.0) f.status = FixStatus::Ambiguous;
  }
  return f;
}

std::vector<Observation> fixSightings(const std::vector<Observation>& observations, const GlobalFixOptions& options) {
  std::vector<Observation> out;
  out.reserve(observations.size());
  for (const Observation& o : observations) out.push_back(fixSighting(o, options));
  return out;
}

}  // namespace

GlobalFix fixFromLandmarks(const std::vector<Observation>& observations, const std::vector<Eigen::Vector2d>& landmarks,
                           const std::optional<double>& compass_theta, double compass_sigma,
                           const GlobalFixOptions& options) {
  std::vector<Eigen::Vector3d> l3;
  for (const Eigen::Vector2d& l : landmarks) l3.emplace_back(l.x(), l.y(), 0.0);
  return fixFromLandmarksImpl(fixSightings(observations, options), l3, false, compass_theta, compass_sigma, options);
}

GlobalFix fixFromLandmarks(const std::vector<Observation>& observations, const std::vector<Eigen::Vector3d>& landmarks,
                           const std::optional<double>& compass_theta, double compass_sigma,
                           const GlobalFixOptions& options) {
  return fixFromLandmarksImpl(fixSightings(observations, options), landmarks, true, compass_theta, compass_sigma,
                              options);
}

}  // namespace stereoloc
