#pragma once
// Central-difference Jacobians, for checking analytic Jacobians (tests, selfcheck) — never
// used inside an estimator.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>

namespace stereoloc {

// J(i, j) = (f(x + h_j e_j) - f(x - h_j e_j))_i / (2 h_j), with h_j = step * max(1, |x_j|).
// `minus(a, b)` forms the output difference (pass a wrapping difference for angle outputs).
template <int M, int N, typename F, typename Minus>
Eigen::Matrix<double, M, N> numericJacobian(const F& f, const Eigen::Matrix<double, N, 1>& x, const Minus& minus,
                                            double step = 1e-6) {
  Eigen::Matrix<double, M, N> J;
  for (int j = 0; j < N; ++j) {
    const double h = step * std::max(1.0, std::fabs(x(j)));
    Eigen::Matrix<double, N, 1> xp = x, xm = x;
    xp(j) += h;
    xm(j) -= h;
    J.col(j) = minus(f(xp), f(xm)) / (2.0 * h);
  }
  return J;
}

template <int M, int N, typename F>
Eigen::Matrix<double, M, N> numericJacobian(const F& f, const Eigen::Matrix<double, N, 1>& x, double step = 1e-6) {
  return numericJacobian<M, N>(
      f, x, [](const Eigen::Matrix<double, M, 1>& a, const Eigen::Matrix<double, M, 1>& b) { return (a - b).eval(); },
      step);
}

// Largest element-wise error relative to max(1, |J|max): the figure the tests bound by 1e-6.
template <typename A, typename B>
double relativeJacobianError(const A& analytic, const B& numeric) {
  const double scale = std::max(1.0, numeric.cwiseAbs().maxCoeff());
  return (analytic - numeric).cwiseAbs().maxCoeff() / scale;
}

}  // namespace stereoloc
