// The accuracy study run through the library (src/study/study.h) and through `stereoloc study`
// writes the same files, byte for byte apart from the wall-clock timing columns.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <cctype>
#include <sstream>

#include "cli_util.h"
#include "src/study/study.h"
#include "test_util.h"

namespace stereoloc {
namespace {

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
// Every number with exactly three decimals (the report's timings) becomes "T": the regular
// expression [0-9]+\.[0-9]{3}\b, written out (std::regex trips GCC 12's uninitialised-use
// warning under the sanitizers).
std::string withoutTimings(const std::string& md) {
  auto digit = [&](size_t k) { return k < md.size() && std::isdigit(static_cast<unsigned char>(md[k])) != 0; };
  auto word = [&](size_t k) { return k < md.size() && (std::isalnum(static_cast<unsigned char>(md[k])) != 0 || md[k] == '_'); };
  std::string out;
  size_t i = 0;
  while (i < md.size()) {
    if (!digit(i)) {
      out += md[i++];
      continue;
    }
    size_t j = i;
    while (digit(j)) ++j;
    if (j < md.size() && md[j] == '.' && digit(j + 1) && digit(j + 2) && digit(j + 3) && !word(j + 4)) {
      out += 'T';
      i = j + 4;
    } else {
      out.append(md, i, j - i);
      i = j;
    }
  }
  return out;
}

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
    const std::string a = test::readFile(e.path().string()), b = test::readFile(dir.file("cli/" + name));
    ASSERT_FALSE(b.empty()) << name << " missing from the command line's study";
    ++files;
    if (name == "trials.csv")
      EXPECT_EQ(withoutColumn(a, 26), withoutColumn(b, 26)) << name;
    else if (name == "summary.csv")
      EXPECT_EQ(withoutColumn(a, 12), withoutColumn(b, 12)) << name;
    else if (name == "report.md")
      EXPECT_EQ(withoutTimings(a), withoutTimings(b)) << name;
    else
      EXPECT_TRUE(a == b) << name << " differs";
  }
  EXPECT_GE(files, 10u);  // yaml, 3 CSV, report and the figures
}

}  // namespace
}  // namespace stereoloc
