// Stage 8: ZNCC stereo matching of floor features along the epipolar row.
#include <gtest/gtest.h>

#include <cmath>

#include "frontend/frontend.h"
#include "synthetic_scene.h"

using namespace stereoloc;
using namespace stereoloc::frontend;

namespace {

using test::renderFloor;
using test::Strip;

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
