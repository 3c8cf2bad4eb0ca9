// Stage 7: goal corners from colour transitions (3.6), sub-pixel and robust.
#include <gtest/gtest.h>

#include <cmath>

#include "frontend/goal_corners.h"
#include "frontend/stereo_match.h"
#include "synthetic_scene.h"

using namespace stereoloc;
using namespace stereoloc::frontend;

namespace {
using stereoloc::test::kWhite;
using stereoloc::test::kYellow;
using stereoloc::test::kBlue;
using stereoloc::test::kDark;

cv::Vec3b mix(const cv::Vec3b& a, const cv::Vec3b& b, double t) {
  cv::Vec3b r;
  for (int c = 0; c < 3; ++c) r[c] = static_cast<uint8_t>(std::lround((1 - t) * a[c] + t * b[c]));
  return r;
}

// Rows [r0, r1): `left` colour up to column edge_a, `mid` colour up to edge_b, `right` after;
// box-filtered (pixel x covers [x - 0.5, x + 0.5]). Other rows dark.
cv::Mat bands(double edge_a, double edge_b, const cv::Vec3b& left, const cv::Vec3b& mid, const cv::Vec3b& right,
              int r0 = 100, int r1 = 130) {
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(25, 25, 25));
  for (int y = r0; y < r1; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const double ca = std::clamp(x + 0.5 - edge_a, 0.0, 1.0), cb = std::clamp(x + 0.5 - edge_b, 0.0, 1.0);
      img.at<cv::Vec3b>(y, x) = mix(mix(left, mid, ca), right, cb);
    }
  return img;
}
}  // namespace

TEST(GoalCorners, TransitionAtItsSubPixelColumn) {
  for (double e : {120.0, 120.25, 120.5, 120.8}) {
    const cv::Mat img = bands(e, e + 60.4, kWhite, kYellow, kWhite);
    std::vector<GoalEdge> edges;
    std::vector<float> scratch;
    detectGoalEdges(img, GoalParams(), edges, scratch);
    ASSERT_EQ(edges.size(), 2u) << e;
    for (const GoalEdge& g : edges) {
      EXPECT_EQ(g.color, GoalColor::Yellow);
      EXPECT_NEAR(g.u, g.side < 0 ? e : e + 60.4, 0.05) << e << " side " << g.side;
      EXPECT_NEAR(g.v, 114.5, 0.01);
      EXPECT_EQ(g.rows, 30);
    }
  }
}

TEST(GoalCorners, BlueOneSideAndOutlierRowsRejected) {
  // Blue to the left of white only (the right edge of the goal in the image): side +1.
  cv::Mat img = bands(50.0, 200.6, kDark, kBlue, kWhite);
  // A few rows where something else shifts the transition by 5 px.
  for (int y = 100; y < 104; ++y)
    for (int x = 195; x < 206; ++x) img.at<cv::Vec3b>(y, x) = kBlue;
  std::vector<GoalEdge> edges;
  std::vector<float> scratch;
  detectGoalEdges(img, GoalParams(), edges, scratch);
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_EQ(edges[0].color, GoalColor::Blue);
  EXPECT_EQ(edges[0].side, 1);
  EXPECT_NEAR(edges[0].u, 200.6, 0.05);
  EXPECT_EQ(edges[0].rows, 26);
}

TEST(GoalCorners, NoGoalNoEdgesAndOrangeIsNotYellow) {
  std::vector<GoalEdge> edges;
  std::vector<float> scratch;
  detectGoalEdges(bands(100, 150, kWhite, kDark, kWhite), GoalParams(), edges, scratch);
  EXPECT_TRUE(edges.empty());
  detectGoalEdges(bands(100, 150, kWhite, cv::Vec3b(0, 150, 255), kWhite), GoalParams(), edges, scratch);  // a ball
  EXPECT_TRUE(edges.empty());
}

TEST(GoalCorners, StereoMatchFindsTheRightColumn) {
  const StereoRig rig;
  const DisparityRange range = validDisparities(rig, StereoParams());
  const cv::Mat left = bands(140.3, 190.0, kWhite, kYellow, kWhite);
  const cv::Mat right = bands(140.3 - 7.35, 190.0 - 7.35, kWhite, kYellow, kWhite);
  std::vector<GoalEdge> edges;
  std::vector<float> scratch;
  std::vector<Transition> tr;
  detectGoalEdges(left, GoalParams(), edges, scratch);
  ASSERT_EQ(edges.size(), 2u);
  for (const GoalEdge& g : edges) {
    const auto ur = matchGoalEdge(right, g, range, GoalParams(), tr, scratch);
    ASSERT_TRUE(ur.has_value());
    EXPECT_NEAR(g.u - *ur, 7.35, 0.05);
  }
  // Nothing in the right image: no match.
  EXPECT_FALSE(matchGoalEdge(cv::Mat(240, 320, CV_8UC3, cv::Scalar(25, 25, 25)), edges[0], range, GoalParams(), tr,
                             scratch)
                   .has_value());
}

// A goal corner the right camera does not see (beyond its border), where a few rows of another
// white/colour transition (a wall's top edge) lie in the search range: not matched on them.
TEST(GoalCorners, StereoMatchNeedsTheLeftEdgesRows) {
  const StereoRig rig;
  const DisparityRange range = validDisparities(rig, StereoParams());
  const cv::Mat left = bands(140.3, 400.0, kWhite, kBlue, kWhite, 100, 170);
  cv::Mat right = bands(-10.0, 400.0, kWhite, kBlue, kWhite, 100, 170);
  for (int y = 100; y < 106; ++y)  // the wall's top edge crossing the rows of the goal's top
    for (int x = 0; x < 120; ++x) right.at<cv::Vec3b>(y, x) = kWhite;
  std::vector<GoalEdge> edges;
  std::vector<float> scratch;
  std::vector<Transition> tr;
  detectGoalEdges(left, GoalParams(), edges, scratch);
  ASSERT_EQ(edges.size(), 1u);
  EXPECT_EQ(edges[0].rows, 70);
  EXPECT_FALSE(matchGoalEdge(right, edges[0], range, GoalParams(), tr, scratch).has_value());
  GoalParams any_rows;
  any_rows.min_right_row_fraction = 0.0;  // what the few rows alone would give
  const auto wrong = matchGoalEdge(right, edges[0], range, any_rows, tr, scratch);
  ASSERT_TRUE(wrong.has_value());
  EXPECT_NEAR(*wrong, 120.0, 0.5);
  // Seen on 45 of its 70 rows, it is matched.
  right = bands(140.3 - 20.0, 400.0, kWhite, kBlue, kWhite, 100, 170);
  for (int y = 100; y < 125; ++y)
    for (int x = 0; x < 320; ++x) right.at<cv::Vec3b>(y, x) = kDark;
  const auto ur = matchGoalEdge(right, edges[0], range, GoalParams(), tr, scratch);
  ASSERT_TRUE(ur.has_value());
  EXPECT_NEAR(edges[0].u - *ur, 20.0, 0.05);
}
