// JSON Lines of the real-time stream (src/pipeline/stream_io.h): what a line may carry, the
// one-line errors, and estimates written so that they read back exactly.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "src/core/error.h"
#include "src/pipeline/stream_io.h"

namespace stereoloc {
namespace {

std::string errorOf(const std::string& line) {
  try {
    parseStreamLine(line, StereoRig(), 0.0);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(StreamIo, PixelObservationsCarryTheirSlideGain) {
  const StereoRig rig;
  const std::string px = R"("u_left":180,"v_left":150,"u_right":170,"v_right":150)";
  const StreamLine a = parseStreamLine(R"({"step":1,"d_left":1,"d_right":1,"observations":[{)" + px +
                                           R"(,"slide_gain":-0.75},{)" + px + R"(}]})",
                                       rig, 0.0);
  ASSERT_EQ(a.observations.size(), 2u);
  EXPECT_EQ(a.observations[0].slide_gain, -0.75);
  EXPECT_EQ(a.observations[1].slide_gain, 0.0);
  const std::string bad = errorOf(R"({"step":1,"d_left":1,"d_right":1,"observations":[{)" + px + R"(,"slide_gain":"x"}]})");
  EXPECT_NE(bad.find("slide_gain"), std::string::npos) << bad;
}

TEST(StreamIo, ParsesOdometryObservationsAndLateImages) {
  const StereoRig rig;
  const StreamLine a = parseStreamLine(
      R"({"step":12,"t":1.2,"d_left":10.5,"d_right":-3,"compass":0.3,"head_pan":0.1,)"
      R"("observations":[{"landmark_id":3,"range":800,"bearing":-0.2,"sigma_range":20,"sigma_bearing":0.01}]})",
      rig, 0.05);
  EXPECT_TRUE(a.has_odometry);
  EXPECT_EQ(a.step.step, 12);
  EXPECT_EQ(a.obs_step, 12);
  EXPECT_EQ(a.step.d_right, -3.0);
  EXPECT_EQ(a.step.compass_sigma, 0.05);  // the default sigma
  ASSERT_EQ(a.observations.size(), 1u);
  EXPECT_EQ(a.observations[0].landmark_id, 3);
  EXPECT_EQ(a.observations[0].covariance(0, 0), 400.0);
  EXPECT_TRUE(a.observations[0].covariance.allFinite());

  const StreamLine b =
      parseStreamLine(R"({"step":13,"d_left":1,"d_right":1,"obs_step":11,"left":"l.png","right":"r.png"})", rig, 0);
  EXPECT_EQ(b.obs_step, 11);
  EXPECT_EQ(b.left_image, "l.png");
  EXPECT_TRUE(b.hasObservationData());

  const StreamLine c = parseStreamLine(R"({"obs_step":9,"observations":[{"range":500,"bearing":0.1,)"
                                       R"("sigma_range":5,"sigma_bearing":0.01,"type":"point"}]})",
                                       rig, 0);
  EXPECT_FALSE(c.has_odometry);
  EXPECT_EQ(c.obs_step, 9);
  EXPECT_EQ(c.observations.at(0).landmark_id, -1);
}

TEST(StreamIo, BadLinesSayWhatIsWrong) {
  EXPECT_NE(errorOf("not json").find("column 1"), std::string::npos);
  EXPECT_NE(errorOf("[1,2]").find("JSON object"), std::string::npos);
  EXPECT_NE(errorOf(R"({"step":1,"d_left":1})").find("\"d_right\""), std::string::npos);
  EXPECT_NE(errorOf(R"({"step":1.5,"d_left":1,"d_right":1})").find("integer"), std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"obs_step":4,"left":"a","right":"b"})").find("after"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"left":"a"})").find("together"), std::string::npos);
  EXPECT_NE(errorOf(R"({"obs_step":3})").find("without observations"), std::string::npos);
  EXPECT_NE(errorOf(R"({"t":3})").find("missing"), std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"left":"a","right":"b","observations":[]})").find("not both"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"observations":[{"range":-1,"bearing":0,)"
                    R"("sigma_range":1,"sigma_bearing":1}]})")
                .find("observations[0]"),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"compass":0.1})").find("compass_sigma"), std::string::npos);
  // A sigma whose inverse square overflows, or one that says nothing.
  for (const char* sigma : {"1e-300", "1e300"})
    EXPECT_NE(errorOf(std::string(R"({"step":3,"d_left":1,"d_right":1,"compass":0.1,"compass_sigma":)") + sigma + "}")
                  .find("within [1e-06, 2 pi] rad"),
              std::string::npos)
        << sigma;
}

// Strict JSON: a number strtod would read but JSON does not write, or a key given twice, is an
// error at its column, not a value.
TEST(StreamIo, NumbersAndKeysAreStrictJson) {
  for (const char* number : {"NaN", "nan", "Infinity", "inf", "0x10", ".5", "+1", "1.", "1e", "-", "1.e3"}) {
    const std::string e = errorOf(std::string(R"({"step":3,"d_left":)") + number + R"(,"d_right":1})");
    EXPECT_EQ(e.rfind("column 2", 0), 0u) << number << ": " << e;  // at the number (column 20) or just after
  }
  EXPECT_NE(errorOf(R"({"step":3,"d_left":01,"d_right":1})").find("column 21: expected ',' or '}'"), std::string::npos);
  for (const char* number : {"0", "-0", "12", "-1.5", "1e3", "1E-3", "2.5e+2", "0.125"})
    EXPECT_EQ(errorOf(std::string(R"({"step":3,"d_left":)") + number + R"(,"d_right":1})"), "") << number;
  EXPECT_DOUBLE_EQ(parseStreamLine(R"({"step":3,"d_left":2.5e+2,"d_right":-0.125})", StereoRig(), 0).step.d_left, 250);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"step":2})").find("duplicate key \"step\""),
            std::string::npos);
  EXPECT_NE(errorOf(R"({"step":3,"d_left":1,"d_right":1,"observations":[{"range":800,"range":9,"bearing":0,)"
                    R"("sigma_range":1,"sigma_bearing":1}]})")
                .find("duplicate key \"range\""),
            std::string::npos);
}

TEST(StreamIo, EstimatesReadBackExactly) {
  Estimate e;
  e.step = 7;
  e.t = 0.1;
  e.pose = Pose2(1.0 / 3.0, -2.0e-7, 3.0);
  e.covariance = Eigen::Matrix3d::Identity() * (1.0 / 7.0);
  e.status = EstimateStatus::Tracking;
  StreamOutputExtras x;
  x.compute_ms = 1.25;
  x.obs_step = 5;
  x.late = "inserted";
  const std::string line = formatStreamEstimate(e, x);
  const std::string back = R"({"step":7,"t":0.10000000000000001,"x":0.33333333333333331,"y":-1.9999999999999999e-07,)"
                           R"("theta":3,"covariance":[0.14285714285714285,0,0,0,0.14285714285714285,0,0,0,)"
                           R"(0.14285714285714285],"status":"tracking","compute_ms":1.2500,"obs_step":5,"late":"inserted"})"
                           "\n";
  EXPECT_EQ(line, back);
  Estimate none;
  EXPECT_EQ(formatStreamEstimate(none), "{\"step\":0,\"t\":0,\"status\":\"uninitialised\"}\n");
}

}  // namespace
}  // namespace stereoloc
