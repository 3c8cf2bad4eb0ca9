#include "src/calib/target_pairs.h"

#include <opencv2/core/persistence.hpp>
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <map>
#include <set>

#include "src/core/error.h"
#include "src/io/image_file.h"

namespace stereoloc {
namespace {

namespace fs = std::filesystem;

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

bool isImageFile(const fs::path& path) {
  static const std::set<std::string> kExtensions = {".png", ".jpg",  ".jpeg", ".bmp", ".pgm", ".ppm",
                                                    ".pbm", ".tif", ".tiff", ".webp", ".jp2"};
  return kExtensions.count(lower(path.extension().string())) > 0;
}

// The key of `name` after `prefix` (case-insensitive, one '_' or '-' after it dropped); false
// when the name does not start with the prefix or nothing follows it.
bool keyAfter(const std::string& name, const std::string& prefix, std::string& key) {
  if (name.size() <= prefix.size() || lower(name.substr(0, prefix.size())) != prefix) return false;
  key = name.substr(prefix.size());
  if (key.front() == '_' || key.front() == '-') key.erase(0, 1);
  return !key.empty();
}

cv::Mat readGrey(const std::string& path, const std::string& where) {
  ImageRead read = readImageFile(path, ImageColour::Grey);
  if (!read.problem.empty()) throw Error(where + ": cannot read the image (" + read.problem + ")");
  return read.image;
}

std::vector<TargetPair> readFolder(const fs::path& folder) {
  std::map<std::string, fs::path> left, right;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (!entry.is_regular_file() || !isImageFile(entry.path())) continue;
    const std::string name = entry.path().filename().string();
    std::string key;
    if (keyAfter(name, "left", key)) left[key] = entry.path();
    if (keyAfter(name, "right", key)) right[key] = entry.path();
  }
  for (const auto& [key, path] : left)
    if (!right.count(key)) throw Error(path.string() + ": no right image with the key '" + key + "' beside it");
  for (const auto& [key, path] : right)
    if (!left.count(key)) throw Error(path.string() + ": no left image with the key '" + key + "' beside it");
  if (left.empty()) throw Error(folder.string() + ": no left<key>/right<key> image pairs");
  std::vector<TargetPair> pairs;
  for (const auto& [key, path] : left) {
    TargetPair p;
    p.name = path.string();
    p.left = readGrey(path.string(), path.string());
    p.right = readGrey(right[key].string(), right[key].string());
    pairs.push_back(std::move(p));
  }
  return pairs;
}

std::vector<TargetPair> readList(const fs::path& list) {
  const std::string where = list.string();
  cv::FileStorage fs;
  try {
    if (!fs.open(where, cv::FileStorage::READ)) throw Error(where + ": not an OpenCV image list (cannot be opened)");
  } catch (const cv::Exception& e) {
    throw Error(where + ": not an OpenCV image list (" + e.err + ")");
  }
  cv::FileNode names = fs["imagelist"];
  if (!names.isSeq() && !names.isString()) {
    names = cv::FileNode();
    for (const cv::FileNode& node : fs.root())
      if (node.isSeq()) {
        names = node;
        break;
      }
  }
  if (!names.isSeq() && !names.isString()) throw Error(where + ": no sequence of image names (an `imagelist` node)");
  std::vector<std::string> files;
  if (names.isString()) {
    files.push_back(names.string());  // an XML list of one name reads as that name
  } else {
    for (const cv::FileNode& n : names) {
      const std::string entry = "entry " + std::to_string(files.size() + 1);
      if (!n.isString()) throw Error(where + ": imagelist " + entry + " is not a file name");
      files.push_back(n.string());
    }
  }
  if (files.empty()) throw Error(where + ": the imagelist is empty");
  if (files.size() % 2 != 0)
    throw Error(where + ": the imagelist has an odd number of names (" + std::to_string(files.size()) +
                "); left and right alternate");
  std::vector<TargetPair> pairs;
  for (size_t i = 0; i < files.size(); i += 2) {
    const fs::path l = list.parent_path() / files[i], r = list.parent_path() / files[i + 1];
    TargetPair p;
    p.name = l.string();
    p.left = readGrey(l.string(), where + ": imagelist entry " + std::to_string(i + 1) + " (" + l.string() + ")");
    p.right = readGrey(r.string(), where + ": imagelist entry " + std::to_string(i + 2) + " (" + r.string() + ")");
    pairs.push_back(std::move(p));
  }
  return pairs;
}

}  // namespace

std::vector<TargetPair> readTargetPairs(const std::string& folder_or_list) {
  const fs::path path(folder_or_list);
  std::error_code ec;
  if (fs::is_directory(path, ec)) return readFolder(path);
  if (fs::is_regular_file(path, ec)) return readList(path);
  throw Error(folder_or_list + ": no such folder or image list");
}

}  // namespace stereoloc
