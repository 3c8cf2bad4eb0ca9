#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "test_util.h"

namespace {
namespace fs = std::filesystem;

struct Result {
  int code = -1;
  std::string out;
};

Result run(const std::string& args) {
  const std::string cmd = std::string(STEREOLOC_BIN_DIR) + "/stereoloc " + args + " 2>&1";
  Result r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) r.out.append(buf, n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class CliSimulate : public ::testing::Test {
 protected:
  void SetUp() override {
    root = (fs::temp_directory_path() / ("stereoloc_cli_sim_" + std::to_string(::getpid()))).string();
    fs::remove_all(root);
    fs::create_directories(root);
  }
  void TearDown() override { fs::remove_all(root); }
  std::string root;
};

TEST_F(CliSimulate, SimulateThenInfo) {
  const Result s = run("simulate --scenario circle --seed 5 --out " + root + "/c");
  ASSERT_EQ(s.code, 0) << s.out;
  const Result i = run("info " + root + "/c");
  ASSERT_EQ(i.code, 0) << i.out;
  EXPECT_NE(i.out.find("steps: 100"), std::string::npos) << i.out;
  EXPECT_NE(i.out.find("steps without observations"), std::string::npos) << i.out;
  EXPECT_NE(i.out.find("blue_goal_y450"), std::string::npos) << i.out;
  EXPECT_NE(i.out.find("images: none"), std::string::npos) << i.out;
}

TEST_F(CliSimulate, SameSeedByteIdenticalAndRefusesOverwrite) {
  ASSERT_EQ(run("simulate --scenario rect-spin --trial b --seed 9 --obstacles 3 --out " + root + "/a").code, 0);
  ASSERT_EQ(run("simulate --scenario rect-spin --trial 1 --seed 9 --obstacles 3 --out " + root + "/b").code, 0);
  for (const char* f : {"dataset.yaml", "odometry.csv", "observations.csv", "compass.csv", "groundtruth.csv"})
    EXPECT_EQ(stereoloc::test::readFile(root + "/a/" + f), stereoloc::test::readFile(root + "/b/" + f)) << f;
  const Result again = run("simulate --scenario line --out " + root + "/a");
  EXPECT_EQ(again.code, 2) << again.out;
  EXPECT_NE(again.out.find("--force"), std::string::npos);
  EXPECT_EQ(run("simulate --scenario line --force --out " + root + "/a").code, 0);
  EXPECT_NE(stereoloc::test::readFile(root + "/a/dataset.yaml").find("name: line"), std::string::npos);
}

TEST_F(CliSimulate, ImagesWithGroundTruth) {
  for (const char* d : {"/i", "/j"}) {
    const Result r = run("simulate --scenario line --steps 3 --obstacles 1 --images --out " + root + d);
    ASSERT_EQ(r.code, 0) << r.out;
  }
  for (const char* f : {"images/left_000000.png", "images/right_000002.png", "images/truth_000001.json"}) {
    EXPECT_TRUE(fs::exists(root + "/i/" + f)) << f;
    EXPECT_EQ(stereoloc::test::readFile(root + "/i/" + f), stereoloc::test::readFile(root + "/j/" + f)) << f;
  }
  EXPECT_NE(stereoloc::test::readFile(root + "/i/images/truth_000000.json").find("\"goal_corner\""), std::string::npos);
  const Result i = run("info " + root + "/i");
  EXPECT_EQ(i.code, 0) << i.out;
  EXPECT_NE(i.out.find("images: 3 stereo pairs, every one readable"), std::string::npos) << i.out;
  fs::remove(root + "/i/images/right_000001.png");
  const Result bad = run("info " + root + "/i");
  EXPECT_EQ(bad.code, 1);
  EXPECT_NE(bad.out.find("right_000001.png"), std::string::npos) << bad.out;
  // An image that is there but does not decode is as bad as a missing one.
  fs::copy_file(root + "/i/images/left_000001.png", root + "/i/images/right_000001.png");
  std::ofstream(root + "/i/images/left_000002.png", std::ios::trunc) << "not a png";
  const Result corrupt = run("info " + root + "/i");
  EXPECT_EQ(corrupt.code, 1);
  EXPECT_NE(corrupt.out.find("left_000002.png"), std::string::npos) << corrupt.out;
}

TEST_F(CliSimulate, UsageAndDataErrors) {
  EXPECT_EQ(run("simulate --scenario nope --out " + root + "/x").code, 2);
  EXPECT_EQ(run("simulate --scenario rect --trial e --out " + root + "/x").code, 2);
  EXPECT_EQ(run("simulate --scenario circle").code, 2);
  EXPECT_FALSE(fs::exists(root + "/x"));
  ASSERT_EQ(run("simulate --scenario spin --out " + root + "/s").code, 0);
  {
    std::ofstream out(root + "/s/compass.csv", std::ios::app);
    out << "1000,1,0.5\n";
  }
  const Result bad = run("info " + root + "/s");
  EXPECT_EQ(bad.code, 1);
  EXPECT_NE(bad.out.find("compass.csv:102: step 1000 is not in odometry.csv"), std::string::npos) << bad.out;
  EXPECT_EQ(run("info " + root + "/missing").code, 1);
}

}  // namespace
