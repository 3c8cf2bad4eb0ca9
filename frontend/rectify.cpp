#include "frontend/rectify.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "src/core/error.h"

namespace stereoloc::frontend {
namespace {

// OpenCV's fixed-point maps hold positions in 1/2^INTER_BITS px.
constexpr double kMapStep = 1.0 / (1 << cv::INTER_BITS);

double bilinear(const cv::Mat& m, double u, double v) {
  const double uc = std::clamp(u, 0.0, m.cols - 1.0), vc = std::clamp(v, 0.0, m.rows - 1.0);
  const int u0 = std::min(static_cast<int>(uc), m.cols - 2), v0 = std::min(static_cast<int>(vc), m.rows - 2);
  const double a = uc - u0, b = vc - v0;
  const float* r0 = m.ptr<float>(v0);
  const float* r1 = m.ptr<float>(v0 + 1);
  return (1 - b) * ((1 - a) * r0[u0] + a * r0[u0 + 1]) + b * ((1 - a) * r1[u0] + a * r1[u0 + 1]);
}

// s of rectify.h: the RMS singular value of (d raw / d rect)^-1, from central differences of
// the float maps (one-sided at the border).
cv::Mat scaleMap(const cv::Mat& mx, const cv::Mat& my) {
  cv::Mat s(mx.size(), CV_32FC1);
  for (int v = 0; v < mx.rows; ++v) {
    const int v0 = std::max(v - 1, 0), v1 = std::min(v + 1, mx.rows - 1);
    for (int u = 0; u < mx.cols; ++u) {
      const int u0 = std::max(u - 1, 0), u1 = std::min(u + 1, mx.cols - 1);
      const double du = u1 - u0, dv = v1 - v0;
      const double a = (mx.at<float>(v, u1) - mx.at<float>(v, u0)) / du;  // d x_raw / d u
      const double b = (mx.at<float>(v1, u) - mx.at<float>(v0, u)) / dv;  // d x_raw / d v
      const double c = (my.at<float>(v, u1) - my.at<float>(v, u0)) / du;  // d y_raw / d u
      const double d = (my.at<float>(v1, u) - my.at<float>(v0, u)) / dv;  // d y_raw / d v
      const double det = a * d - b * c;
      // The inverse's Frobenius norm is the forward one's divided by |det| (2x2).
      const double frob2 = (a * a + b * b + c * c + d * d) / (det * det);
      s.at<float>(v, u) = std::isfinite(frob2) && det != 0 ? static_cast<float>(std::sqrt(0.5 * frob2)) : 1.0f;
    }
  }
  return s;
}

}  // namespace

Rectifier::Rectifier(const StereoCalibration& c) : size_(c.image_size), source_(c.source) {
  c.validate(c.source.empty() ? "calibration" : c.source);
  const cv::Mat* K[2] = {&c.K1, &c.K2};
  const cv::Mat* D[2] = {&c.D1, &c.D2};
  const cv::Mat* Rr[2] = {&c.R1, &c.R2};
  const cv::Mat* P[2] = {&c.P1, &c.P2};
  for (int i = 0; i < 2; ++i) {
    cv::initUndistortRectifyMap(*K[i], *D[i], *Rr[i], *P[i], size_, CV_32FC1, map_x_[i], map_y_[i]);
    cv::convertMaps(map_x_[i], map_y_[i], map_fixed_[i], map_frac_[i], CV_16SC2, false);
    scale_[i] = scaleMap(map_x_[i], map_y_[i]);
  }
}

void Rectifier::rectify(const cv::Mat& left_raw, const cv::Mat& right_raw) {
  for (const cv::Mat* m : {&left_raw, &right_raw})
    if (m->size() != size_)
      throw Error((m == &left_raw ? "left" : "right") + std::string(" image: size ") + std::to_string(m->cols) + "x" +
                  std::to_string(m->rows) + " differs from the calibration's image_size " + std::to_string(size_.width) +
                  "x" + std::to_string(size_.height) + (source_.empty() ? "" : " (" + source_ + ")"));
  // The two cameras are independent tasks of OpenCV's thread pool (OpenCV runs a nested
  // parallel_for_, the remap's own, serially), so with two threads the pair costs one remap of
  // wall time; each output depends only on its input, whatever the thread count. (One remap of a
  // 320x240 image is a single stripe of OpenCV's own splitting, so without this the pair runs
  // serially.) Replicated borders: a constant border would draw a strong straight edge for the
  // line stages.
  const cv::Mat* in[2] = {&left_raw, &right_raw};
  cv::Mat* out[2] = {&left_.m, &right_.m};
  for (int i = 0; i < 2; ++i) out[i]->create(size_, in[i]->type());  // allocation stays on the caller's thread
  cv::parallel_for_(
      cv::Range(0, 2),
      [&](const cv::Range& r) {
        for (int i = r.start; i < r.end; ++i)
          cv::remap(*in[i], *out[i], map_fixed_[i], map_frac_[i], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      },
      2);
}

double Rectifier::effectiveSigma(int camera, double u, double v, double sigma_px) const {
  const double s = bilinear(scale_[camera != 0], u, v);
  return std::sqrt(s * s * sigma_px * sigma_px + kMapStep * kMapStep / 12.0);
}

cv::Point2d Rectifier::rawFromRectified(int camera, double u, double v) const {
  const int i = camera != 0;
  return {bilinear(map_x_[i], u, v), bilinear(map_y_[i], u, v)};
}

}  // namespace stereoloc::frontend
