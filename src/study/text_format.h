#pragma once
// printf-style formatting into a std::string, for the studies' tables and CSV lines.
#include <string>

namespace stereoloc {

// The text printf(format, ...) would print, whatever its length.
std::string formatText(const char* format, ...) __attribute__((format(printf, 1, 2)));

}  // namespace stereoloc
