#pragma once
// The one exception type of stereoloc. Its message is a single line that names the offending
// file/line/field (or argument) and the reason, ready to print after "stereoloc: ".
#include <stdexcept>
#include <string>

namespace stereoloc {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

// Degenerate geometry (coincident landmarks, zero disparity, ...) that a caller may want to
// tell apart from bad input.
class GeometryError : public Error {
 public:
  explicit GeometryError(const std::string& what) : Error(what) {}
};

}  // namespace stereoloc
