// `stereoloc refine DIR --out est.csv`: offline trajectory refinement with the batch smoother,
// the same as `localize --method batch`.
#include "tools/stereoloc/cli_common.h"
#include "tools/stereoloc/localize_common.h"

namespace stereoloc::cli {

void add_refine_command(CLI::App& app) {
  auto a = std::make_shared<LocalizeArgs>();
  a->method = "batch";
  CLI::App* sub = app.add_subcommand("refine", "Offline trajectory refinement with the batch smoother (= localize --method batch)");
  addLocalizeOptions(sub, a, false);
  sub->callback([a] { runLocalize(*a); });
}

}  // namespace stereoloc::cli
