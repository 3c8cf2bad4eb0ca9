#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
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

TEST(EstimateIo, CsvRowHasThePrintfDigits) {
  Estimate e;
  e.step = 123456;
  e.t = 1234.5678901234567;
  e.pose = Pose2(-0.0, 1.0 / 3.0, -3.1415926535897931);
  e.covariance << 1e-300, 2.5e-7, -0.0, 2.5e-7, 1e21, 7.0, -0.0, 7.0, 0.1;
  const Eigen::Matrix3d& P = e.covariance;
  char expected[512];
  std::snprintf(expected, sizeof(expected), "%ld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g", e.step, e.t,
                e.pose.x, e.pose.y, e.pose.theta, P(0, 0), P(0, 1), P(0, 2), P(1, 1), P(1, 2), P(2, 2));
  EXPECT_EQ(estimateCsvRow(e), expected);
  char tum[256];
  std::snprintf(tum, sizeof(tum), "%.9f %.9f %.9f 0 0 0 %.12f %.12f", e.t, e.pose.x * 1e-3, e.pose.y * 1e-3,
                std::sin(0.5 * e.pose.theta), std::cos(0.5 * e.pose.theta));
  EXPECT_EQ(estimateTumRow(e), tum);
}

TEST(EstimateIo, LongFilesRoundTripThroughTheWriteBuffer) {
  test::TempDir dir;
  std::vector<Estimate> est(30000);  // several buffer flushes
  for (size_t i = 0; i < est.size(); ++i) {
    est[i].step = static_cast<long>(i);
    est[i].t = 0.01 * static_cast<double>(i);
    est[i].pose = Pose2(std::sqrt(static_cast<double>(i)), -1.0 / (1.0 + static_cast<double>(i)), std::sin(static_cast<double>(i)));
    est[i].covariance = Eigen::Matrix3d::Identity() * (1.0 + 1e-3 * static_cast<double>(i));
    est[i].status = EstimateStatus::Tracking;
  }
  writeEstimatesCsv(dir.file("long.csv"), est);
  const auto back = readEstimatesCsv(dir.file("long.csv"));
  ASSERT_EQ(back.size(), est.size());
  for (size_t i = 0; i < est.size(); ++i) {
    ASSERT_EQ(back[i].pose.x, est[i].pose.x);
    ASSERT_EQ(back[i].pose.y, est[i].pose.y);
    ASSERT_EQ(back[i].pose.theta, est[i].pose.theta);
    ASSERT_EQ(back[i].covariance, est[i].covariance);
  }
}

}  // namespace stereoloc
