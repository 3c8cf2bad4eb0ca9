// The fix, smoother and kidnap studies through their library API: reports to the given stream,
// files where asked, usage errors for bad options.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <string>

#include "src/pipeline/usage_error.h"
#include "src/study/fix_study.h"
#include "src/study/kidnap_study.h"
#include "src/study/smoother_study.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// What a study printed into a temporary FILE*.
class Capture {
 public:
  Capture() : file_(std::tmpfile()) {}
  ~Capture() { std::fclose(file_); }
  Capture(const Capture&) = delete;
  Capture& operator=(const Capture&) = delete;
  std::FILE* file() { return file_; }
  std::string text() {
    std::fflush(file_);
    std::rewind(file_);
    std::string out;
    char buf[4096];
    size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, file_)) > 0) out.append(buf, n);
    return out;
  }

 private:
  std::FILE* file_;
};

TEST(SmootherStudy, ReturnsTheReportAndWritesItWhereAsked) {
  test::TempDir dir;
  SmootherStudyConfig c;
  c.scenarios = "line";
  c.trials = 2;
  c.windows = "5";
  c.particles = 100;
  c.threads = 1;
  c.out_dir = dir.file("out");
  const std::string md = runSmootherStudy(c);
  EXPECT_NE(md.find("## line"), std::string::npos) << md;
  EXPECT_NE(md.find("| window W=5 |"), std::string::npos) << md;
  EXPECT_TRUE(std::filesystem::exists(dir.file("out/smoothers.md")));
  c.windows = "5,zero";
  EXPECT_THROW(runSmootherStudy(c), UsageError);
  c.windows = "5";
  c.scenarios = "kidnap";  // no continuous true trajectory for the bound
  EXPECT_THROW(runSmootherStudy(c), UsageError);
}

TEST(KidnapStudy, PrintsTheSummaryToItsConsole) {
  Capture console;
  KidnapStudyOptions o;
  o.seeds = 2;
  o.console = console.file();
  runKidnapStudy(o);
  const std::string text = console.text();
  EXPECT_NE(text.find("kidnap study"), std::string::npos) << text;
  EXPECT_NE(text.find("detected within"), std::string::npos) << text;
  o.seeds = 0;
  EXPECT_THROW(runKidnapStudy(o), UsageError);
}

TEST(FixStudy, PrintsTheTablesToItsConsoleAndWritesTheFixes) {
  test::TempDir dir;
  Capture console;
  FixStudyOptions o;
  o.category = "rect";
  o.method = "fix2";
  o.out = dir.file("out");
  o.console = console.file();
  o.log = nullptr;
  runFixStudy(o);
  const std::string text = console.text();
  EXPECT_NE(text.find("6.4"), std::string::npos) << text;  // the thesis's table beside ours
  EXPECT_TRUE(std::filesystem::exists(dir.file("out/fixes.csv")));
  EXPECT_TRUE(std::filesystem::exists(dir.file("out/fixstudy.txt")));
}

}  // namespace
}  // namespace stereoloc
