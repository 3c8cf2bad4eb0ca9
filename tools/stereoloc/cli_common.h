#pragma once
// Shared conventions of the stereoloc subcommands: exit codes and error types.
//   0  success
//   1  bad data (unreadable or malformed files, degenerate geometry): stereoloc::Error
//   2  usage errors (bad or missing arguments): UsageError or a CLI11 parse error
#include <CLI/CLI.hpp>
#include <string>

#include "src/error.h"

namespace stereoloc::cli {

constexpr int kExitBadData = 1;
constexpr int kExitUsage = 2;

class UsageError : public Error {
 public:
  explicit UsageError(const std::string& what) : Error(what) {}
};

// Each subcommand lives in its own file and registers itself on the root app.
void addSelfcheckCommand(CLI::App& app);

}  // namespace stereoloc::cli
