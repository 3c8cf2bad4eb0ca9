#include "src/sim/raw_render.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "src/core/angles.h"
#include "src/core/lens_distortion.h"
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

// The true pose at a fractional step, for the exposures around a step. A drive follows its arcs
// (poseAtStep). The fix scenarios' poses are independent (Scenario::independent_poses) and move
// the robot sideways with its heading fixed, where the arc from one pose does not end at the
// next: poseAtStep jumps by up to a step's length at each step, and a sub-exposure or the right
// camera's exposure just before the step would see the scene from a pose 20-40 mm away (a stereo
// baseline of 30 mm). Between independent poses the robot moves straight at a constant turn rate
// instead, so the pose is continuous at every step.
Pose2 exposurePose(const Scenario& sc, double step) {
  if (!sc.independent_poses) return poseAtStep(sc, step);
  const double t = std::clamp(step, 0.0, static_cast<double>(sc.poses.size() - 1));
  const size_t k = std::min(static_cast<size_t>(t), sc.poses.size() - 1);
  const double a = t - static_cast<double>(k);
  if (a <= 0.0 || k + 1 >= sc.poses.size()) return sc.poses[k];
  const Pose2& p = sc.poses[k];
  const Pose2& q = sc.poses[k + 1];
  return Pose2(p.x + a * (q.x - p.x), p.y + a * (q.y - p.y), wrapAngle(p.theta + a * angleDiff(q.theta, p.theta)));
}

}  // namespace

RawPairRenderer::RawPairRenderer(const FieldMap& map, const StereoRigParams& nominal, const ErrorProfile& profile,
                                 const DrawnErrors& errors, const RenderOptions& options, double dt)
    : map_(trueFieldMap(map, errors)), nominal_(nominal), nominal_rig_(nominal), profile_(profile), errors_(errors), options_(options), dt_(dt) {
  options_.validate();
  const int W = nominal.image_width, H = nominal.image_height;
  std::vector<cv::Point2d> raw;
  raw.reserve(static_cast<size_t>(W) * H);
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) raw.emplace_back(u, v);
  for (int c = 0; c < 2; ++c) {
    const RawCamera cam = trueCamera(nominal_rig_, errors_, c, 0);
    const std::vector<cv::Point2d> n = pixelRays(cam.K, cam.D, raw);
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
  opt.compute_truth = false;
  const StereoRenderer renderer(map_, StereoRig(p), opt);
  const double pan = sc.head_pan[s];

  // Where each raw pixel reads the ideal image, and so which ideal pixels are read at all:
  // cv::remap's bilinear taps of a map value x are floor(x) .. floor(x) + 2 (it rounds x to
  // 1/32 px first); one more on the low side for safety. The other pixels are not ray-cast.
  const RawCamera cams[2] = {trueCamera(nominal_rig_, errors_, 0, s), trueCamera(nominal_rig_, errors_, 1, s)};
  cv::Mat mx[2], my[2];
  StereoRenderer::ColumnRanges needed[2];
  for (int c = 0; c < 2; ++c) {
    const cv::Matx33d Rt = cv::Matx33d(cams[c].R).t();
    mx[c].create(H, W, CV_32FC1);
    my[c].create(H, W, CV_32FC1);
    needed[c].assign(static_cast<size_t>(p.image_height), {p.image_width, 0});
    for (int v = 0; v < H; ++v) {
      const cv::Vec2f* ray = rays_[c].ptr<cv::Vec2f>(v);
      float* x_row = mx[c].ptr<float>(v);
      float* y_row = my[c].ptr<float>(v);
      for (int u = 0; u < W; ++u) {
        const cv::Vec3d X = Rt * cv::Vec3d(ray[u][0], ray[u][1], 1.0);
        x_row[u] = static_cast<float>(f * X[0] / X[2] + cu);
        y_row[u] = static_cast<float>(f * X[1] / X[2] + cv_);
        const int x0 = static_cast<int>(std::floor(x_row[u])), y0 = static_cast<int>(std::floor(y_row[u]));
        for (int y = std::max(y0 - 1, 0); y <= std::min(y0 + 2, p.image_height - 1); ++y) {
          std::pair<int, int>& r = needed[c][static_cast<size_t>(y)];
          r.first = std::min(r.first, std::max(x0 - 1, 0));
          r.second = std::max(r.second, std::min(x0 + 3, p.image_width));
        }
      }
    }
  }

  // Motion blur and the right camera's exposure offset: each sub-exposure renders only the
  // camera whose image it feeds.
  const int K = profile_.exposure_s > 0 ? profile_.exposure_samples : 1;
  cv::Mat acc[2];
  for (int k = 0; k < K; ++k) {
    const double tau = profile_.exposure_s * ((k + 0.5) / K - 0.5);
    for (int c = 0; c < 2; ++c) {
      const double t = tau + (c == 1 ? errors_.exposure_offset_s : 0.0);
      const cv::Mat img = renderer.renderCamera(exposurePose(sc, static_cast<double>(s) + t / dt_), pan, obstacles, c,
                                                &needed[c]);
      cv::Mat fimg;
      img.convertTo(fimg, CV_32FC3, 1.0 / K);
      if (k == 0)
        acc[c] = fimg;
      else
        acc[c] += fimg;
    }
  }

  StereoImages out;
  if (options_.compute_truth) out.truth = renderer.truth(sc.poses[s], pan, obstacles);
  cv::RNG rng(noise_seed);
  for (int c = 0; c < 2; ++c) {
    cv::Mat raw;
    cv::remap(acc[c], raw, mx[c], my[c], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    if (options_.noise_sigma > 0) {
      cv::Mat noise(raw.size(), CV_32FC3);
      rng.fill(noise, cv::RNG::NORMAL, 0.0, options_.noise_sigma);
      raw += noise;
    }
    raw.convertTo(c == 0 ? out.left : out.right, CV_8UC3);
    if (!options_.compute_truth) continue;
    ImageTruth& t = c == 0 ? out.truth.left : out.truth.right;
    for (ImageLandmark& l : t.landmarks) l.pixel = toRaw(l.pixel, f, cu, cv_, cams[c]);
    for (ImageSegment& g : t.segments) {
      g.a = toRaw(g.a, f, cu, cv_, cams[c]);
      g.b = toRaw(g.b, f, cu, cv_, cams[c]);
    }
  }
  return out;
}

}  // namespace stereoloc
