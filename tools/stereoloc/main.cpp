// stereoloc — stereo-vision and odometry self-localization in a known map.
// Thin entry point: every subcommand is registered from its own file (see cli_common.h).
#include <CLI/CLI.hpp>
#include <glog/logging.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <iostream>

#include "tools/stereoloc/cli_common.h"

namespace {

// No option of ours means anything by an empty value (`--csv ''` would otherwise write nothing,
// silently), by a number that is not finite (CLI11 reads "nan" and "inf" as numbers), nor by a
// negative or too large value of an unsigned one (CLI11 reads a seed of -1 as 2^64 - 1 and clamps
// 2^64 to it): refused before any command runs.
void refuseValuesNoOptionMeans(const CLI::App& app) {
  for (const CLI::App* sub : app.get_subcommands()) {
    for (const CLI::Option* opt : sub->get_options()) {
      if (opt->count() == 0 || opt->get_type_size_max() == 0) continue;
      const bool real = opt->get_type_name().rfind("FLOAT", 0) == 0;
      const bool unsigned_integer = opt->get_type_name().rfind("UINT", 0) == 0;
      for (const std::string& value : opt->results()) {
        if (value.empty()) throw stereoloc::UsageError(opt->get_name() + ": empty value");
        if (real && !std::isfinite(std::strtod(value.c_str(), nullptr)))
          throw stereoloc::UsageError(opt->get_name() + ": '" + value + "' is not a finite number");
        if (unsigned_integer) {
          errno = 0;
          std::strtoull(value.c_str(), nullptr, 0);
          if (value.find('-') != std::string::npos || errno == ERANGE)
            throw stereoloc::UsageError(opt->get_name() + ": '" + value + "' is not within [0, 2^64 - 1]");
        }
      }
    }
    refuseValuesNoOptionMeans(*sub);
  }
}

}  // namespace

int main(int argc, char** argv) {
  using namespace stereoloc::cli;
  // Ceres logs through glog, before our one-line error when a solve fails: only a check failure
  // (glog's FATAL, a bug) may print, to standard error, and no log file is written.
  FLAGS_logtostderr = true;
  FLAGS_minloglevel = google::GLOG_FATAL;
  google::InitGoogleLogging(argv[0]);
  CLI::App app{"stereoloc: real-time self-localization of small mobile robots from stereo vision and wheel "
               "odometry in a known map (units: mm, rad, s)."};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Print the help of every subcommand");
#define STEREOLOC_COMMAND(name) add_##name##_command(app);
#include "tools/stereoloc/commands.inc"
#undef STEREOLOC_COMMAND
  app.parse_complete_callback([&app] { refuseValuesNoOptionMeans(app); });
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "stereoloc: " << e.what() << " (see --help)\n";
    return kExitUsage;
  } catch (const UsageError& e) {
    std::cerr << "stereoloc: " << e.what() << " (see --help)\n";
    return kExitUsage;
  } catch (const stereoloc::Error& e) {
    std::cerr << "stereoloc: " << e.what() << "\n";
    return kExitBadData;
  } catch (const std::exception& e) {
    std::cerr << "stereoloc: internal error: " << e.what() << "\n";
    return kExitBadData;
  }
  return 0;
}
