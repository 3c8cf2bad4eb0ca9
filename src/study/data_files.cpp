#include "src/study/data_files.h"

#include <cstdlib>
#include <filesystem>
#include <vector>

namespace stereoloc {

std::string findDataFile(const std::string& name) {
  std::vector<std::string> dirs;
  if (const char* env = std::getenv("STEREOLOC_DATA_DIR")) dirs.push_back(env);
  dirs.push_back(STEREOLOC_SOURCE_DATA_DIR);
  dirs.push_back(STEREOLOC_INSTALL_DATA_DIR);
  for (const std::string& d : dirs)
    if (std::filesystem::exists(d + "/" + name)) return d + "/" + name;
  return "";
}

}  // namespace stereoloc
