#pragma once
// The data files the studies read (data/thesis_tables.yaml: the thesis's tables to print beside
// ours). Looked up in $STEREOLOC_DATA_DIR, then the source tree's data/, then the installed
// share/stereoloc.
#include <string>

namespace stereoloc {

// The path of data file `name`, or "" when it is in none of the places above.
std::string findDataFile(const std::string& name);

}  // namespace stereoloc
