#include "src/core/lens_distortion.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <vector>

#include "src/core/error.h"
#include "src/core/numeric_diff.h"

namespace stereoloc {
namespace {

cv::Mat coefficients(std::vector<double> d) { return cv::Mat(d, true).reshape(1, 1); }

// The plain 4-coefficient lens, a strong barrel lens (a 640 x 480 image's corner at f = 400 px
// sees a ray 170 px further out), a rational lens, and every term of the 12-coefficient model.
std::vector<cv::Mat> lenses() {
  return {coefficients({-0.05, 0.01, 0.002, -0.001}),
          coefficients({-0.25, 0.05, 0.001, -0.002, 0.0}),
          coefficients({0.4, -0.2, 0.001, 0.002, 0.05, 0.6, -0.1, 0.03}),
          coefficients({-0.1, 0.02, 0.003, -0.002, 0.004, 0.05, 0.01, 0.002, 0.004, -0.002, -0.003, 0.001})};
}

cv::Mat camera() { return (cv::Mat_<double>(3, 3) << 400, 0, 322, 0, 405, 236, 0, 0, 1); }

TEST(LensDistortion, IsOpenCvsModel) {
  const cv::Mat K = camera();
  for (const cv::Mat& D : lenses()) {
    std::vector<cv::Point3d> points;
    for (double x = -0.8; x <= 0.8; x += 0.2)
      for (double y = -0.6; y <= 0.6; y += 0.2) points.emplace_back(x, y, 1.0);
    std::vector<cv::Point2d> projected;
    cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, D, projected);
    for (size_t i = 0; i < points.size(); ++i) {
      const Eigen::Vector2d d = distortNormalized(D, Eigen::Vector2d(points[i].x, points[i].y));
      EXPECT_NEAR(400 * d.x() + 322, projected[i].x, 1e-9) << D;
      EXPECT_NEAR(405 * d.y() + 236, projected[i].y, 1e-9) << D;
    }
  }
}

TEST(LensDistortion, JacobianMatchesCentralDifferences) {
  for (const cv::Mat& D : lenses())
    for (const Eigen::Vector2d& x :
         {Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(0.7, -0.5), Eigen::Vector2d(-0.3, 0.45)}) {
      Eigen::Matrix2d J_d_x;
      distortNormalized(D, x, &J_d_x);
      const Eigen::Matrix2d numeric =
          numericJacobian<2, 2>([&](const Eigen::Vector2d& p) { return distortNormalized(D, p); }, x);
      EXPECT_LT(relativeJacobianError(J_d_x, numeric), 1e-8) << D << "\nat " << x.transpose();
    }
}

TEST(LensDistortion, UndistortingInvertsTheModel) {
  for (const cv::Mat& D : lenses())
    for (double x = -0.8; x <= 0.8; x += 0.1)
      for (double y = -0.6; y <= 0.6; y += 0.1) {
        const Eigen::Vector2d ideal(x, y);
        const std::optional<Eigen::Vector2d> back = undistortNormalized(D, distortNormalized(D, ideal));
        ASSERT_TRUE(back) << D << " at " << ideal.transpose();
        EXPECT_LT((*back - ideal).norm(), 1e-12) << D;
      }
}

// Every pixel of an image, with a quarter of the supersampled grid: the rays cv::undistortPoints
// gives when iterated to convergence.
TEST(LensDistortion, PixelRaysAreOpenCvsUndistortedPoints) {
  const cv::Mat K = camera();
  std::vector<cv::Point2d> pixels;
  for (double v = -0.5; v <= 479.5; v += 1.75)
    for (double u = -0.5; u <= 639.5; u += 1.75) pixels.emplace_back(u, v);
  for (const cv::Mat& D : lenses()) {
    std::vector<cv::Point2d> expected;
    cv::undistortPoints(pixels, expected, K, D, cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 1000, 1e-13));
    const std::vector<cv::Point2d> rays = pixelRays(K, D, pixels);
    ASSERT_EQ(rays.size(), pixels.size());
    double worst_px = 0.0;
    for (size_t i = 0; i < rays.size(); ++i)
      worst_px = std::max(worst_px, 400.0 * cv::norm(rays[i] - expected[i]));
    EXPECT_LT(worst_px, 1e-9) << D;
  }
}

// Beyond where a barrel lens folds back there is no ray: Newton's method says so rather than
// returning the point behind the fold (x = -1.52 here) that also distorts to the pixel.
TEST(LensDistortion, NoRayWhereTheLensFoldsBack) {
  const cv::Mat D = coefficients({-0.6, 0.0, 0.0, 0.0});
  // r_d = r (1 - 0.6 r^2) peaks at r = 1 / sqrt(1.8), r_d = 0.497: nothing distorts to 0.6.
  EXPECT_FALSE(undistortNormalized(D, Eigen::Vector2d(0.6, 0.0)));
  const std::optional<Eigen::Vector2d> inside = undistortNormalized(D, Eigen::Vector2d(0.3, 0.2));
  ASSERT_TRUE(inside);
  EXPECT_LT((distortNormalized(D, *inside) - Eigen::Vector2d(0.3, 0.2)).norm(), 1e-13);
}

TEST(LensDistortion, BadCoefficientsAreAnError) {
  EXPECT_THROW(distortNormalized(coefficients({0.1, 0.2, 0.3}), Eigen::Vector2d(0.1, 0.1)), Error);
  EXPECT_THROW(pixelRays(cv::Mat::eye(2, 2, CV_64F), coefficients({0.1, 0, 0, 0}), {{1.0, 2.0}}), Error);
  cv::Mat K = camera();
  K.at<double>(0, 0) = 0.0;
  EXPECT_THROW(pixelRays(K, coefficients({0.1, 0, 0, 0}), {{1.0, 2.0}}), Error);
  // No coefficients: the pinhole.
  const std::vector<cv::Point2d> rays = pixelRays(camera(), cv::Mat(), {{722.0, 641.0}});
  EXPECT_NEAR(rays[0].x, 1.0, 1e-15);
  EXPECT_NEAR(rays[0].y, 1.0, 1e-15);
}

}  // namespace
}  // namespace stereoloc
