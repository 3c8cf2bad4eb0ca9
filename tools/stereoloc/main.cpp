// stereoloc — stereo-vision and odometry self-localization in a known map.
// Thin entry point: every subcommand is registered from its own file (see cli_common.h).
#include <CLI/CLI.hpp>
#include <iostream>

#include "tools/stereoloc/cli_common.h"

int main(int argc, char** argv) {
  using namespace stereoloc::cli;
  CLI::App app{"stereoloc: real-time self-localization of small mobile robots from stereo vision and wheel "
               "odometry in a known map (units: mm, rad, s)."};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "Print the help of every subcommand");
#define STEREOLOC_COMMAND(name) add_##name##_command(app);
#include "tools/stereoloc/commands.inc"
#undef STEREOLOC_COMMAND
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
