#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "test_util.h"

namespace stereoloc {

TEST(AtomicFile, InterruptedWriteLeavesPreviousFileIntact) {
  test::TempDir dir;
  const std::string path = dir.file("out.csv");
  writeFileAtomically(path, "old\n");
  {
    AtomicOutputFile f(path);
    f.stream() << "new partial";
    // destroyed without commit(): as if the run was interrupted
  }
  EXPECT_EQ(test::readFile(path), "old\n");
  size_t files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) files += e.is_regular_file();
  EXPECT_EQ(files, 1u) << "temporary file left behind";
  {
    AtomicOutputFile f(path);
    f.stream() << "new\n";
    f.commit();
  }
  EXPECT_EQ(test::readFile(path), "new\n");
  EXPECT_THROW(writeFileAtomically(dir.file("no/such/dir/x"), "x"), Error);
}

// Renaming a file over a device or a pipe would replace it (over /dev/null, for every program on
// the machine): they are written in place. A symbolic link keeps pointing where it did, at the
// new content.
TEST(AtomicFile, PipesAreWrittenInPlaceAndLinksKept) {
  {
    test::TempDir dir;
    const std::string fifo = dir.file("pipe");
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
    // Held open for reading (and writing, so that opening it does not block), read afterwards.
    const int fd = ::open(fifo.c_str(), O_RDWR | O_NONBLOCK);
    ASSERT_GE(fd, 0);
    writeFileAtomically(fifo, "through the pipe\n");
    char buf[64] = {};
    const ssize_t n = ::read(fd, buf, sizeof buf - 1);
    ::close(fd);
    EXPECT_EQ(std::string(buf, n > 0 ? static_cast<size_t>(n) : 0), "through the pipe\n");
    EXPECT_TRUE(std::filesystem::is_fifo(fifo));
  }
  test::TempDir dir;
  writeFileAtomically(dir.file("real.csv"), "old\n");
  std::filesystem::create_symlink(dir.file("real.csv"), dir.file("link.csv"));
  writeFileAtomically(dir.file("link.csv"), "new\n");
  EXPECT_TRUE(std::filesystem::is_symlink(dir.file("link.csv")));
  EXPECT_EQ(test::readFile(dir.file("real.csv")), "new\n");
  EXPECT_THROW(writeFileAtomically(dir.path(), "x"), Error);  // a directory
}

}  // namespace stereoloc
