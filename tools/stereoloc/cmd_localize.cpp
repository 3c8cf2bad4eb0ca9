// `stereoloc localize DIR --method M --out est.csv`: runs one estimator over a dataset and writes
// its estimates (CSV, optionally TUM).
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {

void add_localize_command(CLI::App& app) {
  auto a = std::make_shared<LocalizeArgs>();
  CLI::App* sub = app.add_subcommand("localize", "Run one estimator over a dataset and write its estimates");
  addLocalizeOptions(sub, a, true);
  sub->callback([a, sub] {
    checkMethodOptions(*a, *sub);
    runLocalize(*a);
  });
}

}  // namespace stereoloc::cli
