#include "src/core/stereo_calibration.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace {

// A calibration file written by hand or by another tool may have R that is orthonormal only to
// the printed digits; 1e-6 accepts 7 significant digits and rejects any real scale or shear.
constexpr double kOrthoTol = 1e-6;

[[noreturn]] void fail(const std::string& where, const std::string& key, const std::string& reason) {
  throw Error(where + ": " + key + ": " + reason);
}

bool allFinite(const cv::Mat& m) { return cv::checkRange(m, true, nullptr, -1e300, 1e300); }

cv::Mat readMat(const YamlReader& in, const std::string& key) {
  if (!in.has(key)) in.fail(key, "missing");
  cv::Mat m;
  try {
    in.node()[key] >> m;
  } catch (const cv::Exception&) {
    in.fail(key, "not a matrix");
  }
  if (m.empty()) in.fail(key, "not a matrix");
  cv::Mat d;
  m.convertTo(d, CV_64F);
  return d;
}

void checkShape(const std::string& where, const std::string& key, const cv::Mat& m, int rows, int cols) {
  if (m.rows != rows || m.cols != cols)
    fail(where, key, "expected a " + std::to_string(rows) + "x" + std::to_string(cols) + " matrix, got " +
                         std::to_string(m.rows) + "x" + std::to_string(m.cols));
  if (!allFinite(m)) fail(where, key, "not finite (NaN or inf)");
}

void checkCamera(const std::string& where, const std::string& key, const cv::Mat& K) {
  checkShape(where, key, K, 3, 3);
  if (!(K.at<double>(0, 0) > 0 && K.at<double>(1, 1) > 0)) fail(where, key, "focal length must be positive");
  if (K.at<double>(1, 0) != 0 || K.at<double>(2, 0) != 0 || K.at<double>(2, 1) != 0 || K.at<double>(2, 2) != 1)
    fail(where, key, "not a camera matrix (expected [fx s cx; 0 fy cy; 0 0 1])");
}

void checkRotation(const std::string& where, const std::string& key, const cv::Mat& R) {
  checkShape(where, key, R, 3, 3);
  const double err = cv::norm(R * R.t() - cv::Mat::eye(3, 3, CV_64F), cv::NORM_INF);
  if (!(err < kOrthoTol)) fail(where, key, "not orthonormal (|R R^T - I| = " + std::to_string(err) + ")");
  if (!(cv::determinant(R) > 0)) fail(where, key, "not a rotation (determinant < 0)");
}

void checkDistortion(const std::string& where, const std::string& key, const cv::Mat& D) {
  const int n = static_cast<int>(D.total());
  if (!(D.rows == 1 || D.cols == 1) || !(n == 4 || n == 5 || n == 8 || n == 12))
    fail(where, key, "expected 4, 5, 8 or 12 coefficients, got " + std::to_string(n));
  if (!allFinite(D)) fail(where, key, "not finite (NaN or inf)");
}

// cv::stereoRectify's rectified projections: P = [f 0 cx tx; 0 f cy ty; 0 0 1 0]; what the
// checks of validate() do not compare across P1 and P2 (skew, the last row, the left camera at
// the origin) is checked here.
void checkRectifiedProjection(const std::string& where, const std::string& key, const cv::Mat& P, bool left) {
  checkShape(where, key, P, 3, 4);
  const double px = 1e-9 * std::max(1.0, std::fabs(P.at<double>(0, 0)));  // tolerance of a pixel-scaled entry
  const auto small = [](double v, double tol) { return std::fabs(v) <= tol; };
  const bool form = small(P.at<double>(0, 1), px) && small(P.at<double>(1, 0), px) && small(P.at<double>(2, 0), 1e-9) &&
                    small(P.at<double>(2, 1), 1e-9) && small(P.at<double>(2, 3), 1e-9) &&
                    small(P.at<double>(2, 2) - 1.0, 1e-9);
  if (!form) fail(where, key, "not a rectified projection (expected [f 0 cx tx; 0 f cy ty; 0 0 1 0])");
  if (left && !(small(P.at<double>(0, 3), px) && small(P.at<double>(1, 3), px)))
    fail(where, key, "the left rectified camera must be at the origin (P1(0,3) = P1(1,3) = 0)");
}

bool isIdentity(const cv::Mat& R) { return cv::norm(R - cv::Mat::eye(3, 3, CV_64F), cv::NORM_INF) < 1e-12; }

}  // namespace

void StereoCalibration::validate(const std::string& where) const {
  checkCamera(where, "M1", K1);
  checkCamera(where, "M2", K2);
  checkDistortion(where, "D1", D1);
  checkDistortion(where, "D2", D2);
  checkRotation(where, "R", R);
  checkShape(where, "T", T.rows == 1 ? T.t() : T, 3, 1);
  if (!(cv::norm(T) > 0)) fail(where, "T", "baseline must be non-zero");
  if (!(image_size.width >= 8 && image_size.height >= 8)) fail(where, "image_size", "must be at least 8 x 8 px");
  checkRotation(where, "R1", R1);
  checkRotation(where, "R2", R2);
  checkRectifiedProjection(where, "P1", P1, true);
  checkRectifiedProjection(where, "P2", P2, false);
  if (!Q.empty()) checkShape(where, "Q", Q, 4, 4);
  // The rig model has one focal length and one principal point for both rectified images and
  // the right camera on the rectified x axis: the zero-disparity form of cv::stereoRectify.
  const double f = P1.at<double>(0, 0);
  if (!(f > 0)) fail(where, "P1", "focal length must be positive");
  if (std::fabs(P1.at<double>(1, 1) - f) > 1e-9 * f || std::fabs(P2.at<double>(0, 0) - f) > 1e-9 * f ||
      std::fabs(P2.at<double>(1, 1) - f) > 1e-9 * f)
    fail(where, "P2", "rectified focal lengths differ from P1's");
  if (std::fabs(P2.at<double>(0, 2) - P1.at<double>(0, 2)) > 1e-9 || std::fabs(P2.at<double>(1, 2) - P1.at<double>(1, 2)) > 1e-9)
    fail(where, "P2", "principal point differs from P1's (rectify with CALIB_ZERO_DISPARITY)");
  if (std::fabs(P2.at<double>(1, 3)) > 1e-9 * f || std::fabs(P2.at<double>(2, 3)) > 1e-9)
    fail(where, "P2", "right camera is not on the rectified x axis (vertical stereo is not supported)");
  if (!(P2.at<double>(0, 3) < 0)) fail(where, "P2", "right camera must be to the right of the left (P2(0,3) < 0)");
}

StereoCalibration StereoCalibration::load(const std::string& path, const std::string& extrinsics_path) {
  YamlReader in(path);
  std::optional<YamlReader> ex_reader;
  if (!extrinsics_path.empty()) ex_reader.emplace(extrinsics_path);
  const YamlReader& ex = ex_reader ? *ex_reader : in;
  const std::string& ex_path = ex.path();
  StereoCalibration c;
  c.source = extrinsics_path.empty() ? path : path + " + " + extrinsics_path;
  auto camera = [&](const char* m, const char* k) {
    if (in.has(m)) return readMat(in, m);
    if (in.has(k)) return readMat(in, k);
    in.fail(m, std::string("missing (neither ") + m + " nor " + k + ")");
  };
  c.K1 = camera("M1", "K1");
  c.K2 = camera("M2", "K2");
  c.D1 = readMat(in, "D1");
  c.D2 = readMat(in, "D2");
  c.R = readMat(ex, "R");
  c.T = readMat(ex, "T");
  if (c.T.rows == 1) c.T = c.T.t();
  if (in.has("image_size")) {
    const YamlNode s = in.child("image_size");
    if (s.size() != 2) in.fail("image_size", "expected [width, height]");
    const cv::FileNode w = s.node()[0], h = s.node()[1];
    if (!w.isInt() || !h.isInt()) in.fail("image_size", "expected two integers [width, height]");
    c.image_size = cv::Size(static_cast<int>(w), static_cast<int>(h));
  } else {
    c.image_size = cv::Size(in.getInt("image_width"), in.getInt("image_height"));
  }
  // Check the raw calibration before cv::stereoRectify sees it (it asserts on bad input).
  checkCamera(path, in.has("M1") ? "M1" : "K1", c.K1);
  checkCamera(path, in.has("M2") ? "M2" : "K2", c.K2);
  checkDistortion(path, "D1", c.D1);
  checkDistortion(path, "D2", c.D2);
  checkRotation(ex_path, "R", c.R);
  checkShape(ex_path, "T", c.T, 3, 1);
  if (!(c.image_size.width >= 8 && c.image_size.height >= 8)) in.fail("image_size", "must be at least 8 x 8 px");
  const bool any = ex.has("R1") || ex.has("R2") || ex.has("P1") || ex.has("P2");
  if (any) {
    for (const char* k : {"R1", "R2", "P1", "P2"})
      if (!ex.has(k)) ex.fail(k, "missing (R1, R2, P1 and P2 come together)");
    c.R1 = readMat(ex, "R1");
    c.R2 = readMat(ex, "R2");
    c.P1 = readMat(ex, "P1");
    c.P2 = readMat(ex, "P2");
    if (ex.has("Q")) c.Q = readMat(ex, "Q");
  } else {
    c.rectify();
  }
  c.validate(ex_path);
  return c;
}

void StereoCalibration::rectify() {
  cv::Rect roi1, roi2;
  cv::stereoRectify(K1, D1, K2, D2, image_size, R, T, R1, R2, P1, P2, Q, cv::CALIB_ZERO_DISPARITY, 0.0, image_size,
                    &roi1, &roi2);
}

void StereoCalibration::save(const std::string& path) const {
  YamlWriter out;
  out.comment("stereo calibration in OpenCV's layout (cv::stereoCalibrate / cv::stereoRectify). Units: px, mm.");
  out.put("image_size", std::vector<int>{image_size.width, image_size.height});
  out.put("M1", K1);
  out.put("D1", D1);
  out.put("M2", K2);
  out.put("D2", D2);
  out.put("R", R);
  out.put("T", T);
  out.put("R1", R1);
  out.put("R2", R2);
  out.put("P1", P1);
  out.put("P2", P2);
  if (!Q.empty()) out.put("Q", Q);
  out.writeAtomically(path);
}

bool StereoCalibration::needsRemap() const {
  return cv::countNonZero(D1) > 0 || cv::countNonZero(D2) > 0 || !isIdentity(R1) || !isIdentity(R2) ||
         cv::norm(K1 - P1.colRange(0, 3), cv::NORM_INF) > 1e-12 || cv::norm(K2 - P2.colRange(0, 3), cv::NORM_INF) > 1e-12;
}

StereoCalibration idealCalibration(int width, int height, double f, double ou, double ov, double baseline_mm) {
  StereoCalibration c;
  c.K1 = (cv::Mat_<double>(3, 3) << f, 0, ou, 0, f, ov, 0, 0, 1);
  c.K2 = c.K1.clone();
  c.D1 = cv::Mat::zeros(1, 5, CV_64F);
  c.D2 = cv::Mat::zeros(1, 5, CV_64F);
  c.R = cv::Mat::eye(3, 3, CV_64F);
  c.T = (cv::Mat_<double>(3, 1) << -baseline_mm, 0, 0);
  c.image_size = cv::Size(width, height);
  c.R1 = cv::Mat::eye(3, 3, CV_64F);
  c.R2 = cv::Mat::eye(3, 3, CV_64F);
  c.P1 = (cv::Mat_<double>(3, 4) << f, 0, ou, 0, 0, f, ov, 0, 0, 0, 1, 0);
  c.P2 = (cv::Mat_<double>(3, 4) << f, 0, ou, -f * baseline_mm, 0, f, ov, 0, 0, 0, 1, 0);
  c.Q = (cv::Mat_<double>(4, 4) << 1, 0, 0, -ou, 0, 1, 0, -ov, 0, 0, 0, f, 0, 0, 1.0 / baseline_mm, 0);
  return c;
}

}  // namespace stereoloc
