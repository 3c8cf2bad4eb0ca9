#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {

namespace {
std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}
}  // namespace

TEST(AtomicFile, InterruptedWriteLeavesPreviousFileIntact) {
  test::TempDir dir;
  const std::string path = dir.file("out.csv");
  writeFileAtomically(path, "old\n");
  {
    AtomicOutputFile f(path);
    f.stream() << "new partial";
    // destroyed without commit(): as if the run was interrupted
  }
  EXPECT_EQ(slurp(path), "old\n");
  size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, 1u) << "temporary file left behind";
  {
    AtomicOutputFile f(path);
    f.stream() << "new\n";
    f.commit();
  }
  EXPECT_EQ(slurp(path), "new\n");
  EXPECT_THROW(writeFileAtomically(dir.file("no/such/dir/x"), "x"), Error);
}

}  // namespace stereoloc
