// `--frontend images`: localize, refine, stream --from and study run the vision frontend on
// rendered stereo pairs (src/pipeline/frontend_source.h) instead of the simulated pixels.
// Small on purpose (a few dozen pairs); the accuracy study itself is `make demo`.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <opencv2/core.hpp>
#include <sstream>
#include <vector>

#include "cli_util.h"
#include "src/io/image_file.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// One small dataset with images shared by the tests: `line` drives towards a goal and sees its
// corners from the first step (thesis 6.5.2).
class FrontendImages : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::TempDir("frontend_images");
    const test::CliRun r =
        test::runCli("simulate --scenario line --steps 25 --seed 5 --images --out " + dir_->file("d"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  // Largest position error (mm) of an estimates CSV against the dataset's ground truth, and
  // the number of compared rows; -1 on a non-finite value.
  static std::pair<double, int> maxError(const std::string& est_csv) {
    const auto truth = test::readRows(dir_->file("d/groundtruth.csv"));
    double worst = 0;
    int n = 0;
    for (const auto& [step, e] : test::readRows(est_csv)) {
      for (double v : e)
        if (!std::isfinite(v)) return {-1, n};
      const auto it = truth.find(step);
      if (it == truth.end()) continue;
      worst = std::max(worst, std::hypot(e[2] - it->second[2], e[3] - it->second[3]));
      ++n;
    }
    return {worst, n};
  }
  static test::TempDir* dir_;
};
test::TempDir* FrontendImages::dir_ = nullptr;

TEST_F(FrontendImages, LocalizeEveryTrackerFromImagesStaysCloseToTruth) {
  for (const char* m : {"ekf", "pf", "window", "batch"}) {
    const std::string out = dir_->file(std::string(m) + ".csv");
    const test::CliRun r = test::runCli("localize " + dir_->file("d") + " --method " + m +
                                        " --frontend images --out " + out);
    ASSERT_EQ(r.exit_code, 0) << m << ": " << r.output;
    EXPECT_NE(r.output.find("frontend on 25 image pairs"), std::string::npos) << r.output;
    const auto [worst, n] = maxError(out);
    EXPECT_EQ(n, 25) << m;
    EXPECT_GE(worst, 0) << m << ": non-finite estimate";
    // Known start (30 mm, 5 deg noise) and goal corners at 0.5-1.5 m: well inside 150 mm.
    EXPECT_LT(worst, 150.0) << m;
  }
}

TEST_F(FrontendImages, GlobalFixesFromImagesAreCloseToTruth) {
  // One goal corner + compass (section 4.3.2): `line` sees one goal corner on almost every step.
  const std::string out = dir_->file("fix1.csv");
  const test::CliRun r =
      test::runCli("localize " + dir_->file("d") + " --method fix1 --frontend images --out " + out);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto [worst, n] = maxError(out);
  EXPECT_GE(n, 20) << r.output;
  EXPECT_GE(worst, 0);
  EXPECT_LT(worst, 200.0);
}

TEST_F(FrontendImages, RefineAndStreamAcceptTheImageFrontend) {
  const test::CliRun r = test::runCli("refine " + dir_->file("d") + " --frontend images --frontend-landmarks goal_corners --out " +
                                      dir_->file("refine.csv"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_LT(maxError(dir_->file("refine.csv")).first, 150.0);
  const test::CliRun s = test::runCli("stream --from " + dir_->file("d") + " --frontend images --window 5");
  ASSERT_EQ(s.exit_code, 0) << s.output;
  EXPECT_EQ(std::count(s.output.begin(), s.output.end(), '\n'), 26) << "25 estimates + the frontend summary\n" << s.output;
  EXPECT_EQ(s.output.find("null"), std::string::npos) << s.output;
  // Images only come with a dataset.
  EXPECT_EQ(test::runCli("stream --frontend images").exit_code, 2);
}

TEST(FrontendImagesErrors, MissingUnreadableOrWrongSizeImageIsOneLineNamingTheFile) {
  test::TempDir dir("frontend_images_err");
  ASSERT_EQ(test::runCli("simulate --scenario line --steps 4 --seed 2 --images --out " + dir.file("d")).exit_code, 0);
  const std::string left2 = dir.file("d/images/left_000002.png");
  // Wrong size.
  writePngFile(left2, cv::Mat(100, 120, CV_8UC3, cv::Scalar(0, 128, 0)));
  test::CliRun r = test::runCli("localize " + dir.file("d") + " --method ekf --frontend images --out " + dir.file("e.csv"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("left_000002.png"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("120x100"), std::string::npos) << r.output;
  // Not an image.
  std::ofstream(left2) << "not a png";
  r = test::runCli("localize " + dir.file("d") + " --method ekf --frontend images --out " + dir.file("e.csv"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("left_000002.png"), std::string::npos) << r.output;
  // Missing.
  std::filesystem::remove(dir.file("d/images/right_000003.png"));
  r = test::runCli("localize " + dir.file("d") + " --method ekf --frontend images --out " + dir.file("e.csv"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("right_000003.png"), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;

  // A dataset without images.
  ASSERT_EQ(test::runCli("simulate --scenario line --steps 4 --seed 2 --out " + dir.file("p")).exit_code, 0);
  r = test::runCli("localize " + dir.file("p") + " --method ekf --frontend images --out " + dir.file("e.csv"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no images"), std::string::npos) << r.output;
  EXPECT_EQ(test::runCli("localize " + dir.file("p") + " --frontend video --out " + dir.file("e.csv")).exit_code, 2);
}

TEST(StudyImages, RendersRunsTheFrontendAndIsIdenticalWhateverTheThreadCount) {
  test::TempDir dir("study_images");
  const std::string args = "study --scenarios line --methods fix2,ekf,window --trials 2 --seed 3 --no-progress --frontend images";
  const test::CliRun one = test::runCli(args + " --threads 1 --out " + dir.file("one"));
  ASSERT_EQ(one.exit_code, 0) << one.output;
  EXPECT_NE(one.output.find("report: "), std::string::npos) << one.output;
  const test::CliRun two = test::runCli(args + " --threads 2 --out " + dir.file("two"));
  ASSERT_EQ(two.exit_code, 0) << two.output;
  EXPECT_EQ(test::readFile(dir.file("one/steps.csv")), test::readFile(dir.file("two/steps.csv")));
  EXPECT_NE(test::readFile(dir.file("one/report.md")).find("vision frontend"), std::string::npos);
  // Every method produced estimates close to the truth (summary: position RMSE, column 5).
  std::stringstream summary(test::readFile(dir.file("one/summary.csv")));
  std::string line;
  std::getline(summary, line);
  int rows = 0;
  while (std::getline(summary, line)) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    std::string x;
    while (std::getline(ls, x, ',')) f.push_back(x);
    ASSERT_GE(f.size(), 5u) << line;
    const double rmse = std::stod(f[4]);
    EXPECT_TRUE(std::isfinite(rmse)) << line;
    EXPECT_GT(rmse, 0.0) << line;
    EXPECT_LT(rmse, 150.0) << line;
    ++rows;
  }
  EXPECT_EQ(rows, 3);
}

}  // namespace
}  // namespace stereoloc
