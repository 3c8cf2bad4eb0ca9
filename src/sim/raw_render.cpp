#include "src/sim/raw_render.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

Eigen::Vector2d toRaw(const Eigen::Vector2d& ideal, double f, double cu, double cv_, const RawCamera& cam) {
  const cv::Mat X = cam.R * (cv::Mat_<double>(3, 1) << (ideal.x() - cu) / f, (ideal.y() - cv_) / f, 1.0);
  std::vector<cv::Point2d> out;
  cv::projectPoints(std::vector<cv::Point3d>{cv::Point3d(X.at<double>(0), X.at<double>(1), X.at<double>(2))},
                    cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cam.K, cam.D, out);
  return {out[0].x, out[0].y};
}

}  // namespace

RawPairRenderer::RawPairRenderer(const FieldMap& map, const StereoRigParams& nominal, const ErrorProfile& profile,
                                 const DrawnErrors& errors, const RenderOptions& options, double dt)
    : map_(map), nominal_(nominal), nominal_rig_(nominal), profile_(profile), errors_(errors), options_(options), dt_(dt) {
  options_.validate();
  const int W = nominal.image_width, H = nominal.image_height;
  std::vector<cv::Point2d> raw;
  raw.reserve(static_cast<size_t>(W) * H);
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) raw.emplace_back(u, v);
  for (int c = 0; c < 2; ++c) {
    const RawCamera cam = trueCamera(nominal_rig_, errors_, c, 0);
    std::vector<cv::Point2d> n;
    cv::undistortPoints(raw, n, cam.K, cam.D, cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-9));
    rays_[c].create(H, W, CV_32FC2);
    for (int v = 0; v < H; ++v)
      for (int u = 0; u < W; ++u) {
        const cv::Point2d& q = n[static_cast<size_t>(v) * W + u];
        rays_[c].at<cv::Vec2f>(v, u) = cv::Vec2f(static_cast<float>(q.x), static_cast<float>(q.y));
      }
  }
}

StereoImages RawPairRenderer::render(const Scenario& sc, size_t s, const std::vector<Obstacle>& obstacles,
                                     uint64_t noise_seed) const {
  const int M = kMarginPx, W = nominal_.image_width, H = nominal_.image_height;
  StereoRigParams p = trueRigParams(nominal_, errors_, s);
  p.image_width = W + 2 * M;
  p.image_height = H + 2 * M;
  p.focal_px = nominal_rig_.focal();
  p.principal_u = nominal_rig_.principalU() + M;
  p.principal_v = nominal_rig_.principalV() + M;
  const double f = p.focal_px, cu = p.principal_u, cv_ = p.principal_v;
  RenderOptions opt = options_;
  opt.noise_sigma = 0.0;
  const StereoRenderer renderer(map_, StereoRig(p), opt);
  const double pan = sc.head_pan[s];

  // Motion blur and the right camera's exposure offset.
  const int K = profile_.exposure_s > 0 ? profile_.exposure_samples : 1;
  cv::Mat acc[2];
  for (int k = 0; k < K; ++k) {
    const double tau = profile_.exposure_s * ((k + 0.5) / K - 0.5);
    const Pose2 pl = poseAtStep(sc, static_cast<double>(s) + tau / dt_);
    const StereoImages il = renderer.render(pl, pan, obstacles, noise_seed);
    StereoImages ir_store;
    const StereoImages* ir = &il;
    if (errors_.exposure_offset_s != 0.0) {
      ir_store = renderer.render(poseAtStep(sc, static_cast<double>(s) + (tau + errors_.exposure_offset_s) / dt_), pan,
                                 obstacles, noise_seed);
      ir = &ir_store;
    }
    const cv::Mat* src[2] = {&il.left, &ir->right};
    for (int c = 0; c < 2; ++c) {
      cv::Mat fimg;
      src[c]->convertTo(fimg, CV_32FC3, 1.0 / K);
      if (k == 0)
        acc[c] = fimg;
      else
        acc[c] += fimg;
    }
  }

  StereoImages out;
  out.truth = renderer.truth(sc.poses[s], pan, obstacles);
  cv::RNG rng(noise_seed);
  for (int c = 0; c < 2; ++c) {
    const RawCamera cam = trueCamera(nominal_rig_, errors_, c, s);
    const cv::Matx33d Rt = cv::Matx33d(cam.R).t();
    cv::Mat mx(H, W, CV_32FC1), my(H, W, CV_32FC1);
    for (int v = 0; v < H; ++v)
      for (int u = 0; u < W; ++u) {
        const cv::Vec2f n = rays_[c].at<cv::Vec2f>(v, u);
        const cv::Vec3d X = Rt * cv::Vec3d(n[0], n[1], 1.0);
        mx.at<float>(v, u) = static_cast<float>(f * X[0] / X[2] + cu);
        my.at<float>(v, u) = static_cast<float>(f * X[1] / X[2] + cv_);
      }
    cv::Mat raw;
    cv::remap(acc[c], raw, mx, my, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    if (options_.noise_sigma > 0) {
      cv::Mat noise(raw.size(), CV_32FC3);
      rng.fill(noise, cv::RNG::NORMAL, 0.0, options_.noise_sigma);
      raw += noise;
    }
    raw.convertTo(c == 0 ? out.left : out.right, CV_8UC3);

    ImageTruth& t = c == 0 ? out.truth.left : out.truth.right;
    for (ImageLandmark& l : t.landmarks) l.pixel = toRaw(l.pixel, f, cu, cv_, cam);
    for (ImageSegment& g : t.segments) {
      g.a = toRaw(g.a, f, cu, cv_, cam);
      g.b = toRaw(g.b, f, cu, cv_, cam);
    }
  }
  return out;
}

}  // namespace stereoloc
