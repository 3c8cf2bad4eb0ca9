#pragma once
// Thin helpers over cv::FileStorage (OpenCV's YAML) whose errors name the file and the key,
// e.g. "data/field.yaml: landmarks[3].x: not a finite number".
#include <opencv2/core/persistence.hpp>
#include <string>

namespace stereoloc {

// A node plus the path that names it in error messages.
class YamlNode {
 public:
  YamlNode(cv::FileNode node, std::string context) : node_(std::move(node)), context_(std::move(context)) {}

  const cv::FileNode& node() const { return node_; }
  const std::string& context() const { return context_; }
  bool has(const std::string& key) const;

  YamlNode child(const std::string& key) const;  // required
  size_t size() const;                           // sequence length (0 if not a sequence)
  YamlNode at(size_t i) const;                   // sequence element

  double getDouble(const std::string& key) const;  // required, finite
  double getDouble(const std::string& key, double fallback) const;
  int getInt(const std::string& key) const;
  int getInt(const std::string& key, int fallback) const;
  std::string getString(const std::string& key) const;
  std::string getString(const std::string& key, const std::string& fallback) const;
  bool getBool(const std::string& key, bool fallback) const;  // 0/1 or true/false

  [[noreturn]] void fail(const std::string& key, const std::string& reason) const;

 private:
  cv::FileNode node_;
  std::string context_;
};

// Opens and parses a YAML file; a missing file or a parse error throws stereoloc::Error.
class YamlReader : public YamlNode {
 public:
  explicit YamlReader(const std::string& path);
  const std::string& path() const { return path_; }

 private:
  YamlReader(cv::FileStorage fs, const std::string& path);
  cv::FileStorage fs_;
  std::string path_;
};

// Writes YAML through cv::FileStorage into memory, then atomically to a file.
class YamlWriter {
 public:
  YamlWriter();
  cv::FileStorage& fs() { return fs_; }
  void comment(const std::string& text);
  template <typename T>
  void put(const std::string& key, const T& value) {
    fs_ << key << value;
  }
  // Every scalar key of `node` (strings, integers, reals), in its order: a file rewritten with
  // keys appended (a rig with the standard deviations it hands over).
  void putScalarsOf(const YamlNode& node);
  std::string str();
  void writeAtomically(const std::string& path);

 private:
  cv::FileStorage fs_;
};

}  // namespace stereoloc
