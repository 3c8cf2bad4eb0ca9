#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

#include "cli_util.h"
#include "test_util.h"

namespace stereoloc {

// `cmake --install` puts the tool, the libraries and a CMake package config under a prefix;
// another project then builds with find_package(stereoloc), links stereoloc::stereoloc and runs
// a small study through the installed API (tests/tools/consumer).
TEST(Install, ConsumerProjectBuildsAgainstInstalledPackage) {
#ifdef __SANITIZE_ADDRESS__
  GTEST_SKIP() << "sanitizer build: its static libraries need -fsanitize in the consumer too; checked in the Release build";
#endif
  test::TempDir dir;
  const std::string build = std::string(STEREOLOC_BIN_DIR) + "/..";
  const std::string prefix = dir.file("prefix");
  auto sh = [](const std::string& cmd) { return std::system((cmd + " > /dev/null 2>&1").c_str()); };
  ASSERT_EQ(sh("cmake --install '" + build + "' --prefix '" + prefix + "'"), 0);
  ASSERT_EQ(sh("test -x '" + prefix + "/bin/stereoloc'"), 0);
  ASSERT_EQ(sh("cmake -S '" + std::string(STEREOLOC_SOURCE_DIR) + "/tests/tools/consumer' -B '" + dir.file("cb") +
               "' -DCMAKE_PREFIX_PATH='" + prefix + "' -DCMAKE_BUILD_TYPE=Release"),
            0);
  ASSERT_EQ(sh("cmake --build '" + dir.file("cb") + "'"), 0);
  EXPECT_EQ(sh("'" + dir.file("cb") + "/consumer' '" + dir.file("study") + "'"), 0);
  EXPECT_TRUE(std::filesystem::exists(dir.file("study/summary.csv")));
  EXPECT_TRUE(std::filesystem::exists(dir.file("study/circle_trajectories.png")));
}

}  // namespace stereoloc
