#include "src/calib/stereo_target_problem.h"

#include <opencv2/calib3d.hpp>

namespace stereoloc {
Eigen::MatrixXd intrinsicColumns(const cv::Mat& jac, const StereoTargetLayout& L) {
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(jac.rows, L.intrinsics());
  for (int i = 0; i < jac.rows; ++i) {
    const double* j = jac.ptr<double>(i);
    int k = 0;
    if (L.same_focal) {
      A(i, k++) = j[6] + j[7];
    } else {
      A(i, k++) = j[6];
      A(i, k++) = j[7];
    }
    A(i, k++) = j[8];
    A(i, k++) = j[9];
    for (int d = 0; d < L.distortion; ++d) A(i, k++) = j[10 + d];
  }
  return A;
}

void stereoTargetResiduals(const StereoTargetParameters& p, const StereoTargetLayout& L, int v,
                           const std::vector<cv::Point3d>& X, const std::vector<cv::Point2f>& left,
                           const std::vector<cv::Point2f>& right, Eigen::VectorXd& e, Eigen::MatrixXd* J) {
  const int n = static_cast<int>(X.size());
  e.resize(4 * n);
  if (J) J->setZero(4 * n, L.size());
  std::vector<cv::Point2d> proj;
  cv::Mat jac;
  cv::projectPoints(X, p.rv[v], p.tv[v], p.K[0], p.D[0], proj, J ? jac : cv::noArray());
  for (int i = 0; i < n; ++i) {
    e(2 * i) = proj[i].x - left[i].x;
    e(2 * i + 1) = proj[i].y - left[i].y;
  }
  if (J) {
    J->block(0, L.camera(0), 2 * n, L.intrinsics()) = intrinsicColumns(jac, L);
    for (int i = 0; i < 2 * n; ++i)
      for (int k = 0; k < 6; ++k) (*J)(i, L.view(v) + k) = jac.at<double>(i, k);
  }
  // Right camera: the board in the right frame, X_right = R (R_v X + t_v) + T.
  cv::Mat r3, t3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2;
  cv::composeRT(p.rv[v], p.tv[v], p.r, p.T, r3, t3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2);
  cv::projectPoints(X, r3, t3, p.K[1], p.D[1], proj, J ? jac : cv::noArray());
  for (int i = 0; i < n; ++i) {
    e(2 * n + 2 * i) = proj[i].x - right[i].x;
    e(2 * n + 2 * i + 1) = proj[i].y - right[i].y;
  }
  if (!J) return;
  J->block(2 * n, L.camera(1), 2 * n, L.intrinsics()) = intrinsicColumns(jac, L);
  // J_pose3 = [d/dr3, d/dt3]; chain through composeRT to (r_v, t_v) and (r, T).
  const cv::Mat jr3 = jac.colRange(0, 3), jt3 = jac.colRange(3, 6);
  const cv::Mat d_rv = jr3 * dr3dr1 + jt3 * dt3dr1, d_tv = jr3 * dr3dt1 + jt3 * dt3dt1;
  const cv::Mat d_r = jr3 * dr3dr2 + jt3 * dt3dr2, d_T = jr3 * dr3dt2 + jt3 * dt3dt2;
  for (int i = 0; i < 2 * n; ++i)
    for (int k = 0; k < 3; ++k) {
      (*J)(2 * n + i, L.view(v) + k) = d_rv.at<double>(i, k);
      (*J)(2 * n + i, L.view(v) + 3 + k) = d_tv.at<double>(i, k);
      (*J)(2 * n + i, L.relative() + k) = d_r.at<double>(i, k);
      (*J)(2 * n + i, L.relative() + 3 + k) = d_T.at<double>(i, k);
    }
}

StereoTargetParameters StereoTargetParameters::plus(const StereoTargetLayout& L, const Eigen::VectorXd& dx) const {
  const StereoTargetParameters& p = *this;
  StereoTargetParameters q = p;
  for (int c = 0; c < 2; ++c) {
    q.K[c] = p.K[c].clone();
    q.D[c] = p.D[c].clone();
    int k = L.camera(c);
    if (L.same_focal) {
      q.K[c].at<double>(0, 0) += dx(k);
      q.K[c].at<double>(1, 1) += dx(k++);
    } else {
      q.K[c].at<double>(0, 0) += dx(k++);
      q.K[c].at<double>(1, 1) += dx(k++);
    }
    q.K[c].at<double>(0, 2) += dx(k++);
    q.K[c].at<double>(1, 2) += dx(k++);
    for (int d = 0; d < L.distortion; ++d) q.D[c].at<double>(0, d) += dx(k++);
  }
  for (int k = 0; k < 3; ++k) {
    q.r[k] += dx(L.relative() + k);
    q.T[k] += dx(L.relative() + 3 + k);
  }
  for (int v = 0; v < L.pairs; ++v)
    for (int k = 0; k < 3; ++k) {
      q.rv[v][k] += dx(L.view(v) + k);
      q.tv[v][k] += dx(L.view(v) + 3 + k);
    }
  return q;
}

}  // namespace stereoloc
