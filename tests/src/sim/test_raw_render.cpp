// RawPairRenderer ray-casts, per sub-exposure, only the camera that sub-exposure feeds and only
// the ideal pixels cv::remap reads (StereoRenderer::renderCamera with column ranges): the raw
// pairs must be those of rendering whole ideal pairs and remapping them.
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "src/sim/raw_render.h"
#include "src/sim/renderer.h"
#include "src/sim/simulator.h"

namespace stereoloc {
namespace {

double maxDiff(const cv::Mat& a, const cv::Mat& b) { return cv::norm(a, b, cv::NORM_INF); }

TEST(RenderCamera, IsRenderOfThatCameraAndRangesKeepTheirPixels) {
  const FieldMap map = FieldMap::miroSot();
  RenderOptions o;
  o.threads = 2;
  o.compute_truth = false;
  Obstacle robot;
  robot.position = Eigen::Vector2d(500, 620);
  const StereoRenderer renderer(map, StereoRig(), o);
  for (const std::vector<Obstacle>& obstacles : {std::vector<Obstacle>{}, std::vector<Obstacle>{robot}}) {
    const Pose2 pose(900, 600, 2.8);
    const StereoImages pair = renderer.render(pose, 0.1, obstacles);
    const cv::Mat left = renderer.renderCamera(pose, 0.1, obstacles, 0);
    const cv::Mat right = renderer.renderCamera(pose, 0.1, obstacles, 1);
    EXPECT_EQ(maxDiff(pair.left, left), 0.0);
    EXPECT_EQ(maxDiff(pair.right, right), 0.0);
    // Ragged ranges, empty rows, ranges past the border: the asked pixels are render()'s, the
    // others 0.
    StereoRenderer::ColumnRanges needed(static_cast<size_t>(left.rows));
    for (int v = 0; v < left.rows; ++v)
      needed[static_cast<size_t>(v)] = v % 7 == 3 ? std::pair<int, int>(5, 5) : std::pair<int, int>(40 - v % 50, 200 + v);
    const cv::Mat part = renderer.renderCamera(pose, 0.1, obstacles, 1, &needed);
    int compared = 0;
    for (int v = 0; v < part.rows; ++v)
      for (int u = 0; u < part.cols; ++u) {
        const auto [first, last] = needed[static_cast<size_t>(v)];
        const bool asked = u >= first && u < last;
        const cv::Vec3b want = asked ? right.at<cv::Vec3b>(v, u) : cv::Vec3b(0, 0, 0);
        ASSERT_EQ(part.at<cv::Vec3b>(v, u), want) << u << " " << v;
        compared += asked ? 1 : 0;
      }
    EXPECT_GT(compared, 20000);
  }
  EXPECT_THROW(renderer.renderCamera(Pose2(900, 600, 2.8), 0.0, {}, 2), Error);
  StereoRenderer::ColumnRanges short_ranges(3, {0, 10});
  EXPECT_THROW(renderer.renderCamera(Pose2(900, 600, 2.8), 0.0, {}, 0, &short_ranges), Error);
}

// The raw pair as the definition in raw_render.h states it, computed the long way: whole ideal
// pairs of the true head at every sub-exposure, the left image of the left camera's exposure
// and the right image of the right's, averaged, remapped through every raw pixel's ray.
StereoImages rawPairTheLongWay(const FieldMap& map, const StereoRigParams& nominal, const ErrorProfile& profile,
                               const DrawnErrors& e, const RenderOptions& options, double dt, const Scenario& sc,
                               size_t s, uint64_t noise_seed) {
  const int M = RawPairRenderer::kMarginPx, W = nominal.image_width, H = nominal.image_height;
  const StereoRig nominal_rig(nominal);
  StereoRigParams p = trueRigParams(nominal, e, s);
  p.image_width = W + 2 * M;
  p.image_height = H + 2 * M;
  p.focal_px = nominal_rig.focal();
  p.principal_u = nominal_rig.principalU() + M;
  p.principal_v = nominal_rig.principalV() + M;
  const double f = nominal_rig.focal(), cu = p.principal_u, cv_ = p.principal_v;
  RenderOptions opt = options;
  opt.noise_sigma = 0.0;
  opt.compute_truth = false;
  const StereoRenderer renderer(map, StereoRig(p), opt);
  const int K = profile.exposure_samples;
  cv::Mat acc[2];
  for (int k = 0; k < K; ++k) {
    const double tau = profile.exposure_s * ((k + 0.5) / K - 0.5);
    const StereoImages il = renderer.render(poseAtStep(sc, s + tau / dt), sc.head_pan[s], {});
    const StereoImages ir = renderer.render(poseAtStep(sc, s + (tau + e.exposure_offset_s) / dt), sc.head_pan[s], {});
    const cv::Mat* src[2] = {&il.left, &ir.right};
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
  cv::RNG rng(noise_seed);
  for (int c = 0; c < 2; ++c) {
    const RawCamera cam = trueCamera(nominal_rig, e, c, s);
    std::vector<cv::Point2d> raw, n;
    for (int v = 0; v < H; ++v)
      for (int u = 0; u < W; ++u) raw.emplace_back(u, v);
    cv::undistortPoints(raw, n, cam.K, cam.D, cv::noArray(), cv::noArray(),
                        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-9));
    const cv::Matx33d Rt = cv::Matx33d(cam.R).t();
    cv::Mat mx(H, W, CV_32FC1), my(H, W, CV_32FC1);
    for (int v = 0; v < H; ++v)
      for (int u = 0; u < W; ++u) {
        const cv::Point2d& q = n[static_cast<size_t>(v) * W + u];
        const cv::Vec3d X = Rt * cv::Vec3d(static_cast<float>(q.x), static_cast<float>(q.y), 1.0);
        mx.at<float>(v, u) = static_cast<float>(f * X[0] / X[2] + cu);
        my.at<float>(v, u) = static_cast<float>(f * X[1] / X[2] + cv_);
      }
    cv::Mat img;
    cv::remap(acc[c], img, mx, my, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    cv::Mat noise(img.size(), CV_32FC3);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, options.noise_sigma);
    img += noise;
    img.convertTo(c == 0 ? out.left : out.right, CV_8UC3);
  }
  return out;
}

TEST(RawPairRenderer, SameImagesAsRenderingWholePairsAndAnyThreadCount) {
  const ErrorProfile profile = ErrorProfile::realistic();
  std::mt19937_64 rng(11);
  DrawnErrors e = drawErrors(profile, 3, rng);
  e.exposure_offset_s = 0.004;  // the right camera's exposure differs from the left's
  Scenario sc;
  sc.poses = {Pose2(300, 650, 0.0), Pose2(330, 655, 0.15), Pose2(360, 665, 0.3)};  // turning towards the goal
  sc.head_pan = {0.0, 0.0, 0.05};
  sc.carried = {false, false, false};
  const StereoRigParams nominal;
  RenderOptions one, two;
  one.threads = 1;
  two.threads = 2;
  one.noise_sigma = two.noise_sigma = 1.5;
  one.compute_truth = two.compute_truth = false;
  const FieldMap map = FieldMap::miroSot();
  const RawPairRenderer a(map, nominal, profile, e, one, 0.1), b(map, nominal, profile, e, two, 0.1);
  for (size_t s = 1; s < 3; ++s) {
    const StereoImages x = a.render(sc, s, {}, 40 + s), y = b.render(sc, s, {}, 40 + s);
    const StereoImages ref = rawPairTheLongWay(map, nominal, profile, e, one, 0.1, sc, s, 40 + s);
    EXPECT_EQ(maxDiff(x.left, ref.left), 0.0) << s;
    EXPECT_EQ(maxDiff(x.right, ref.right), 0.0) << s;
    EXPECT_EQ(maxDiff(x.left, y.left), 0.0) << s;
    EXPECT_EQ(maxDiff(x.right, y.right), 0.0) << s;
    EXPECT_TRUE(x.truth.left.landmarks.empty());  // no truth unless asked
  }
}

// The fix scenarios' poses are independent and step sideways with a fixed heading, which the
// arc between them (poseAtStep) does not follow: their exposures lie on the straight path
// between the poses instead, so a pair shows the scene from its own pose, blurred by the motion.
TEST(RawPairRenderer, IndependentPosesExposeAroundTheirOwnPose) {
  ErrorProfile profile;  // exact cameras: only the exposure differs from the ideal pair
  profile.exposure_s = 0.01;
  profile.exposure_samples = 3;
  DrawnErrors e;
  e.exposure_offset_s = -0.005;  // the right camera's exposure ends before the step
  Scenario sc;
  for (int k = 0; k < 3; ++k) sc.poses.push_back(Pose2(400, 500 + 20.0 * k, 0.0));  // sideways, 20 mm/step
  sc.head_pan.assign(3, 0.0);
  sc.carried.assign(3, false);
  sc.independent_poses = true;
  RenderOptions o;
  o.compute_truth = false;
  const FieldMap map = FieldMap::miroSot();
  const StereoRigParams nominal;
  const StereoImages ideal = StereoRenderer(map, StereoRig(nominal), o).render(sc.poses[1], 0.0, {});
  auto meanDiff = [&](const Scenario& scenario) {
    const StereoImages raw = RawPairRenderer(map, nominal, profile, e, o, 0.1).render(scenario, 1, {}, 0);
    return 0.5 * (cv::norm(raw.left, ideal.left, cv::NORM_L1) + cv::norm(raw.right, ideal.right, cv::NORM_L1)) /
           static_cast<double>(ideal.left.total() * 3);
  };
  const double continuous = meanDiff(sc);
  sc.independent_poses = false;  // the same poses as a drive: the arcs jump at each step
  const double arcs = meanDiff(sc);
  EXPECT_LT(continuous, 0.5);
  EXPECT_GT(arcs, 4.0 * continuous);
}

}  // namespace
}  // namespace stereoloc
