#include <gtest/gtest.h>

#include <string>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/core/yaml_util.h"
#include "test_util.h"

namespace stereoloc {
namespace {

// A YAML file that does not parse: one line naming the file and the line OpenCV's parser
// stopped at, so the user can go there.
TEST(YamlReader, ParseErrorNamesFileAndLine) {
  test::TempDir dir;
  const std::string path = dir.file("broken.yaml");
  writeFileAtomically(path, "%YAML:1.0\n---\na: 1\nb: [1, 2\nc: 3\n");
  const std::string e = test::errorOf([&] { YamlReader{path}; });
  EXPECT_EQ(e.rfind(path + ":", 0), 0u) << e;
  EXPECT_NE(e.find(path + ":5: YAML parse error: "), std::string::npos) << e;
  EXPECT_EQ(e.find('\n'), std::string::npos) << e;
}

TEST(YamlReader, EmptyOrMissingFileIsNamed) {
  test::TempDir dir;
  writeFileAtomically(dir.file("empty.yaml"), "");
  EXPECT_EQ(test::errorOf([&] { YamlReader{dir.file("empty.yaml")}; }),
            dir.file("empty.yaml") + ": empty file (expected YAML)");
  EXPECT_EQ(test::errorOf([&] { YamlReader{dir.file("none.yaml")}; }),
            dir.file("none.yaml") + ": cannot open (no such file)");
}

TEST(YamlReader, BadValueNamesFileAndKey) {
  test::TempDir dir;
  writeFileAtomically(dir.file("v.yaml"), "%YAML:1.0\n---\nx: .nan\ny: abc\n");
  const YamlReader y(dir.file("v.yaml"));
  EXPECT_NE(test::errorOf([&] { y.getDouble("x"); }).find(dir.file("v.yaml") + ": x:"), std::string::npos);
  EXPECT_NE(test::errorOf([&] { y.getDouble("y"); }).find(dir.file("v.yaml") + ": y:"), std::string::npos);
  EXPECT_NE(test::errorOf([&] { y.getDouble("z"); }).find(dir.file("v.yaml") + ": z: missing"), std::string::npos);
  EXPECT_DOUBLE_EQ(y.getDouble("z", 2.5), 2.5);
}

}  // namespace
}  // namespace stereoloc
