// The text forms of a frontend result: every segment, feature and observation appears in both,
// with the units each form states.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "frontend/detection_text.h"

namespace stereoloc::frontend {
namespace {

FrontendResult sampleResult() {
  FrontendResult r;
  LineFeature marking;  // the horizontal line y = 100 from x = 60 to x = 10 (t runs along -x)
  marking.theta = 0.5 * M_PI;
  marking.rho = 100;
  marking.t_min = -60;
  marking.t_max = -10;
  marking.marking = true;
  r.lines.push_back(marking);
  PointFeature goal;
  goal.type = LandmarkType::GoalCorner;
  goal.u = 120.25;
  goal.v = 80.5;
  goal.color = GoalColor::Yellow;
  goal.landmark_id = 3;
  r.features.push_back(goal);
  Observation seen;
  seen.type = LandmarkType::GoalCorner;
  seen.landmark_id = 3;
  seen.range = 1234.5;
  seen.bearing = 0.25;
  seen.covariance << 400.0, 0.01, 0.01, 1e-4;
  seen.pixels = StereoPixels{120.25, 80.5, 108.75, 80.5};
  r.observations.push_back(seen);
  Observation bare = seen;  // no pixels
  bare.pixels.reset();
  bare.landmark_id = -1;
  r.observations.push_back(bare);
  return r;
}

TEST(DetectionText, TableListsEverythingWithBearingInDegrees) {
  const std::string t = detectionsTable(sampleResult());
  EXPECT_NE(t.find("segments (left image, px): 1"), std::string::npos) << t;
  EXPECT_NE(t.find("marking"), std::string::npos) << t;
  EXPECT_NE(t.find("goal_corner  u  120.25 v   80.50  yellow landmark 3"), std::string::npos) << t;
  EXPECT_NE(t.find("observations: 2"), std::string::npos) << t;
  // 0.25 rad = 14.32 deg; sigma_r = sqrt(400) = 20 mm.
  EXPECT_NE(t.find("1234.5        14.32  120.25   108.75   80.50        20.0"), std::string::npos) << t;
  // Without pixels the pixel columns hold a dash and the row keeps its width.
  EXPECT_NE(t.find("14.32       -        -       -        20.0"), std::string::npos) << t;
}

TEST(DetectionText, JsonListsEverythingWithBearingInRadians) {
  const std::string j = detectionsJson(sampleResult());
  EXPECT_EQ(j.front(), '{');
  EXPECT_EQ(j.back(), '\n');
  EXPECT_NE(j.find("{\"x1\": 60.000, \"y1\": 100.000, \"x2\": 10.000, \"y2\": 100.000, \"marking\": true}"), std::string::npos)
      << j;
  EXPECT_NE(j.find("\"color\": \"yellow\""), std::string::npos) << j;
  EXPECT_NE(j.find("\"range\": 1234.500, \"bearing\": 0.250000, \"u_left\": 120.250"), std::string::npos) << j;
  // The observation without pixels has no pixel keys.
  size_t pixel_keys = 0;
  for (size_t p = j.find("\"u_left\""); p != std::string::npos; p = j.find("\"u_left\"", p + 1)) ++pixel_keys;
  EXPECT_EQ(pixel_keys, 1u) << j;
  EXPECT_NE(j.find("\"landmark_id\": -1, \"range\": 1234.500, \"bearing\": 0.250000, \"covariance\""), std::string::npos) << j;
}

}  // namespace
}  // namespace stereoloc::frontend
