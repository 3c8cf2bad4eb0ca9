#include "src/core/yaml_util.h"

#include <cmath>
#include <filesystem>
#include <opencv2/core.hpp>

#include "src/core/atomic_file.h"
#include "src/core/error.h"

namespace stereoloc {

bool YamlNode::has(const std::string& key) const {
  return node_.isMap() && !node_[key].empty() && !node_[key].isNone();
}

void YamlNode::fail(const std::string& key, const std::string& reason) const {
  throw Error(context_ + (key.empty() ? "" : (context_.back() == ':' ? " " : ".") + key) + ": " + reason);
}

YamlNode YamlNode::child(const std::string& key) const {
  if (!has(key)) fail(key, "missing");
  return YamlNode(node_[key], context_ + (context_.back() == ':' ? " " : ".") + key);
}

size_t YamlNode::size() const { return node_.isSeq() ? node_.size() : 0; }

YamlNode YamlNode::at(size_t i) const {
  return YamlNode(node_[static_cast<int>(i)], context_ + "[" + std::to_string(i) + "]");
}

double YamlNode::getDouble(const std::string& key) const {
  if (!has(key)) fail(key, "missing");
  const cv::FileNode n = node_[key];
  if (!n.isReal() && !n.isInt()) fail(key, "not a number");
  const double v = static_cast<double>(n);
  if (!std::isfinite(v)) fail(key, "not a finite number");
  return v;
}

double YamlNode::getDouble(const std::string& key, double fallback) const {
  return has(key) ? getDouble(key) : fallback;
}

int YamlNode::getInt(const std::string& key) const {
  if (!has(key)) fail(key, "missing");
  const cv::FileNode n = node_[key];
  if (!n.isInt()) fail(key, "not an integer");
  return static_cast<int>(n);
}

int YamlNode::getInt(const std::string& key, int fallback) const { return has(key) ? getInt(key) : fallback; }

std::string YamlNode::getString(const std::string& key) const {
  if (!has(key)) fail(key, "missing");
  const cv::FileNode n = node_[key];
  if (!n.isString()) fail(key, "not a string");
  return static_cast<std::string>(n);
}

std::string YamlNode::getString(const std::string& key, const std::string& fallback) const {
  return has(key) ? getString(key) : fallback;
}

bool YamlNode::getBool(const std::string& key, bool fallback) const {
  if (!has(key)) return fallback;
  const cv::FileNode n = node_[key];
  if (n.isInt()) {
    const int v = static_cast<int>(n);
    if (v == 0 || v == 1) return v == 1;
  } else if (n.isString()) {
    const std::string s = static_cast<std::string>(n);
    if (s == "true") return true;
    if (s == "false") return false;
  }
  fail(key, "not a boolean (0/1 or true/false)");
}

namespace {
// OpenCV 4.6's YAML parser reports "FILE(LINE): reason" in the exception's function name and the
// parser's function in its error text; the line is what a user needs.
std::string yamlParseError(const std::string& path, const cv::Exception& e) {
  const std::string prefix = path + "(";
  if (e.code == cv::Error::StsParseError && e.func.rfind(prefix, 0) == 0) {
    const size_t close = e.func.find("): ", prefix.size());
    if (close != std::string::npos) {
      const std::string line = e.func.substr(prefix.size(), close - prefix.size());
      if (!line.empty() && line.find_first_not_of("0123456789") == std::string::npos)
        return path + ":" + line + ": YAML parse error: " + e.func.substr(close + 3);
    }
  }
  std::string msg = e.err.empty() ? std::string(e.what()) : e.err;
  for (char& c : msg)
    if (c == '\n') c = ' ';
  return path + ": YAML parse error: " + msg;
}

cv::FileStorage openForReading(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) throw Error(path + ": cannot open (no such file)");
  std::error_code ec;
  if (std::filesystem::file_size(path, ec) == 0 && !ec) throw Error(path + ": empty file (expected YAML)");
  try {
    cv::FileStorage fs(path, cv::FileStorage::READ | cv::FileStorage::FORMAT_YAML);
    if (!fs.isOpened()) throw Error(path + ": cannot open as YAML");
    return fs;
  } catch (const cv::Exception& e) {
    throw Error(yamlParseError(path, e));
  }
}
}  // namespace

YamlReader::YamlReader(const std::string& path) : YamlReader(openForReading(path), path) {}

YamlReader::YamlReader(cv::FileStorage fs, const std::string& path)
    : YamlNode(fs.root(), path + ":"), fs_(std::move(fs)), path_(path) {}

YamlWriter::YamlWriter()
    : fs_(".yaml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML) {}

void YamlWriter::comment(const std::string& text) { fs_.writeComment(text); }

std::string YamlWriter::str() { return fs_.releaseAndGetString(); }

void YamlWriter::putScalarsOf(const YamlNode& node) {
  for (auto it = node.node().begin(); it != node.node().end(); ++it) {
    const cv::FileNode n = *it;
    if (n.isString())
      put(n.name(), static_cast<std::string>(n));
    else if (n.isInt())
      put(n.name(), static_cast<int>(n));
    else if (n.isReal())
      put(n.name(), static_cast<double>(n));
  }
}

void YamlWriter::writeAtomically(const std::string& path) { writeFileAtomically(path, str()); }

}  // namespace stereoloc
