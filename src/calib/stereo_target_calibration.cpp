#include "src/calib/stereo_target_calibration.h"

#include <Eigen/Dense>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "src/calib/stereo_target_problem.h"
#include "src/core/error.h"
#include "src/core/yaml_util.h"

namespace stereoloc {
namespace {

cv::Mat grey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat g;
  cv::cvtColor(image, g, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  return g;
}

cv::Mat firstCoefficients(const cv::Mat& D, int n) {
  cv::Mat out = cv::Mat::zeros(1, n, CV_64F);
  const cv::Mat flat = D.reshape(1, 1);
  for (int i = 0; i < n && i < flat.cols; ++i) out.at<double>(0, i) = flat.at<double>(0, i);
  return out;
}

double median(std::vector<double> x) {
  std::nth_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(x.size() / 2), x.end());
  return x[x.size() / 2];
}

// The pairs whose images both show the whole board, their corners in the same order; every
// pair's outcome appended to `outcome`.
struct Detections {
  std::vector<cv::Point3f> object;
  std::vector<std::vector<cv::Point2f>> left, right;
  std::vector<size_t> index;  // of each used pair in the pairs handed in
};

Detections detectPairs(const std::vector<TargetPair>& pairs, const CheckerBoard& board,
                       std::vector<TargetPairResult>& outcome) {
  Detections out;
  out.object = board.corners();
  const cv::Size size = pairs.front().left.size();
  for (size_t i = 0; i < pairs.size(); ++i) {
    const TargetPair& pair = pairs[i];
    TargetPairResult r;
    r.name = pair.name;
    if (pair.left.empty() || pair.right.empty()) throw Error(pair.name + ": an image of the pair is empty");
    if (pair.left.depth() != CV_8U || pair.right.depth() != CV_8U) throw Error(pair.name + ": images must be 8-bit");
    const auto text = [](const cv::Size& s) { return std::to_string(s.width) + "x" + std::to_string(s.height); };
    if (pair.left.size() != pair.right.size())
      throw Error(pair.name + ": the left image is " + text(pair.left.size()) + ", the right " +
                  text(pair.right.size()));
    if (pair.left.size() != size)
      throw Error(pair.name + ": image size " + text(pair.left.size()) + " differs from " + text(size) + " of " +
                  pairs.front().name);
    std::vector<cv::Point2f> l = detectBoardCorners(pair.left, board), rr = detectBoardCorners(pair.right, board);
    if (l.empty() || rr.empty()) {
      r.reason = std::string("board not found in the ") + (l.empty() && rr.empty() ? "left and right images"
                                                           : l.empty()            ? "left image"
                                                                                  : "right image");
      outcome.push_back(r);
      continue;
    }
    orderLike(l, rr);
    r.used = true;
    r.left_corners = l;
    r.right_corners = rr;
    outcome.push_back(r);
    out.left.push_back(std::move(l));
    out.right.push_back(std::move(rr));
    out.index.push_back(i);
  }
  return out;
}

int openCvFlags(const TargetCalibrationOptions& options) {
  int flags = 0;
  if (options.distortion_coefficients == 4) flags |= cv::CALIB_FIX_K3;
  if (options.distortion_coefficients == 8) flags |= cv::CALIB_RATIONAL_MODEL;
  if (options.same_focal_axes) flags |= cv::CALIB_FIX_ASPECT_RATIO;
  return flags;
}

const cv::TermCriteria kOpenCvCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12);

// One camera calibrated alone (cv::calibrateCamera) and the board's pose in each of its views.
struct MonocularCalibration {
  cv::Mat K, D;
  std::vector<cv::Mat> rvecs, tvecs;
};

MonocularCalibration calibrateCamera(const std::vector<cv::Point3f>& object,
                                     const std::vector<std::vector<cv::Point2f>>& corners, cv::Size size,
                                     const TargetCalibrationOptions& options) {
  MonocularCalibration m;
  m.K = cv::Mat::eye(3, 3, CV_64F);
  m.D = cv::Mat::zeros(1, options.distortion_coefficients == 8 ? 8 : 5, CV_64F);
  const std::vector<std::vector<cv::Point3f>> objects(corners.size(), object);
  cv::calibrateCamera(objects, corners, size, m.K, m.D, m.rvecs, m.tvecs, openCvFlags(options), kOpenCvCriteria);
  return m;
}

// Each pair's stereo consistency, judged apart from the others: the right camera's pose
// against the left from that pair's two monocular board poses, R_v = R_r R_l^T and
// T_v = t_r - R_v t_l; their median over the pairs (per component) the head's geometry; and
// the RMS distance (px) of the pair's right corners from where the board's pose in the left
// image and that geometry put them. A pair that does not fit the others spoils every joint
// fit, but not the pairs' median.
std::vector<double> stereoConsistencyPx(const MonocularCalibration& left, const MonocularCalibration& right,
                                        const Detections& found) {
  const size_t V = found.left.size();
  std::vector<cv::Vec3d> w(V), T(V);
  for (size_t v = 0; v < V; ++v) {
    cv::Mat Rl, Rr;
    cv::Rodrigues(left.rvecs[v], Rl);
    cv::Rodrigues(right.rvecs[v], Rr);
    const cv::Mat R = Rr * Rl.t();
    const cv::Mat t = right.tvecs[v] - R * left.tvecs[v];
    cv::Mat rv;
    cv::Rodrigues(R, rv);
    for (int k = 0; k < 3; ++k) {
      w[v][k] = rv.at<double>(k);
      T[v][k] = t.at<double>(k);
    }
  }
  cv::Vec3d w_med, T_med;
  for (int k = 0; k < 3; ++k) {
    std::vector<double> wk, Tk;
    for (size_t v = 0; v < V; ++v) {
      wk.push_back(w[v][k]);
      Tk.push_back(T[v][k]);
    }
    w_med[k] = median(wk);
    T_med[k] = median(Tk);
  }
  const std::vector<cv::Point3f> object = found.object;
  std::vector<double> rms;
  for (size_t v = 0; v < V; ++v) {
    cv::Mat r_right, t_right;
    cv::composeRT(left.rvecs[v], left.tvecs[v], cv::Mat(w_med), cv::Mat(T_med), r_right, t_right);
    std::vector<cv::Point2f> predicted;
    cv::projectPoints(object, r_right, t_right, right.K, right.D, predicted);
    double sum = 0.0;
    for (size_t i = 0; i < predicted.size(); ++i) sum += std::pow(cv::norm(predicted[i] - found.right[v][i]), 2);
    rms.push_back(std::sqrt(sum / static_cast<double>(predicted.size())));
  }
  return rms;
}

// Leaves out the pairs that do not fit the others (a board the detector misread, a blurred
// pair, or one whose cameras exposed apart while the board moved): those whose stereo
// consistency (stereoConsistencyPx) is over outlier_factor times the pairs' median and
// kOutlierFloorPx, the worst first, while more than min_views remain; each one's outcome says
// why. Returns the pairs kept. `mono`'s board poses are those of the pairs handed in.
int leaveOutInconsistentPairs(const MonocularCalibration mono[2], const TargetCalibrationOptions& options,
                              Detections& found, std::vector<TargetPairResult>& outcome) {
  const std::vector<double> rms = stereoConsistencyPx(mono[0], mono[1], found);
  const double typical = median(rms);
  const double limit = std::max(options.outlier_factor * typical, TargetCalibrationOptions::kOutlierFloorPx);
  std::vector<size_t> order(rms.size());
  for (size_t v = 0; v < order.size(); ++v) order[v] = v;
  std::stable_sort(order.begin(), order.end(), [&](size_t i, size_t j) { return rms[i] > rms[j]; });
  int kept = static_cast<int>(rms.size());
  std::vector<bool> drop(rms.size(), false);
  for (size_t k = 0; k < order.size() && rms[order[k]] > limit && kept > options.min_views; ++k) {
    drop[order[k]] = true;
    --kept;
    TargetPairResult& out = outcome[found.index[order[k]]];
    out.used = false;
    out.rms_px = rms[order[k]];
    char why[200];
    std::snprintf(why, sizeof why,
                  "does not fit the others: its right corners lie %.2f px RMS from where its left image and the "
                  "pairs' median stereo geometry put them, over %.1f times the pairs' median (%.2f px)",
                  rms[order[k]], options.outlier_factor, typical);
    out.reason = why;
  }
  for (size_t v = drop.size(); v-- > 0;)
    if (drop[v]) {
      found.left.erase(found.left.begin() + static_cast<std::ptrdiff_t>(v));
      found.right.erase(found.right.begin() + static_cast<std::ptrdiff_t>(v));
      found.index.erase(found.index.begin() + static_cast<std::ptrdiff_t>(v));
    }
  return kept;
}

// OpenCV's estimate: both cameras together (cv::stereoCalibrate) from each one's own; the board
// poses the left camera's.
StereoTargetParameters openCvEstimate(const Detections& found, const MonocularCalibration mono[2], cv::Size size,
                                      const TargetCalibrationOptions& options) {
  const int nd = options.distortion_coefficients;
  const std::vector<std::vector<cv::Point3f>> objects(found.left.size(), found.object);
  StereoTargetParameters p;
  for (int c = 0; c < 2; ++c) {
    p.K[c] = mono[c].K.clone();
    p.D[c] = mono[c].D.clone();
  }
  cv::Mat R, T, E, F;
  cv::stereoCalibrate(objects, found.left, found.right, p.K[0], p.D[0], p.K[1], p.D[1], size, R, T, E, F,
                      openCvFlags(options) | cv::CALIB_USE_INTRINSIC_GUESS, kOpenCvCriteria);
  for (int c = 0; c < 2; ++c) p.D[c] = firstCoefficients(p.D[c], nd);
  cv::Mat rm;
  cv::Rodrigues(R, rm);
  p.r = cv::Vec3d(rm.at<double>(0), rm.at<double>(1), rm.at<double>(2));
  p.T = cv::Vec3d(T.at<double>(0), T.at<double>(1), T.at<double>(2));
  for (size_t v = 0; v < objects.size(); ++v) {
    cv::Mat rv, tv;
    cv::solvePnP(objects[v], found.left[v], p.K[0], p.D[0], rv, tv);
    p.rv.emplace_back(rv.at<double>(0), rv.at<double>(1), rv.at<double>(2));
    p.tv.emplace_back(tv.at<double>(0), tv.at<double>(1), tv.at<double>(2));
  }
  return p;
}

struct JointSolution {
  double cost = 0.0;  // sum of squared residuals, px^2
  Eigen::MatrixXd H;  // J^T J at the solution
};

// The joint least squares of both images of every pair over all parameters at once: damped
// Gauss-Newton steps from OpenCV's solution (whose board poses are the left camera's alone), so
// that the covariance is taken at the joint optimum. `p` is moved to the solution.
JointSolution refineJointly(StereoTargetParameters& p, const StereoTargetLayout& L, const std::vector<cv::Point3d>& object,
                            const Detections& found) {
  const int n = L.size();
  auto normalEquations = [&](const StereoTargetParameters& q, Eigen::MatrixXd* H, Eigen::VectorXd* g) {
    double cost = 0.0;
    if (H) H->setZero(n, n);
    if (g) g->setZero(n);
    Eigen::VectorXd e;
    Eigen::MatrixXd J;
    for (int v = 0; v < L.pairs; ++v) {
      stereoTargetResiduals(q, L, v, object, found.left[static_cast<size_t>(v)], found.right[static_cast<size_t>(v)], e,
                            H ? &J : nullptr);
      cost += e.squaredNorm();
      if (H) {
        H->noalias() += J.transpose() * J;
        g->noalias() += J.transpose() * e;
      }
    }
    return cost;
  };
  JointSolution s;
  Eigen::VectorXd g;
  s.cost = normalEquations(p, &s.H, &g);
  double lambda = 1e-6;
  for (int it = 0; it < 20; ++it) {
    Eigen::MatrixXd A = s.H;
    A.diagonal() += lambda * s.H.diagonal().cwiseMax(1e-12);
    const Eigen::VectorXd dx = A.ldlt().solve(-g);
    const StereoTargetParameters q = p.plus(L, dx);
    const double c = normalEquations(q, nullptr, nullptr);
    if (std::isfinite(c) && c < s.cost) {
      const bool done = s.cost - c < 1e-12 * s.cost;
      p = q;
      s.cost = normalEquations(p, &s.H, &g);
      lambda = std::max(lambda / 10, 1e-12);
      if (done) break;
    } else {
      lambda *= 10;
      if (lambda > 1e6) break;
    }
  }
  return s;
}

// Sigma = s^2 (J^T J)^-1, s^2 the residuals' variance per coordinate.
Eigen::MatrixXd covarianceOf(const JointSolution& joint, const StereoTargetLayout& L, size_t corners) {
  const int n = L.size();
  const int m = 4 * static_cast<int>(corners) * L.pairs;
  if (m <= n) throw Error("calibrate: too few corners for the parameters; take more pairs");
  const double s2 = joint.cost / (m - n);
  Eigen::LDLT<Eigen::MatrixXd> ldlt(joint.H);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive() || ldlt.vectorD().minCoeff() <= 0.0)
    throw Error("calibrate: the pairs do not constrain the calibration (the board at too few attitudes); take "
                "views with the board turned and tilted");
  const Eigen::MatrixXd Sigma = s2 * ldlt.solve(Eigen::MatrixXd::Identity(n, n));
  if (!Sigma.allFinite()) throw Error("calibrate: the calibration's covariance is not finite; take more varied views");
  return Sigma;
}

// Where a ray lands at the image's corners relative to one at the principal point: the largest
// standard deviation of the four, J_pixel_intrinsics Sigma J^T.
double imageCornerSigma(const StereoTargetParameters& p, const StereoTargetLayout& L, int c, const Eigen::MatrixXd& Sigma,
                        cv::Size size) {
  const int ni = L.intrinsics();
  const Eigen::MatrixXd block = Sigma.block(L.camera(c), L.camera(c), ni, ni);
  const std::vector<cv::Point2d> pixels = {{0.0, 0.0},
                                           {size.width - 1.0, 0.0},
                                           {0.0, size.height - 1.0},
                                           {size.width - 1.0, size.height - 1.0},
                                           {p.K[c].at<double>(0, 2), p.K[c].at<double>(1, 2)}};
  std::vector<cv::Point2d> rays;
  cv::undistortPoints(pixels, rays, p.K[c], p.D[c], cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
  std::vector<cv::Point3d> X;
  for (const auto& q : rays) X.emplace_back(q.x, q.y, 1.0);
  std::vector<cv::Point2d> back;
  cv::Mat jac;
  cv::projectPoints(X, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), p.K[c], p.D[c], back, jac);
  const Eigen::MatrixXd A = intrinsicColumns(jac, L);  // 10 x ni; rows 8-9 the principal point's
  double worst = 0.0;
  for (int i = 0; i < 4; ++i) {
    const Eigen::MatrixXd relative = A.middleRows(2 * i, 2) - A.middleRows(8, 2);
    const Eigen::Matrix2d cov = relative * block * relative.transpose();
    worst = std::max(worst, std::sqrt(std::max(cov(0, 0), cov(1, 1))));
  }
  return worst;
}

// The rectified head's standard deviations (TargetCalibrationSigmas' comment gives each).
void headSigmas(const StereoTargetParameters& p, const StereoTargetLayout& L, const Eigen::MatrixXd& Sigma, cv::Size size,
                TargetCalibrationSigmas& S) {
  const int n = L.size();
  auto sdOf = [&](const Eigen::VectorXd& a) { return std::sqrt(std::max(a.dot(Sigma * a), 0.0)); };
  const double fx1 = p.K[0].at<double>(0, 0), fx2 = p.K[1].at<double>(0, 0);
  const double b = cv::norm(p.T);
  Eigen::VectorXd a = Eigen::VectorXd::Zero(n);
  for (int k = 0; k < 3; ++k) a(L.relative() + 3 + k) = p.T[k] / b;
  S.baseline_mm = sdOf(a);
  S.baseline_scale = S.baseline_mm / b;
  a.setZero();
  a(L.focalX(0)) = 1.0 / fx1;
  S.focal_scale = sdOf(a);
  a.setZero();
  a(L.focalX(1)) = 1.0 / fx1;
  a(L.focalX(0)) = -fx2 / (fx1 * fx1);
  S.focal_ratio = sdOf(a);
  // A far point on the left optical axis: u_l = cx1, and X_right ~ (I + [w]x) X_left gives
  // u_r = cx2 + fx2 w_y, so the disparity at infinity is cx1 - cx2 - fx2 w_y.
  a.setZero();
  a(L.principalX(0)) = 1.0;
  a(L.principalX(1)) = -1.0;
  a(L.relative() + 1) = -fx2;
  S.disparity_offset_px = sdOf(a);

  // The rectified frame's turn: R1 e_z against (r, T), central differences.
  StereoCalibration probe;
  probe.K1 = p.K[0];
  probe.D1 = p.D[0];
  probe.K2 = p.K[1];
  probe.D2 = p.D[1];
  probe.image_size = size;
  auto axis = [&](const cv::Vec3d& r, const cv::Vec3d& t) {
    cv::Rodrigues(cv::Mat(r), probe.R);
    probe.T = cv::Mat(t).clone();
    probe.rectify();
    return cv::Vec3d(probe.R1.at<double>(0, 2), probe.R1.at<double>(1, 2), probe.R1.at<double>(2, 2));
  };
  Eigen::VectorXd yaw = Eigen::VectorXd::Zero(n), pitch = Eigen::VectorXd::Zero(n);
  for (int k = 0; k < 6; ++k) {
    const double h = k < 3 ? 1e-6 : 1e-5;
    cv::Vec3d r_plus = p.r, r_minus = p.r, t_plus = p.T, t_minus = p.T;
    (k < 3 ? r_plus[k] : t_plus[k - 3]) += h;
    (k < 3 ? r_minus[k] : t_minus[k - 3]) -= h;
    const cv::Vec3d d = (axis(r_plus, t_plus) - axis(r_minus, t_minus)) / (2 * h);
    yaw(L.relative() + k) = d[0];
    pitch(L.relative() + k) = d[1];
  }
  axis(p.r, p.T);
  S.column_offset_px = probe.rectifiedFocal() * sdOf(yaw);
  S.tilt_rad = sdOf(pitch);
}

// Each pair's reprojection RMS over both images, px.
std::vector<double> pairRms(const StereoTargetParameters& p, const StereoTargetLayout& L,
                            const std::vector<cv::Point3d>& object, const Detections& found) {
  std::vector<double> rms;
  for (int v = 0; v < L.pairs; ++v) {
    Eigen::VectorXd e;
    stereoTargetResiduals(p, L, v, object, found.left[static_cast<size_t>(v)], found.right[static_cast<size_t>(v)], e,
                          nullptr);
    rms.push_back(std::sqrt(e.squaredNorm() / static_cast<double>(e.size() / 2)));
  }
  return rms;
}

// Every standard deviation `result.sigmas` states, from one covariance of the parameters.
TargetCalibrationSigmas sigmasOf(const StereoTargetParameters& p, const StereoTargetLayout& L, const Eigen::MatrixXd& Sigma,
                                 cv::Size size) {
  TargetCalibrationSigmas S;
  auto sd = [&](int i) { return std::sqrt(std::max(Sigma(i, i), 0.0)); };
  for (int c = 0; c < 2; ++c) {
    int k = L.camera(c);
    if (L.same_focal) {
      S.focal_px[c][0] = S.focal_px[c][1] = sd(k++);
    } else {
      S.focal_px[c][0] = sd(k++);
      S.focal_px[c][1] = sd(k++);
    }
    S.principal_px[c][0] = sd(k++);
    S.principal_px[c][1] = sd(k++);
    for (int d = 0; d < L.distortion; ++d) S.distortion[c].push_back(sd(k++));
    S.image_corner_px[c] = imageCornerSigma(p, L, c, Sigma, size);
  }
  for (int k = 0; k < 3; ++k) {
    S.rotation_rad[k] = sd(L.relative() + k);
    S.translation_mm[k] = sd(L.relative() + 3 + k);
  }
  headSigmas(p, L, Sigma, size, S);
  return S;
}

// Each standard deviation the larger of a's and b's.
TargetCalibrationSigmas largerOf(const TargetCalibrationSigmas& a, const TargetCalibrationSigmas& b) {
  TargetCalibrationSigmas out = a;
  auto pick = [](double& o, double v) { o = std::max(o, v); };
  for (int c = 0; c < 2; ++c) {
    for (int k = 0; k < 2; ++k) {
      pick(out.focal_px[c][k], b.focal_px[c][k]);
      pick(out.principal_px[c][k], b.principal_px[c][k]);
    }
    for (size_t d = 0; d < out.distortion[c].size(); ++d) pick(out.distortion[c][d], b.distortion[c][d]);
    pick(out.image_corner_px[c], b.image_corner_px[c]);
  }
  for (int k = 0; k < 3; ++k) {
    pick(out.rotation_rad[k], b.rotation_rad[k]);
    pick(out.translation_mm[k], b.translation_mm[k]);
  }
  for (auto field : {&TargetCalibrationSigmas::baseline_mm, &TargetCalibrationSigmas::baseline_scale,
                     &TargetCalibrationSigmas::focal_ratio, &TargetCalibrationSigmas::focal_scale,
                     &TargetCalibrationSigmas::disparity_offset_px, &TargetCalibrationSigmas::column_offset_px,
                     &TargetCalibrationSigmas::tilt_rad})
    pick(out.*field, b.*field);
  return out;
}

// The cameras' parameters (intrinsics, r, T: every parameter but the board poses) in the
// layout's order.
Eigen::VectorXd cameraParameters(const StereoTargetParameters& p, const StereoTargetLayout& L) {
  Eigen::VectorXd x(L.relative() + 6);
  for (int c = 0; c < 2; ++c) {
    int k = L.camera(c);
    x(k++) = p.K[c].at<double>(0, 0);
    if (!L.same_focal) x(k++) = p.K[c].at<double>(1, 1);
    x(k++) = p.K[c].at<double>(0, 2);
    x(k++) = p.K[c].at<double>(1, 2);
    for (int d = 0; d < L.distortion; ++d) x(k++) = p.D[c].at<double>(0, d);
  }
  for (int k = 0; k < 3; ++k) {
    x(L.relative() + k) = p.r[k];
    x(L.relative() + 3 + k) = p.T[k];
  }
  return x;
}

// The joint optimum without each pair in turn (a few Gauss-Newton steps from `p`, the optimum
// with all; board poses those of the pairs kept).
std::vector<StereoTargetParameters> leaveOnePairOut(const StereoTargetParameters& p, const StereoTargetLayout& L,
                                                    const std::vector<cv::Point3d>& object, const Detections& found) {
  std::vector<StereoTargetParameters> fits;
  for (int v = 0; v < L.pairs; ++v) {
    StereoTargetParameters q = p;
    q.rv.erase(q.rv.begin() + v);
    q.tv.erase(q.tv.begin() + v);
    Detections d = found;
    d.left.erase(d.left.begin() + v);
    d.right.erase(d.right.begin() + v);
    StereoTargetLayout Lq = L;
    Lq.pairs = L.pairs - 1;
    refineJointly(q, Lq, object, d);
    fits.push_back(std::move(q));
  }
  return fits;
}

// The spread of the cameras' parameters over the pairs: leave-one-pair-out (jackknife)
// covariance, (V-1)/V sum_v (x_(v) - mean)(x_(v) - mean)^T, x_(v) the cameras' parameters of
// the optimum without pair v. It sees what the fit's covariance cannot: errors shared by a
// view's corners (a board that is not flat or not printed to scale, lighting, the lens model's
// misfit where that view's corners lie), which the fit counts as independent corners.
// Board-pose rows and columns are zero.
Eigen::MatrixXd pairSpreadCovariance(const std::vector<StereoTargetParameters>& fits, const StereoTargetLayout& L) {
  const int V = L.pairs, m = L.relative() + 6;
  std::vector<Eigen::VectorXd> x;
  for (const auto& q : fits) x.push_back(cameraParameters(q, L));
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(m);
  for (const auto& xv : x) mean += xv / V;
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(L.size(), L.size());
  for (const auto& xv : x) C.topLeftCorner(m, m) += (xv - mean) * (xv - mean).transpose();
  C *= static_cast<double>(V - 1) / V;
  if (!C.allFinite()) throw Error("calibrate: a calibration without one of the pairs did not converge; take more pairs");
  return C;
}

}  // namespace

void orderLike(const std::vector<cv::Point2f>& reference, std::vector<cv::Point2f>& corners) {
  if (reference.empty() || corners.empty()) return;
  if ((reference.back() - reference.front()).dot(corners.back() - corners.front()) < 0.0f)
    std::reverse(corners.begin(), corners.end());
}

std::vector<cv::Point2f> detectBoardCorners(const cv::Mat& image, const CheckerBoard& board) {
  std::vector<cv::Point2f> corners;
  if (image.empty()) return corners;
  const cv::Mat g = grey(image);
  const size_t expected = static_cast<size_t>(board.columns) * static_cast<size_t>(board.rows);
  // The classic detector with a global threshold (a clear board in under a millisecond), else
  // the sector-based one (it finds the small, far boards the classic misses), else the classic
  // with adaptive thresholds, last because it takes half a second to give up on an image. The
  // sector-based detector's own sub-pixel corners were biased on our views (focal lengths ~1 %
  // long, 2-8 of their sigmas); every detector's corners are refined by the saddle point of the
  // image gradient.
  const bool found =
      cv::findChessboardCorners(g, board.patternSize(), corners, cv::CALIB_CB_NORMALIZE_IMAGE) ||
      cv::findChessboardCornersSB(g, board.patternSize(), corners, cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE) ||
      cv::findChessboardCorners(g, board.patternSize(), corners, cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE);
  if (!found || corners.size() != expected) return {};
  // The refinement's window must stay inside the corner's four squares: a neighbouring corner's
  // edge in it would pull the saddle point.
  double spacing = 1e9;
  for (int j = 0; j < board.rows; ++j)
    for (int i = 0; i < board.columns; ++i) {
      const cv::Point2f& c = corners[static_cast<size_t>(j * board.columns + i)];
      if (i + 1 < board.columns) spacing = std::min(spacing, cv::norm(c - corners[static_cast<size_t>(j * board.columns + i + 1)]));
      if (j + 1 < board.rows) spacing = std::min(spacing, cv::norm(c - corners[static_cast<size_t>((j + 1) * board.columns + i)]));
    }
  const int half = static_cast<int>(std::clamp(std::floor(0.4 * spacing), 2.0, 7.0));
  cv::cornerSubPix(g, corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-4));
  return corners;
}

TargetCalibrationResult calibrateStereoFromTargets(const std::vector<TargetPair>& pairs, const CheckerBoard& board,
                                                   const TargetCalibrationOptions& options) {
  board.validate("calibration board");
  const int nd = options.distortion_coefficients;
  if (nd != 4 && nd != 5 && nd != 8)
    throw Error("calibrate: distortion_coefficients: must be 4, 5 or 8, got " + std::to_string(nd));
  if (options.min_views < 3)
    throw Error("calibrate: min_views: at least 3 pairs are needed, got " + std::to_string(options.min_views));
  if (pairs.empty()) throw Error("calibrate: no image pairs");
  if (options.outlier_factor < 0.0 || !std::isfinite(options.outlier_factor))
    throw Error("calibrate: outlier_factor: must be >= 0 (0: keep every pair), got " +
                std::to_string(options.outlier_factor));

  TargetCalibrationResult result;
  const cv::Size size = pairs.front().left.size();
  Detections found = detectPairs(pairs, board, result.pairs);
  int V = static_cast<int>(found.left.size());
  if (V < options.min_views) {
    std::string why;
    for (const auto& r : result.pairs)
      if (!r.used) why += (why.empty() ? "" : "; ") + r.name + ": " + r.reason;
    throw Error("calibrate: " + std::to_string(V) + " of " + std::to_string(pairs.size()) +
                " pairs show the whole board in both images, " + std::to_string(options.min_views) +
                " needed" + (why.empty() ? "" : " (" + why + ")"));
  }

  // Each camera alone first: OpenCV's stereo estimate starts from them, and a pair's stereo
  // consistency is judged from its two monocular board poses.
  const MonocularCalibration mono[2] = {calibrateCamera(found.object, found.left, size, options),
                                        calibrateCamera(found.object, found.right, size, options)};
  if (options.outlier_factor > 0.0) V = leaveOutInconsistentPairs(mono, options, found, result.pairs);

  StereoTargetLayout L;
  L.same_focal = options.same_focal_axes;
  L.distortion = nd;
  L.pairs = V;
  const std::vector<cv::Point3d> object(found.object.begin(), found.object.end());
  StereoTargetParameters p = openCvEstimate(found, mono, size, options);
  const JointSolution joint = refineJointly(p, L, object, found);
  const std::vector<StereoTargetParameters> without = leaveOnePairOut(p, L, object, found);
  const Eigen::MatrixXd Sigma = covarianceOf(joint, L, object.size());
  result.fit_sigmas = sigmasOf(p, L, Sigma, size);
  result.pair_spread_sigmas = sigmasOf(p, L, pairSpreadCovariance(without, L), size);
  result.sigmas = largerOf(result.fit_sigmas, result.pair_spread_sigmas);

  // The result and every pair's reprojection RMS.
  StereoCalibration& cal = result.calibration;
  cal.K1 = p.K[0];
  cal.D1 = p.D[0];
  cal.K2 = p.K[1];
  cal.D2 = p.D[1];
  cv::Rodrigues(cv::Mat(p.r), cal.R);
  cal.T = cv::Mat(p.T).clone();
  cal.image_size = size;
  cal.source = "checkerboard calibration";
  cal.rectify();
  cal.validate("calibrate");
  result.used_pairs = V;
  result.corners_per_image = static_cast<int>(object.size());
  result.rms_px = std::sqrt(joint.cost / (2.0 * static_cast<double>(object.size()) * V));
  const std::vector<double> rms = pairRms(p, L, object, found);
  for (size_t v = 0; v < rms.size(); ++v) result.pairs[found.index[v]].rms_px = rms[v];
  double row_sq = 0.0;
  for (size_t v = 0; v < found.left.size(); ++v) {
    std::vector<cv::Point2f> l, r;
    cv::undistortPoints(found.left[v], l, cal.K1, cal.D1, cal.R1, cal.P1);
    cv::undistortPoints(found.right[v], r, cal.K2, cal.D2, cal.R2, cal.P2);
    for (size_t k = 0; k < l.size(); ++k) row_sq += std::pow(l[k].y - r[k].y, 2);
  }
  result.rectified_row_rms_px = std::sqrt(row_sq / (static_cast<double>(object.size()) * V));
  return result;
}

void saveCalibratedRig(const std::string& path, const StereoRigParams& mounting, const TargetCalibrationResult& result,
                       double tilt_sigma_rad, double column_offset_sigma_px, double drive_disparity_sigma_px) {
  const TargetCalibrationSigmas& S = result.sigmas;
  if (!(tilt_sigma_rad > 0.0) || !std::isfinite(tilt_sigma_rad))
    throw Error(path + ": tilt_correction_sigma_rad: must be a positive standard deviation, got " +
                std::to_string(tilt_sigma_rad));
  if (!(column_offset_sigma_px > 0.0) || !std::isfinite(column_offset_sigma_px))
    throw Error(path + ": column_offset_sigma_px: must be a positive standard deviation, got " +
                std::to_string(column_offset_sigma_px));
  if (!(drive_disparity_sigma_px >= 0.0) || !std::isfinite(drive_disparity_sigma_px))
    throw Error(path + ": disparity_offset_sigma_px: the drive's part must be >= 0, got " +
                std::to_string(drive_disparity_sigma_px));
  const std::pair<const char*, double> sigmas[] = {
      {"tilt_correction_sigma_rad", std::hypot(tilt_sigma_rad, S.tilt_rad)},
      {"baseline_scale_sigma", S.baseline_scale},
      // A mounting that states the cameras' exposure offset has each pair moved to one instant:
      // no drive's part then (src/core/exposure_offset.h).
      {"disparity_offset_sigma_px",
       std::hypot(S.disparity_offset_px, mounting.exposure_offset_s != 0.0 ? 0.0 : drive_disparity_sigma_px)},
      {"column_offset_sigma_px", std::hypot(column_offset_sigma_px, S.column_offset_px)},
      {"focal_ratio_sigma", S.focal_ratio},
      {"focal_scale_sigma", S.focal_scale}};
  for (const auto& [key, value] : sigmas)
    if (!(value > 0.0) || !std::isfinite(value))
      throw Error(path + ": " + key + ": the calibration states no uncertainty (" + std::to_string(value) +
                  "); a self-calibration needs a positive prior");
  const StereoRig rig(mounting, result.calibration);
  rig.save(path);
  // The rig as written, then the sigmas (the rig reader ignores them; CalibrationHandover reads them).
  YamlReader back(path);
  YamlWriter w;
  w.comment("stereoloc rig of a checkerboard-calibrated stereo head (stereoloc calibrate); the calibration's standard "
            "deviations below are the priors of a self-calibration handed this rig.");
  w.putScalarsOf(back);
  for (const auto& [key, value] : sigmas) w.put(key, value);
  w.put("calibration_rms_px", result.rms_px);
  w.put("calibration_pairs", result.used_pairs);
  w.writeAtomically(path);
}

}  // namespace stereoloc
