#pragma once
// What the frontend found in one pair, as text for a person or a script (`stereoloc detect`):
// the marking and other line segments and the point features in left-image pixels, and the
// stereo observations with their range (mm), bearing and pixels. Two forms of the same content:
// aligned tables (bearing in degrees) and one JSON object (bearing in rad; keys segments,
// features, observations). Observations without pixels (none come from the frontend) are
// printed without them.
#include <string>

#include "frontend/frontend.h"

namespace stereoloc::frontend {

std::string detectionsTable(const FrontendResult& result);
std::string detectionsJson(const FrontendResult& result);  // ends with a newline

}  // namespace stereoloc::frontend
