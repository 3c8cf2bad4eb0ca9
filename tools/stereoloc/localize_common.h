#pragma once
// What `localize` and `refine` share: their options and the run.
#include <CLI/CLI.hpp>
#include <cstdint>
#include <memory>
#include <string>

#include "tools/stereoloc/methods.h"

namespace stereoloc::cli {

struct LocalizeArgs {
  std::string dataset, method = "ekf", init = "known", out, tum;
  uint64_t seed = 1;
  MethodOptions options;
  std::string loss = "none";
};

void runLocalize(const LocalizeArgs& args);
// Adds the options; `method_option` false for refine (always the batch smoother).
void addLocalizeOptions(CLI::App* sub, const std::shared_ptr<LocalizeArgs>& args, bool method_option);

}  // namespace stereoloc::cli
