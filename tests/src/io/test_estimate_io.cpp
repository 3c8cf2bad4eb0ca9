#include <gtest/gtest.h>

#include <fstream>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/io/estimate_io.h"
#include "test_util.h"

namespace stereoloc {

TEST(EstimateIo, CsvRoundTripIsExact) {
  test::TempDir dir;
  std::vector<Estimate> est(3);
  for (int i = 0; i < 3; ++i) {
    est[i].step = i * 2;
    est[i].t = 0.1 * i + 1.0 / 3.0;
    est[i].pose = Pose2(1000.0 / 7 * i, -3.25 * i, 0.1 * i - 3.0);
    est[i].covariance << 10 + i, 1.0 / 3, 0.01, 1.0 / 3, 20, -0.02, 0.01, -0.02, 1e-3;
    est[i].status = EstimateStatus::Tracking;
  }
  Estimate uninit = est[2];
  uninit.step = 99;
  uninit.status = EstimateStatus::Uninitialised;
  est.push_back(uninit);
  writeEstimatesCsv(dir.file("e.csv"), est);
  const auto back = readEstimatesCsv(dir.file("e.csv"));
  ASSERT_EQ(back.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(back[i].step, est[i].step);
    EXPECT_EQ(back[i].t, est[i].t);
    EXPECT_EQ(back[i].pose.x, est[i].pose.x);
    EXPECT_EQ(back[i].pose.theta, est[i].pose.theta);
    EXPECT_EQ(back[i].covariance, est[i].covariance);
  }
}

TEST(EstimateIo, TumRowIsMetresAndUnitQuaternion) {
  Estimate e;
  e.t = 2.5;
  e.pose = Pose2(1500, -250, kPi / 2);
  EXPECT_EQ(estimateTumRow(e), "2.500000000 1.500000000 -0.250000000 0 0 0 0.707106781187 0.707106781187");
}

TEST(EstimateIo, MalformedCsvNamesFileAndLine) {
  test::TempDir dir;
  const std::string h = std::string(kEstimateCsvHeader) + "\n";
  auto expectError = [&](const std::string& body, const std::string& needle) {
    writeFileAtomically(dir.file("bad.csv"), body);
    try {
      readEstimatesCsv(dir.file("bad.csv"));
      ADD_FAILURE() << "no error for: " << body;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expectError("x,y\n", "bad.csv:1:");
  expectError(h + "0,0,1,2,3,1,0,0,1,0\n", "bad.csv:2: expected 11 columns");
  expectError(h + "0,0,1,2,abc,1,0,0,1,0,1\n", "bad.csv:2: field 5 is not a number");
  expectError(h + "0,0,1,2,nan,1,0,0,1,0,1\n", "bad.csv:2: field 5 is not finite");
  expectError(h + "1,0,1,2,0,1,0,0,1,0,1\n0,0,1,2,0,1,0,0,1,0,1\n", "bad.csv:3: steps out of order");
}

}  // namespace stereoloc
