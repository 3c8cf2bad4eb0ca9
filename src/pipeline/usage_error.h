#pragma once
// The error of a bad option value given to the pipeline or a study (an unknown method name, a
// trial count below 1, ...), as opposed to bad data (stereoloc::Error). The command-line tool
// exits with 2 for it and with 1 for bad data; a library user may catch it to re-ask the user.
#include <string>
#include <utility>
#include <vector>

#include "src/core/error.h"

namespace stereoloc {

class UsageError : public Error {
 public:
  explicit UsageError(const std::string& what) : Error(what) {}
};

// "a,b,,c" -> {"a", "b", "c"}: the comma-separated lists of the options (empty items dropped).
inline std::vector<std::string> splitCommaList(const std::string& s) {
  std::vector<std::string> out;
  size_t start = 0;
  while (start <= s.size()) {
    const size_t comma = s.find(',', start);
    std::string item = s.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (!item.empty()) out.push_back(std::move(item));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return out;
}

}  // namespace stereoloc
