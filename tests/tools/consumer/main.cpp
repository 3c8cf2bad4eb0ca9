// Uses the installed library: the map and rig models, one method over a simulated dataset
// (src/pipeline), and a small accuracy study (src/study) whose report it checks.
#include <cstdio>
#include <filesystem>
#include <string>

#include "src/core/field_map.h"
#include "src/core/stereo_rig.h"
#include "src/pipeline/methods.h"
#include "src/sim/simulator.h"
#include "src/study/study.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: consumer OUT_DIR\n");
    return 2;
  }
  const stereoloc::FieldMap map = stereoloc::FieldMap::miroSot();
  const stereoloc::StereoRig rig;
  if (map.landmarks().size() != 32 || !(rig.focal() > 0)) return 1;

  stereoloc::SimulationConfig sim;
  sim.scenario.steps = 20;
  const stereoloc::Dataset d = stereoloc::simulate("circle", 0, sim, 3);
  const stereoloc::MethodRun run = stereoloc::runMethod("ekf", d, 3, stereoloc::MethodOptions());
  if (run.estimates.size() != d.steps.size()) return 1;

  stereoloc::StudyConfig c;
  c.scenarios = {"circle"};
  c.methods = {"ekf", "batch"};
  c.trials = 2;
  c.frontend = "pixels";
  c.threads = 1;
  c.log = nullptr;
  c.out_dir = argv[1];
  const stereoloc::StudyResult r = stereoloc::runStudy(c);
  if (r.summary.size() != 2 || !std::filesystem::exists(r.report)) return 1;
  for (const stereoloc::study::SummaryRow& s : r.summary)
    if (s.trials != 2 || !(s.rmse() > 0 && s.rmse() < 1000)) return 1;
  std::printf("consumer ok: ekf RMSE %.1f mm, batch RMSE %.1f mm over %zu trial rows\n", r.summary[0].rmse(),
              r.summary[1].rmse(), r.trial_rows);
  return 0;
}
