#pragma once
// Gaussian helpers: whitening and chi-square statistics for gates and consistency (NEES) checks.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <string>

#include "src/core/error.h"

namespace stereoloc {

// The UPPER-triangular square-root information S of a covariance C: S^T S = C^-1.
// A residual e whitened as S e has squared norm e^T C^-1 e, for any (also non-diagonal) C.
// (Ceres's pose_graph_2d example takes the lower factor L of C^-1 = L L^T and uses L e, whose
// squared norm is e^T L^T L e != e^T C^-1 e unless C is diagonal.)
// Throws stereoloc::Error if C is not finite, not symmetric or not positive definite.
template <int N>
Eigen::Matrix<double, N, N> sqrtInformationUpper(const Eigen::Matrix<double, N, N>& covariance,
                                                 const char* what = "covariance") {
  if (!covariance.allFinite()) throw Error(std::string(what) + ": not finite");
  const double scale = covariance.cwiseAbs().maxCoeff();
  if (!((covariance - covariance.transpose()).cwiseAbs().maxCoeff() <= 1e-9 * (scale > 0 ? scale : 1.0)))
    throw Error(std::string(what) + ": not symmetric");
  const Eigen::Matrix<double, N, N> sym = 0.5 * (covariance + covariance.transpose());
  Eigen::LLT<Eigen::Matrix<double, N, N>> llt_cov(sym);
  if (llt_cov.info() != Eigen::Success) throw Error(std::string(what) + ": not positive definite");
  const Eigen::Matrix<double, N, N> information =
      llt_cov.solve(Eigen::Matrix<double, N, N>::Identity(sym.rows(), sym.cols()));
  Eigen::LLT<Eigen::Matrix<double, N, N>> llt_info(0.5 * (information + information.transpose()));
  if (llt_info.info() != Eigen::Success) throw Error(std::string(what) + ": information not positive definite");
  return llt_info.matrixU();  // = L^T where information = L L^T, so U^T U = information.
}

// Squared Mahalanobis distance e^T C^-1 e (C positive definite).
template <int N>
double mahalanobisSquared(const Eigen::Matrix<double, N, 1>& e, const Eigen::Matrix<double, N, N>& covariance) {
  return e.dot(covariance.ldlt().solve(e));
}

// Chi-square distribution with k degrees of freedom (k >= 1, any integer; k up to 1e6).
double chi2Cdf(double x, int dof);
// The p-quantile (0 < p < 1); exact closed forms for 1 and 2 dof, otherwise Newton on the CDF.
double chi2Quantile(double p, int dof);

// Regularised lower incomplete gamma P(a, x), for a > 0, x >= 0.
double regularizedGammaP(double a, double x);

}  // namespace stereoloc
