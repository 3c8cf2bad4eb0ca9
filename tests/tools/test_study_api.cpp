// The accuracy study run through the library (src/study/study.h) and through `stereoloc study`
// writes the same files, byte for byte apart from the wall-clock timing columns.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "cli_util.h"
#include "src/study/study.h"
#include "test_util.h"

namespace stereoloc {
namespace {

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Drops the 0-based column `col` of every CSV line (the ms_per_step timing).
std::string withoutColumn(const std::string& csv, size_t col) {
  std::istringstream in(csv);
  std::string line, out;
  while (std::getline(in, line)) {
    size_t start = 0;
    for (size_t k = 0; k < col; ++k) start = line.find(',', start) + 1;
    const size_t end = line.find(',', start);
    out += line.substr(0, start) + (end == std::string::npos ? "" : line.substr(end + 1)) + "\n";
  }
  return out;
}

// report.md: the ms/step column is the only number printed with three decimals.
std::string withoutTimings(const std::string& md) { return std::regex_replace(md, std::regex("[0-9]+\\.[0-9]{3}\\b"), "T"); }

TEST(StudyApi, LibraryAndCommandLineWriteTheSameFiles) {
  test::TempDir dir;
  StudyConfig c;
  c.scenarios = {"circle", "line"};
  c.methods = {"fix2", "ekf", "pf", "batch"};
  c.trials = 2;
  c.seed = 5;
  c.threads = 1;
  c.frontend = "pixels";
  c.method_options.particles = 200;
  c.out_dir = dir.file("api");
  c.log = nullptr;
  const StudyResult api = runStudy(c);
  EXPECT_EQ(api.trial_rows, 16u);
  ASSERT_EQ(api.summary.size(), 8u);
  EXPECT_EQ(api.report, c.out_dir + "/report.md");

  const test::CliRun r = test::runCli(
      "study --scenarios circle,line --methods fix2,ekf,pf,batch --trials 2 --seed 5 --threads 2 --particles 200 "
      "--frontend pixels --no-progress --out " + dir.file("cli"));
  ASSERT_EQ(r.exit_code, 0) << r.output;

  size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(c.out_dir)) {
    const std::string name = e.path().filename().string();
    const std::string a = slurp(e.path().string()), b = slurp(dir.file("cli/" + name));
    ASSERT_FALSE(b.empty()) << name << " missing from the command line's study";
    ++files;
    if (name == "trials.csv")
      EXPECT_EQ(withoutColumn(a, 25), withoutColumn(b, 25)) << name;
    else if (name == "summary.csv")
      EXPECT_EQ(withoutColumn(a, 11), withoutColumn(b, 11)) << name;
    else if (name == "report.md")
      EXPECT_EQ(withoutTimings(a), withoutTimings(b)) << name;
    else
      EXPECT_TRUE(a == b) << name << " differs";
  }
  EXPECT_GE(files, 10u);  // yaml, 3 CSV, report and the figures
}

}  // namespace
}  // namespace stereoloc
