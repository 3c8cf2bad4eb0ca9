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

AtomicOutputFile::AtomicOutputFile(const std::string& path) : path_(path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);  // through a symbolic link
  if (!ec && fs::is_directory(st)) throw Error(path + ": is a directory");
  if (!ec && fs::exists(st) && !fs::is_regular_file(st)) {
    // A device or a pipe (/dev/null, /dev/stdout, a FIFO): a file renamed over it would replace
    // it, so it is written in place; it holds no earlier output to protect.
    in_place_ = true;
    out_.open(path, std::ios::out | std::ios::binary);
    if (!out_) throw Error(path + ": cannot open for writing");
    return;
  }
  // Through a symbolic link to a file: the file is replaced, the link stays.
  target_ = path;
  if (!ec && fs::is_symlink(fs::symlink_status(path, ec)) && fs::exists(st)) target_ = fs::canonical(path, ec).string();
  if (ec || target_.empty()) target_ = path;
  tmp_ = temporaryName(target_);
  out_.open(tmp_, std::ios::out | std::ios::trunc | std::ios::binary);
  if (!out_) throw Error(path + ": cannot open for writing");
}

AtomicOutputFile::~AtomicOutputFile() {
  if (!committed_ && !in_place_) {
    out_.close();
    std::error_code ec;
    std::filesystem::remove(tmp_, ec);
  }
}

void AtomicOutputFile::commit() {
  out_.flush();
  if (!out_) throw Error(path_ + ": write failed");
  out_.close();
  if (!in_place_) renameInto(tmp_, target_);
  committed_ = true;
}

}  // namespace stereoloc
