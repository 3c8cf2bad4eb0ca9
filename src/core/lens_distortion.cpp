#include "src/core/lens_distortion.h"

#include <Eigen/LU>
#include <array>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <string>

#include "src/core/error.h"

namespace stereoloc {
namespace {

// k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4, zero where D stops.
std::array<double, 12> coefficients(const cv::Mat& D) {
  std::array<double, 12> c{};
  if (D.empty()) return c;
  const size_t n = D.total();
  if (D.type() != CV_64F || (n != 4 && n != 5 && n != 8 && n != 12))
    throw Error("lens distortion: D: need 4, 5, 8 or 12 CV_64F coefficients, got " + std::to_string(n));
  const cv::Mat d = D.isContinuous() ? D : D.clone();
  for (size_t i = 0; i < n; ++i) c[i] = d.ptr<double>()[i];
  return c;
}

Eigen::Vector2d distort(const std::array<double, 12>& c, const Eigen::Vector2d& p, Eigen::Matrix2d* J_d_p) {
  const double k1 = c[0], k2 = c[1], p1 = c[2], p2 = c[3], k3 = c[4], k4 = c[5], k5 = c[6], k6 = c[7];
  const double s1 = c[8], s2 = c[9], s3 = c[10], s4 = c[11];
  const double x = p.x(), y = p.y();
  const double r2 = x * x + y * y, r4 = r2 * r2, r6 = r4 * r2;
  const double a = 1 + k1 * r2 + k2 * r4 + k3 * r6, b = 1 + k4 * r2 + k5 * r4 + k6 * r6;
  const double radial = a / b;
  const Eigen::Vector2d d(x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + s1 * r2 + s2 * r4,
                          y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + s3 * r2 + s4 * r4);
  if (J_d_p) {
    // d(radial)/d(r2) by the quotient rule; every r2 term then enters through dr2/dx = 2x, dr2/dy = 2y.
    const double da = k1 + 2 * k2 * r2 + 3 * k3 * r4, db = k4 + 2 * k5 * r2 + 3 * k6 * r4;
    const double dradial = (da * b - a * db) / (b * b);
    const double prism_x = s1 + 2 * s2 * r2, prism_y = s3 + 2 * s4 * r2;
    (*J_d_p)(0, 0) = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x + 2 * x * prism_x;
    (*J_d_p)(0, 1) = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y + 2 * y * prism_x;
    (*J_d_p)(1, 0) = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y + 2 * x * prism_y;
    (*J_d_p)(1, 1) = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x + 2 * y * prism_y;
  }
  return d;
}

std::optional<Eigen::Vector2d> undistort(const std::array<double, 12>& c, const Eigen::Vector2d& distorted) {
  constexpr double kTolerance = 1e-13;
  constexpr int kMaxIterations = 30;
  Eigen::Vector2d p = distorted;  // the ideal point of a weak lens is close to the distorted one
  for (int i = 0; i < kMaxIterations; ++i) {
    Eigen::Matrix2d J;
    const Eigen::Vector2d r = distort(c, p, &J) - distorted;
    if (!r.allFinite()) return std::nullopt;
    const double det = J.determinant();
    // Beyond where the lens folds back (det <= 0) the image turns over: a point there distorting
    // to the pixel is not the ray the pixel sees.
    if (r.norm() <= kTolerance) return det > 0.0 ? std::optional<Eigen::Vector2d>(p) : std::nullopt;
    if (!(std::abs(det) > 1e-12)) return std::nullopt;
    p -= J.inverse() * r;
  }
  return std::nullopt;
}

}  // namespace

Eigen::Vector2d distortNormalized(const cv::Mat& D, const Eigen::Vector2d& x, Eigen::Matrix2d* J_d_x) {
  return distort(coefficients(D), x, J_d_x);
}

std::optional<Eigen::Vector2d> undistortNormalized(const cv::Mat& D, const Eigen::Vector2d& distorted) {
  return undistort(coefficients(D), distorted);
}

std::vector<cv::Point2d> pixelRays(const cv::Mat& K, const cv::Mat& D, const std::vector<cv::Point2d>& pixels) {
  if (K.rows != 3 || K.cols != 3 || K.type() != CV_64F)
    throw Error("lens distortion: K: need a 3x3 CV_64F camera matrix");
  const double fx = K.at<double>(0, 0), cx = K.at<double>(0, 2);
  const double fy = K.at<double>(1, 1), cy = K.at<double>(1, 2);
  if (!(fx > 0.0) || !(fy > 0.0)) throw Error("lens distortion: K: focal lengths must be positive");
  const std::array<double, 12> c = coefficients(D);
  std::vector<cv::Point2d> rays(pixels.size());
  std::vector<cv::Point2d> left_over;
  std::vector<size_t> left_over_at;
  for (size_t i = 0; i < pixels.size(); ++i) {
    const Eigen::Vector2d distorted((pixels[i].x - cx) / fx, (pixels[i].y - cy) / fy);
    const std::optional<Eigen::Vector2d> p = undistort(c, distorted);
    if (p) {
      rays[i] = cv::Point2d(p->x(), p->y());
    } else {
      left_over.push_back(pixels[i]);
      left_over_at.push_back(i);
    }
  }
  if (!left_over.empty()) {
    std::vector<cv::Point2d> solved;
    cv::undistortPoints(left_over, solved, K, D, cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
    for (size_t j = 0; j < solved.size(); ++j) rays[left_over_at[j]] = solved[j];
  }
  return rays;
}

}  // namespace stereoloc
