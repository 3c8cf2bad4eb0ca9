// Usage errors every command shares: an option given an empty value or a number that is not
// finite, names a command does not know, options that exclude each other, options the run
// would not use. Each is exit code 2 with one line naming the option, before anything runs or
// is written.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

class CliUsage : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new test::TempDir("cli_usage");
    const test::CliRun sim = test::runCli("simulate --scenario line --steps 20 --seed 2 --out " + dataset());
    ASSERT_EQ(sim.exit_code, 0) << sim.output;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static std::string dataset() { return dir_->file("line"); }
  static std::string file(const std::string& name) { return dir_->file(name); }
  static test::TempDir* dir_;
};
test::TempDir* CliUsage::dir_ = nullptr;

size_t lines(const std::string& text) {
  size_t n = 0;
  for (char c : text) n += c == '\n';
  return n;
}

TEST_F(CliUsage, AnEmptyValueOrANonFiniteNumberIsRefusedNamingTheOption) {
  const test::CliRun csv = test::runCli("realdata " + dataset() + " --csv ''");
  EXPECT_EQ(csv.exit_code, 2);
  EXPECT_EQ(csv.output, "stereoloc: --csv: empty value (see --help)\n");
  const test::CliRun out = test::runCli("localize " + dataset() + " --method ekf --out ''");
  EXPECT_EQ(out.exit_code, 2);
  EXPECT_NE(out.output.find("--out: empty value"), std::string::npos) << out.output;
  const test::CliRun positional = test::runCli("info ''");
  EXPECT_EQ(positional.exit_code, 2);
  EXPECT_NE(positional.output.find("DIR: empty value"), std::string::npos) << positional.output;
  for (const char* value : {"nan", "inf", "-inf", "NaN"}) {
    const test::CliRun pose = test::runCli("stream --from " + dataset() + " --init known --pose 190," + value + ",3");
    EXPECT_EQ(pose.exit_code, 2) << value;
    EXPECT_EQ(pose.output, std::string("stereoloc: --pose: '") + value + "' is not a finite number (see --help)\n");
  }
  const test::CliRun loss = test::runCli("localize " + dataset() + " --method batch --loss huber --loss-scale nan --out " +
                                         file("nan.csv"));
  EXPECT_EQ(loss.exit_code, 2);
  EXPECT_NE(loss.output.find("--loss-scale: 'nan' is not a finite number"), std::string::npos) << loss.output;
  EXPECT_FALSE(std::filesystem::exists(file("nan.csv")));
  // The same options with values run.
  const test::CliRun flag = test::runCli("localize " + dataset() + " --method ekf --tum " + file("t.txt") +
                                         " --out " + file("ekf.csv"));
  EXPECT_EQ(flag.exit_code, 0) << flag.output;
  EXPECT_TRUE(std::filesystem::exists(file("ekf.csv")));
}

// Numbers outside what an option means are usage errors naming the option, before anything runs
// (a blur of a million pixels took minutes, a compass sigma of -1 failed every input line).
TEST_F(CliUsage, NumbersOutsideTheirMeaningAreRefusedNamingTheOption) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"localize " + dataset() + " --method window --window 0 --out " + file("w.csv"), "--window: must be positive, not 0"},
      {"localize " + dataset() + " --method pf --particles 50 --out " + file("p.csv"), "--particles"},
      {"simulate --scenario line --steps 3 --images --image-blur 1e6 --force --out " + file("blur"), "--image-blur"},
      {"stream --from " + dataset() + " --compass-sigma -1", "--compass-sigma"},
      {"stream --compass-sigma 1e-300", "--compass-sigma"},
      {"stream --wheel-base 1e-300", "--wheel-base"},
      {"stream --pose-sigma 1e300,1,1", "--pose-sigma"},
      {"localize " + dataset() + " --method batch --pixel-sigma 1e-300 --out " + file("s.csv"), "--pixel-sigma"},
      {"simulate --scenario line --steps 3 --seed -1 --force --out " + file("seed"), "--seed"},
      {"simulate --scenario line --steps 3 --seed 18446744073709551616 --force --out " + file("seed"), "--seed"}};
  for (const auto& [command, option] : cases) {
    const test::CliRun r = test::runCli(command);
    EXPECT_EQ(r.exit_code, 2) << command << "\n" << r.output;
    EXPECT_EQ(r.output.rfind("stereoloc: " + option, 0), 0u) << r.output;
    EXPECT_EQ(lines(r.output), 1u) << r.output;
  }
}

TEST_F(CliUsage, RealdataRunsOnlyEstimatorsItKnows) {
  const test::CliRun unknown = test::runCli("realdata " + dataset() + " --only ekf,kalman");
  EXPECT_EQ(unknown.exit_code, 2);
  EXPECT_EQ(unknown.output, "stereoloc: --only: unknown estimator 'kalman' (see --help)\n");
  EXPECT_EQ(test::runCli("realdata " + dataset() + " --only ekf,").exit_code, 2);
  const test::CliRun known = test::runCli("realdata " + dataset() + " --only ekf,batch_calib --csv " + file("r.csv"));
  EXPECT_EQ(known.exit_code, 0) << known.output;
  // Both rows and nothing else: the header and two estimators.
  std::ifstream in(file("r.csv"));
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(lines(text), 3u) << text;
  EXPECT_NE(text.find("\nekf,"), std::string::npos) << text;
  EXPECT_NE(text.find("\nbatch_calib,"), std::string::npos) << text;
}

// An option of an estimator --only leaves out, before anything runs; the same option with its
// estimator runs.
TEST_F(CliUsage, RealdataRefusesTheOptionsOfEstimatorsItDoesNotRun) {
  struct Case {
    const char *args, *message;
  };
  for (const Case& c :
       {Case{"--only ekf,batch --window 10", "--window: for the window's estimators only"},
        Case{"--only pf --keyframe-max-steps 3", "--keyframe-max-steps: for the window's estimators only"},
        Case{"--only batch --no-gate", "--no-gate: for the EKF's and the window's estimators only"},
        Case{"--only ekf --particles 500", "--particles: for the particle filter only"},
        Case{"--only ekf --seed 4", "--seed: for the particle filter only"},
        Case{"--only window,batch --robust cauchy", "--robust: for the robust window and batch only"},
        Case{"--only window --batch-guess odometry",
             "--batch-guess: for the batch's estimators and --odometry-delay fit only"}}) {
    const test::CliRun r = test::runCli("realdata " + dataset() + " " + c.args + " --csv " + file("refused.csv"));
    EXPECT_EQ(r.exit_code, 2) << c.args;
    EXPECT_EQ(r.output, std::string("stereoloc: ") + c.message + " (--only lists none) (see --help)\n") << c.args;
    EXPECT_FALSE(std::filesystem::exists(file("refused.csv"))) << c.args;
  }
  // An unknown key is named before an option it would leave unused.
  EXPECT_EQ(test::runCli("realdata " + dataset() + " --only kalman --window 10").output,
            "stereoloc: --only: unknown estimator 'kalman' (see --help)\n");
  for (const char* args : {"--only window_online --window 10 --keyframe-max-steps 3 --window-lost-after 4 --no-gate",
                           "--only pf --particles 200 --seed 4", "--only batch_robust --robust cauchy --robust-scale 2",
                           "--only ekf_calib --no-gate", "--only batch_calib --batch-guess odometry",
                           "--window 10 --particles 200"}) {
    const test::CliRun r = test::runCli("realdata " + dataset() + " " + args);
    EXPECT_EQ(r.exit_code, 0) << args << "\n" << r.output;
  }
}

// An image option on a run without images, a pixel option on one without simulated pixels: an
// error naming the option, before anything runs.
TEST_F(CliUsage, FrontendOptionsNeedTheFrontend) {
  const std::pair<std::string, std::string> cases[] = {
      {"study --frontend pixels --frontend-landmarks goal_corners --trials 1 --scenarios line --out " + file("s"),
       "--frontend-landmarks: for --frontend images only"},
      {"study --frontend pixels --image-noise 2 --trials 1 --scenarios line --out " + file("s"),
       "--image-noise: for --frontend images only"},
      {"fixstudy --frontend pixels --image-noise 2 --runs 1 --category rect", "--image-noise: for --frontend images"},
      {"fixstudy --frontend images --pixel-sigma 1 --runs 1 --category rect", "--pixel-sigma: for --frontend pixels"},
      {"fixstudy --frontend images --calibrate none --runs 1 --category rect",
       "--calibrate: for --frontend images or both in a world that is not ideal only"},
      {"stream --from " + dataset() + " --frontend-params " + std::string(STEREOLOC_DATA_DIR) + "/frontend_default.yaml",
       "--frontend-params: for --frontend images only"},
      {"localize " + dataset() + " --method ekf --frontend-landmarks all --out " + file("f.csv"),
       "--frontend-landmarks: for --frontend images only"}};
  for (const auto& [args, message] : cases) {
    const test::CliRun r = test::runCli(args);
    EXPECT_EQ(r.exit_code, 2) << args;
    EXPECT_NE(r.output.find(message), std::string::npos) << args << ": " << r.output;
  }
  EXPECT_FALSE(std::filesystem::exists(file("s")));
  EXPECT_FALSE(std::filesystem::exists(file("f.csv")));
}

// A study's method options need a listed method that uses them.
TEST_F(CliUsage, StudyMethodOptionsNeedTheirMethod) {
  const test::CliRun pf = test::runCli("study --methods ekf,batch --particles 100 --trials 1 --out " + file("s"));
  EXPECT_EQ(pf.exit_code, 2);
  EXPECT_EQ(pf.output, "stereoloc: --particles: for studies with the particle filter only (--methods ekf,batch) (see --help)\n");
  EXPECT_EQ(test::runCli("study --methods ekf,pf:global --window 5 --trials 1 --out " + file("s")).exit_code, 2);
  EXPECT_FALSE(std::filesystem::exists(file("s")));
  const test::CliRun ok = test::runCli("study --methods ekf,window:calib --window 5 --frontend pixels --scenarios line "
                                       "--trials 1 --out " + file("s"));
  EXPECT_EQ(ok.exit_code, 0) << ok.output;
}

TEST_F(CliUsage, StreamTakesItsSetupFromOneSource) {
  const test::CliRun both = test::runCli("stream --from " + dataset() + " --setup " + dataset());
  EXPECT_EQ(both.exit_code, 2);
  EXPECT_NE(both.output.find("--from excludes --setup"), std::string::npos) << both.output;
  EXPECT_EQ(lines(both.output), 1u) << both.output;
  // The dataset gives the map and the wheel base: one given beside it would be ignored.
  const test::CliRun map = test::runCli("stream --from " + dataset() + " --map " + std::string(STEREOLOC_DATA_DIR) +
                                        "/field_mirosot.yaml");
  EXPECT_EQ(map.exit_code, 2);
  EXPECT_NE(map.output.find("--from excludes --map"), std::string::npos) << map.output;
  const test::CliRun wheels = test::runCli("stream --setup " + dataset() + " --wheel-base 80 < /dev/null");
  EXPECT_EQ(wheels.exit_code, 2);
  EXPECT_NE(wheels.output.find("--setup excludes --wheel-base"), std::string::npos) << wheels.output;
}

}  // namespace
}  // namespace stereoloc
