// Stage 8: ZNCC stereo matching of floor features along the epipolar row.
#include <gtest/gtest.h>

#include <cmath>

#include "frontend/frontend.h"

using namespace stereoloc;
using namespace stereoloc::frontend;

namespace {

struct Strip {  // floor marking in C0 (mm): centreline a -> b, half width
  Eigen::Vector2d a, b;
  double hw = 5.0;
};

// Ray-casts a floor scene (dark floor, white strips, optional white region x >= wall_x) into
// the left or right camera, 4x4 samples per pixel.
cv::Mat renderFloor(const StereoRig& rig, bool right, const std::vector<Strip>& strips, double wall_x = 1e9) {
  const int w = rig.params().image_width, h = rig.params().image_height;
  const double f = rig.focal(), yc = (right ? -0.5 : 0.5) * rig.params().baseline_mm;
  const Eigen::Vector3d o = rig.visionToRobot(Eigen::Vector3d(0, yc, 0), 0.0);
  auto dir = [&](double u, double v) -> Eigen::Vector3d {
    return rig.visionToRobot(Eigen::Vector3d(1.0, yc - (u - rig.principalU()) / f, -(v - rig.principalV()) / f), 0.0) - o;
  };
  const Eigen::Vector3d d00 = dir(0, 0), du = dir(1, 0) - d00, dv = dir(0, 1) - d00;
  auto white = [&](const Eigen::Vector2d& p) {
    if (p.x() >= wall_x) return true;
    for (const Strip& s : strips) {
      const Eigen::Vector2d t = (s.b - s.a).normalized();
      const double along = (p - s.a).dot(t), across = std::fabs(t.x() * (p - s.a).y() - t.y() * (p - s.a).x());
      if (along >= -s.hw && along <= (s.b - s.a).norm() + s.hw && across <= s.hw) return true;
    }
    return false;
  };
  cv::Mat img(h, w, CV_8UC3);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      int n = 0;
      for (int k = 0; k < 16; ++k) {
        const Eigen::Vector3d d = d00 + (u - 0.5 + (k % 4 + 0.5) / 4) * du + (v - 0.5 + (k / 4 + 0.5) / 4) * dv;
        if (d.z() >= 0) continue;  // sky: dark
        const double s = -o.z() / d.z();
        n += white(Eigen::Vector2d(o.x() + s * d.x(), o.y() + s * d.y())) ? 1 : 0;
      }
      const uint8_t g = static_cast<uint8_t>(20 + 210 * n / 16);
      img.at<cv::Vec3b>(v, u) = cv::Vec3b(g, g, g);
    }
  return img;
}

[[maybe_unused]] Eigen::Vector2d pixel(const StereoRig& rig, double x, double y) {
  const auto p = rig.project(Eigen::Vector3d(x, y, 0.0), 0.0);
  return Eigen::Vector2d(p->u_left, p->v_left);
}

}  // namespace

TEST(StereoMatch, FloorCornerDisparityIsSubPixel) {
  const StereoRig rig;
  const std::vector<Strip> scene = {{{250, -150}, {250, 60}}, {{250, 60}, {600, 60}}};
  const cv::Mat left = renderFloor(rig, false, scene), right = renderFloor(rig, true, scene);
  cv::Mat ll, rl;
  bgrToLuma(left, ll);
  bgrToLuma(right, rl);
  const auto px = rig.project(Eigen::Vector3d(250, 60, 0), 0.0);
  ASSERT_TRUE(px.has_value());
  const DisparityRange range = validDisparities(rig, StereoParams());
  const auto d = matchFloorFeature(ll, rl, rig, px->u_left, px->v_left, range, StereoParams());
  ASSERT_TRUE(d.has_value());
  EXPECT_NEAR(*d, px->disparity(), 0.15);
  // The floor predicts the disparity exactly (no noise in this scene).
  EXPECT_NEAR(*floorDisparity(rig, px->u_left, px->v_left), px->disparity(), 1e-6);
  // A flat patch has no unique match.
  EXPECT_FALSE(matchFloorFeature(ll, rl, rig, 160, 235, range, StereoParams()).has_value());
}

// The slide gain against a rendered pair whose right image shows the floor dv rows lower (the
// right camera's principal row moved by dv): the row search's right column moves by s dv for a
// corner with a slanted marking, and not for one whose marking is vertical in the image.
TEST(StereoMatch, SlideGainPredictsTheColumnShiftOfARowOffset) {
  const StereoRig rig;
  struct Case {
    std::vector<Strip> scene;
    Eigen::Vector3d corner;
    bool slanted;
  };
  // Markings ahead at y = +-60 mm run to the vanishing point: slanted in the image, one way left
  // of the centre and the other way right of it (where the floor's shear, 0.43 px per row for
  // b / h = 30 / 70, and the left edge's lean partly cancel).
  const Case cases[] = {{{{{250, -150}, {250, 60}}, {{250, 60}, {600, 60}}}, {250, 60, 0}, true},
                        {{{{250, 150}, {250, -60}}, {{250, -60}, {600, -60}}}, {250, -60, 0}, false}};
  for (const Case& c : cases) {
    const cv::Mat left = renderFloor(rig, false, c.scene);
    cv::Mat ll;
    bgrToLuma(left, ll);
    const auto px = rig.project(c.corner, 0.0);
    ASSERT_TRUE(px.has_value());
    const DisparityRange range = validDisparities(rig, StereoParams());
    double gain0 = 0;
    std::optional<double> d0;
    for (double dv : {0.0, -1.5, 1.5}) {
      StereoRigParams shifted = rig.params();
      shifted.principal_v = rig.principalV() + dv;
      cv::Mat rl;
      bgrToLuma(renderFloor(StereoRig(shifted), true, c.scene), rl);
      double gain = 0;
      const auto d = matchFloorFeature(ll, rl, rig, px->u_left, px->v_left, range, StereoParams(), &gain);
      ASSERT_TRUE(d.has_value()) << "dv " << dv;
      if (dv == 0.0) {
        d0 = d;
        gain0 = gain;
        if (c.slanted) {
          EXPECT_GT(gain, 0.8);
        } else {
          EXPECT_LT(gain, -0.1);
        }
        continue;
      }
      EXPECT_NEAR(gain, gain0, 1e-12);  // a property of the left patch
      // u_r = u_l - d moves by s dv: d by -s dv.
      const double shift = -(*d - *d0);
      // First order: within 35 % (the slanted corner's gain is 0.77 without the shear, 1.20 with it).
      EXPECT_NEAR(shift, gain * dv, 0.35 * std::fabs(gain * dv) + 0.1) << "dv " << dv << " gain " << gain;
      EXPECT_GT(std::fabs(shift), c.slanted ? 1.0 : 0.1);
    }
  }
}

TEST(StereoMatch, FullPipelineObservationOfAFloorCorner) {
  const StereoRig rig;
  const std::vector<Strip> scene = {{{250, -150}, {250, 60}}, {{250, 60}, {600, 60}}};
  Frontend fe(rig, FieldMap::miroSot());
  const FrontendResult& r = fe.process(renderFloor(rig, false, scene), renderFloor(rig, true, scene), 0.0);
  ASSERT_EQ(r.observations.size(), 1u);
  const Observation& o = r.observations[0];
  EXPECT_EQ(o.type, LandmarkType::MarkingCorner);
  EXPECT_EQ(o.landmark_id, -1);
  EXPECT_NEAR(o.range, std::hypot(250.0, 60.0), 0.02 * 257);
  EXPECT_NEAR(o.bearing, std::atan2(60.0, 250.0), 0.01);
  EXPECT_GT(o.covariance(0, 0), 0.0);
  EXPECT_TRUE(o.pixels.has_value());
}
