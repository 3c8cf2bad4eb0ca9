#pragma once
// Outputs are written to a temporary file beside the target and renamed into place, so an
// interrupted run never leaves a truncated file under the final name. A target that is a device
// or a pipe (/dev/null, /dev/stdout, a FIFO) is written in place, since a file renamed over it
// would replace it; through a symbolic link the file it points to is replaced, not the link.
#include <fstream>
#include <string>

namespace stereoloc {

// Writes `content` to `path` atomically. Throws stereoloc::Error naming the path on failure.
void writeFileAtomically(const std::string& path, const std::string& content);

// A file written incrementally and renamed to its final name by commit(). If the object is
// destroyed without commit() (an exception, an interrupted run), the temporary is removed and
// any previous file under the final name is left untouched.
class AtomicOutputFile {
 public:
  explicit AtomicOutputFile(const std::string& path);
  ~AtomicOutputFile();
  AtomicOutputFile(const AtomicOutputFile&) = delete;
  AtomicOutputFile& operator=(const AtomicOutputFile&) = delete;

  std::ostream& stream() { return out_; }
  void commit();
  const std::string& path() const { return path_; }

 private:
  std::string path_, target_, tmp_;  // target_: path_ or the file a symbolic link points to
  std::ofstream out_;
  bool committed_ = false;
  bool in_place_ = false;  // a device or a pipe: no temporary
};

}  // namespace stereoloc
