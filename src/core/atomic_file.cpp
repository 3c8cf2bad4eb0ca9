#include "src/core/atomic_file.h"

#include <cstdio>
#include <filesystem>
#include <system_error>
#include <unistd.h>

#include "src/core/error.h"

namespace stereoloc {
namespace {

std::string temporaryName(const std::string& path) {
  return path + ".tmp." + std::to_string(static_cast<long>(::getpid()));
}

void renameInto(const std::string& tmp, const std::string& path) {
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw Error(path + ": cannot rename temporary file into place");
  }
}

}  // namespace

void writeFileAtomically(const std::string& path, const std::string& content) {
  AtomicOutputFile file(path);
  file.stream() << content;
  file.commit();
}

AtomicOutputFile::AtomicOutputFile(const std::string& path) : path_(path), tmp_(temporaryName(path)) {
  out_.open(tmp_, std::ios::out | std::ios::trunc | std::ios::binary);
  if (!out_) throw Error(path + ": cannot open for writing");
}

AtomicOutputFile::~AtomicOutputFile() {
  if (!committed_) {
    out_.close();
    std::error_code ec;
    std::filesystem::remove(tmp_, ec);
  }
}

void AtomicOutputFile::commit() {
  out_.flush();
  if (!out_) throw Error(path_ + ": write failed");
  out_.close();
  renameInto(tmp_, path_);
  committed_ = true;
}

}  // namespace stereoloc
