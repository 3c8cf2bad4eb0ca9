#include "src/sim/calibration_target.h"

#include <opencv2/calib3d.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>

#include "src/core/error.h"
#include "src/core/lens_distortion.h"
#include "src/io/image_file.h"

namespace stereoloc {
namespace {

// The undistorted normalised ray (x/z, y/z) of every sub-pixel sample of a raw camera, row by
// row, `s` x `s` samples per pixel centred on it (a pixel covers its centre +- 0.5 px).
std::vector<cv::Point2d> sampleRays(const cv::Mat& K, const cv::Mat& D, cv::Size size, int s) {
  std::vector<cv::Point2d> pixels;
  pixels.reserve(static_cast<size_t>(size.area()) * s * s);
  for (int v = 0; v < size.height; ++v)
    for (int b = 0; b < s; ++b)
      for (int u = 0; u < size.width; ++u)
        for (int a = 0; a < s; ++a) pixels.emplace_back(u + (a + 0.5) / s - 0.5, v + (b + 0.5) / s - 0.5);
  return pixelRays(K, D, pixels);
}

// Grey level of the board (or the scene behind it) at board coordinates (x, y) mm.
double boardGrey(double x, double y, const CheckerBoard& board, const CalibrationViewOptions& o) {
  const double s = board.square_mm;
  if (x < -2 * s || y < -2 * s || x >= (board.columns + 1) * s || y >= (board.rows + 1) * s) return o.background;
  if (x < -s || y < -s || x >= board.columns * s || y >= board.rows * s) return o.light;  // the white margin
  const long i = static_cast<long>(std::floor(x / s)), j = static_cast<long>(std::floor(y / s));
  return ((i + j) % 2 == 0) ? o.dark : o.light;
}

// One camera's image of the board at X_cam = R X_board + t.
cv::Mat renderCamera(const std::vector<cv::Point2d>& rays, cv::Size size, int s, const cv::Matx33d& R,
                     const cv::Vec3d& t, const CheckerBoard& board, const CalibrationViewOptions& o,
                     std::mt19937_64& rng) {
  const cv::Vec3d n(R(0, 2), R(1, 2), R(2, 2));  // board normal in the camera frame
  const double nt = n.dot(t);
  const cv::Matx33d Rt = R.t();
  std::normal_distribution<double> noise(0.0, o.noise_sigma > 0 ? o.noise_sigma : 1.0);  // drawn only when > 0
  cv::Mat image(size, CV_8UC1);
  size_t k = 0;
  std::vector<double> row(static_cast<size_t>(size.width));
  for (int v = 0; v < size.height; ++v) {
    std::fill(row.begin(), row.end(), 0.0);
    for (int b = 0; b < s; ++b)
      for (int u = 0; u < size.width; ++u)
        for (int a = 0; a < s; ++a, ++k) {
          const cv::Vec3d d(rays[k].x, rays[k].y, 1.0);
          const double nd = n.dot(d);
          double grey = o.background;
          if (std::abs(nd) > 1e-12 && nt / nd > 0.0) {
            const cv::Vec3d p = Rt * (d * (nt / nd) - t);
            grey = boardGrey(p[0], p[1], board, o);
          }
          row[static_cast<size_t>(u)] += grey;
        }
    for (int u = 0; u < size.width; ++u) {
      const double g = row[static_cast<size_t>(u)] / (s * s) + (o.noise_sigma > 0 ? noise(rng) : 0.0);
      image.at<uchar>(v, u) = cv::saturate_cast<uchar>(std::lround(g));
    }
  }
  return image;
}

cv::Matx33d rotation(double rx, double ry, double rz) {
  cv::Mat R;
  cv::Rodrigues(cv::Vec3d(rx, 0, 0), R);
  cv::Mat Ry, Rz;
  cv::Rodrigues(cv::Vec3d(0, ry, 0), Ry);
  cv::Rodrigues(cv::Vec3d(0, 0, rz), Rz);
  return cv::Matx33d(cv::Mat(R * Ry * Rz));
}

// True when the board with its margin projects inside the image (with a border) in front of
// the camera.
bool boardInside(const CheckerBoard& board, const cv::Matx33d& R, const cv::Vec3d& t, const cv::Mat& K,
                 const cv::Mat& D, cv::Size size) {
  const double s = board.square_mm;
  std::vector<cv::Point3d> outline;
  const int n = 8;  // points per edge: a distorted edge bows between its ends
  const double x0 = -2 * s, x1 = (board.columns + 1) * s, y0 = -2 * s, y1 = (board.rows + 1) * s;
  for (int i = 0; i <= n; ++i) {
    const double f = static_cast<double>(i) / n;
    outline.emplace_back(x0 + f * (x1 - x0), y0, 0.0);
    outline.emplace_back(x0 + f * (x1 - x0), y1, 0.0);
    outline.emplace_back(x0, y0 + f * (y1 - y0), 0.0);
    outline.emplace_back(x1, y0 + f * (y1 - y0), 0.0);
  }
  for (const auto& p : outline) {
    const cv::Vec3d c = R * cv::Vec3d(p.x, p.y, p.z) + t;
    if (c[2] < 20.0) return false;
  }
  cv::Mat rvec;
  cv::Rodrigues(cv::Mat(R), rvec);
  std::vector<cv::Point2d> image;
  cv::projectPoints(outline, rvec, cv::Mat(t), K, D, image);
  const double border = 3.0;
  for (const auto& q : image)
    if (!(q.x >= border && q.y >= border && q.x <= size.width - 1 - border && q.y <= size.height - 1 - border))
      return false;
  return true;
}

}  // namespace

std::vector<CalibrationView> renderCalibrationViews(const StereoCalibration& truth, const CheckerBoard& board,
                                                    const CalibrationViewOptions& o, uint64_t seed) {
  board.validate("calibration board");
  truth.validate("calibration views");
  if (o.views < 1) throw Error("calibration views: views: must be at least 1, got " + std::to_string(o.views));
  if (!(o.min_distance_mm > 0.0) || !(o.max_distance_mm >= o.min_distance_mm))
    throw Error("calibration views: min_distance_mm, max_distance_mm: need 0 < min <= max");
  if (!(o.max_tilt_rad >= 0.0 && o.max_tilt_rad < 1.4) || !(o.max_spin_rad >= 0.0 && o.max_spin_rad <= M_PI))
    throw Error("calibration views: max_tilt_rad, max_spin_rad: out of range");
  if (o.supersampling < 1 || o.supersampling > 16)
    throw Error("calibration views: supersampling: must be 1 to 16, got " + std::to_string(o.supersampling));
  if (!(o.noise_sigma >= 0.0)) throw Error("calibration views: noise_sigma: must be >= 0");
  const cv::Size size = truth.image_size;
  const int s = o.supersampling;
  const std::vector<cv::Point2d> rays_left = sampleRays(truth.K1, truth.D1, size, s);
  const std::vector<cv::Point2d> rays_right = sampleRays(truth.K2, truth.D2, size, s);
  const cv::Matx33d R_lr(truth.R);
  const cv::Vec3d T_lr(truth.T.at<double>(0), truth.T.at<double>(1), truth.T.at<double>(2));
  const double fx = truth.K1.at<double>(0, 0), fy = truth.K1.at<double>(1, 1);
  const double cx = truth.K1.at<double>(0, 2), cy = truth.K1.at<double>(1, 2);
  const cv::Vec3d centre((board.columns - 1) * board.square_mm / 2, (board.rows - 1) * board.square_mm / 2, 0.0);

  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::vector<CalibrationView> views;
  for (int v = 0; v < o.views; ++v) {
    bool placed = false;
    for (int attempt = 0; attempt < o.max_attempts_per_view && !placed; ++attempt) {
      const double z = o.min_distance_mm + unit(rng) * (o.max_distance_mm - o.min_distance_mm);
      // The board's centre anywhere in the left image (a pose that puts part of the board outside
      // either image is drawn again): views near the edges and corners, where the lens bends most.
      const double u = (unit(rng) - 0.5) * size.width + cx, w = (unit(rng) - 0.5) * size.height + cy;
      const cv::Vec3d c(z * (u - cx) / fx, z * (w - cy) / fy, z);
      const cv::Matx33d R = rotation((2 * unit(rng) - 1) * o.max_tilt_rad, (2 * unit(rng) - 1) * o.max_tilt_rad,
                                     (2 * unit(rng) - 1) * o.max_spin_rad);
      const cv::Vec3d t = c - R * centre;
      const cv::Matx33d R_right = R_lr * R;
      const cv::Vec3d t_right = R_lr * t + T_lr;
      if (!boardInside(board, R, t, truth.K1, truth.D1, size) ||
          !boardInside(board, R_right, t_right, truth.K2, truth.D2, size))
        continue;
      CalibrationView view;
      view.R = R;
      view.t = t;
      view.left = renderCamera(rays_left, size, s, R, t, board, o, rng);
      view.right = renderCamera(rays_right, size, s, R_right, t_right, board, o, rng);
      views.push_back(std::move(view));
      placed = true;
    }
    if (!placed)
      throw Error("calibration views: the board (" + std::to_string(board.columns) + "x" + std::to_string(board.rows) +
                  " corners, " + std::to_string(board.square_mm) + " mm squares) did not fit both images in " +
                  std::to_string(o.max_attempts_per_view) + " poses; use a smaller board or a larger distance");
  }
  return views;
}

void writeCalibrationViews(const std::string& dir, const StereoCalibration& truth, const CheckerBoard& board,
                           const CalibrationViewOptions& options, uint64_t seed) {
  const std::vector<CalibrationView> views = renderCalibrationViews(truth, board, options, seed);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw Error(dir + ": cannot create the folder: " + ec.message());
  for (size_t i = 0; i < views.size(); ++i) {
    char name[32];
    for (int c = 0; c < 2; ++c) {
      std::snprintf(name, sizeof name, "%s_%03zu.png", c == 0 ? "left" : "right", i);
      writePngFile((std::filesystem::path(dir) / name).string(), c == 0 ? views[i].left : views[i].right);
    }
  }
  truth.save((std::filesystem::path(dir) / "true_calibration.yml").string());
}

}  // namespace stereoloc
