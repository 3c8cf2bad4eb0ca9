#pragma once
// OpenCV's lens distortion model on normalised image coordinates (x = X/Z, y = Y/Z), its
// Jacobian, and its inverse by Newton's method: the ray of every pixel of a distorted image.
//
// D holds 4, 5, 8 or 12 coefficients in OpenCV's order k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4]]]
// (stereo_calibration.h); missing ones are zero. cv::undistortPoints inverts the same model by a
// fixed-point iteration that needs tens of steps at the corners of a strong barrel lens, each
// checked by a re-projection; Newton's method needs three to five, which makes a supersampled
// simulated image (millions of rays) several times cheaper to cast.
#include <Eigen/Core>
#include <opencv2/core/mat.hpp>
#include <optional>
#include <vector>

namespace stereoloc {

// The distorted normalised point of the ideal one x, and d(distorted)/d(x) when J_d_x is given.
Eigen::Vector2d distortNormalized(const cv::Mat& D, const Eigen::Vector2d& x, Eigen::Matrix2d* J_d_x = nullptr);

// The ideal normalised point whose distortion is `distorted`, to |residual| <= 1e-13, on the
// lens's unfolded part (det J > 0); nullopt when Newton's method does not get there (beyond the
// radius where a barrel lens folds back no ray is seen at that point).
std::optional<Eigen::Vector2d> undistortNormalized(const cv::Mat& D, const Eigen::Vector2d& distorted);

// The normalised rays of the pixels (px) of a camera with matrix K (3x3 CV_64F; as in OpenCV's
// calib3d, K(0, 1) is not used) and distortion D, what cv::undistortPoints gives to 1e-10 px; a
// pixel Newton's method does not converge on is handed to cv::undistortPoints.
std::vector<cv::Point2d> pixelRays(const cv::Mat& K, const cv::Mat& D, const std::vector<cv::Point2d>& pixels);

}  // namespace stereoloc
