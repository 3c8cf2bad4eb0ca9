// `stereoloc study`: the accuracy comparison study (the main job; `make demo` runs it), and
// `stereoloc study merge` for sharded studies.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <memory>

#include "tools/stereoloc/cli_common.h"
#include "src/study/study.h"

namespace stereoloc::cli {
namespace {

struct StudyArgs {
  std::string scenarios = "thesis";
  std::string methods = "fix1,fix2,ekf,iekf,ekf:random,ekf:global,pf,window,batch";
  std::string shard = "0/1";
  std::string init = "known";
  std::string profiles = "ideal";
  StudyConfig config;
  std::vector<std::string> merge_dirs;
  std::string merge_out;
  bool merge_force = false;
  std::string observation_model = toString(MethodOptions().observation_model);
  std::string pf_proposal = toString(MethodOptions().pf_proposal);
};

void runFromArgs(StudyArgs& a) {
  StudyConfig& c = a.config;
  c.scenarios = a.scenarios == "thesis" ? std::vector<std::string>{"circle", "line", "spin", "kidnap"} : splitCommaList(a.scenarios);
  c.methods = splitCommaList(a.methods);
  c.profiles = splitCommaList(a.profiles);
  if (c.scenarios.empty()) throw UsageError("--scenarios is empty");
  if (c.methods.empty()) throw UsageError("--methods is empty");
  const size_t slash = a.shard.find('/');
  try {
    if (slash == std::string::npos) throw std::invalid_argument("no slash");
    size_t used = 0;
    c.shard_index = std::stoi(a.shard.substr(0, slash), &used);
    if (used != slash) throw std::invalid_argument("index");
    const std::string n = a.shard.substr(slash + 1);
    c.shard_count = std::stoi(n, &used);
    if (used != n.size()) throw std::invalid_argument("count");
  } catch (const std::exception&) {
    throw UsageError("--shard must be I/N with integers, e.g. 0/4");
  }
  try {
    c.method_options.init = initModeFromString(a.init);
  } catch (const Error& e) {
    throw UsageError(std::string("--init: ") + e.what());
  }
  try {
    c.method_options.observation_model = observationModelFromString(a.observation_model);
  } catch (const Error& e) {
    throw UsageError(std::string("--observation-model: ") + e.what());
  }
  try {
    c.method_options.pf_proposal = particleProposalFromString(a.pf_proposal);
  } catch (const Error& e) {
    throw UsageError(std::string("--pf-proposal: ") + e.what());
  }
  const StudyResult r = runStudy(c);
  std::fputs(study::summaryText(r.summary).c_str(), stdout);
  std::printf("report: %s\n", r.report.c_str());
}

}  // namespace

void add_study_command(CLI::App& app) {
  auto a = std::make_shared<StudyArgs>();
  CLI::App* sub = app.add_subcommand(
      "study",
      "Accuracy comparison: simulate each scenario and trial with a deterministic seed, run every method on the same "
      "data, evaluate against the ground truth; writes trials.csv, steps.csv, summary.csv, report.md and PNG figures");
  sub->add_option("--scenarios", a->scenarios, "Comma-separated scenario names, or 'thesis' (circle,line,spin,kidnap)")
      ->capture_default_str();
  sub->add_option("--methods", a->methods,
                  "Comma-separated methods: " + methodNamesText() +
                      "; append :known, :random or :global to choose the start (e.g. ekf:random), and :calib "
                      "for odometry and stereo self-calibration (batch:calib, window:calib, ekf:calib, pf:calib) or, for the "
                      "EKF and the fixes, :consider for the same calibration considered, not estimated "
                      "(ekf:consider; fix1:consider and fix2:consider the stereo block); batch:calib-field, window:calib-field and ekf:calib-field also estimate "
                      "the field's dimensions")
      ->capture_default_str();
  sub->add_option("--profile", a->profiles,
                  "Comma-separated error profiles of the simulated world: ideal (exact), realistic (calibration, lens, "
                  "blur, vibration and odometry errors; src/sim/error_profile.h) or profile YAML files; every method "
                  "runs in each, side by side in the report")
      ->capture_default_str();
  sub->add_option("--trials", a->config.trials, "Trials per scenario")->capture_default_str()->check(positiveNumber());
  sub->add_option("--seed", a->config.seed, "Study seed (each trial's seed derives from it)")->capture_default_str();
  sub->add_option("--frontend", a->config.frontend,
                  "Observations: images (each step's stereo pair rendered and run through the vision frontend) or "
                  "pixels (the simulator's noisy pixel projections of the goal corners; much faster)")
      ->capture_default_str()
      ->check(CLI::IsMember({"pixels", "images"}));
  sub->add_option("--frontend-landmarks", a->config.frontend_landmarks,
                  "With images: all (goal corners + unidentified corners/junctions, associated by each estimator at "
                  "its current belief) or goal_corners (the thesis's landmarks only)")
      ->capture_default_str()
      ->check(CLI::IsMember({"all", "goal_corners"}));
  sub->add_option("--image-noise", a->config.image_noise, "With images: Gaussian sensor noise of the rendered pairs, grey levels")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--threads", a->config.threads, "Worker threads (0 = all cores); results do not depend on it")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--shard", a->shard, "Run only trials I, I+N, I+2N, ... (0-based I/N); merge with 'study merge'")
      ->capture_default_str();
  sub->add_option("--init", a->init, "Default start of the trackers: known, random or global")->capture_default_str();
  sub->add_option("--particles", a->config.method_options.particles, "Particles of the particle filter (at least 100)")
      ->capture_default_str()
      ->check(particleCount());
  sub->add_option("--pf-proposal", a->pf_proposal,
                  "Particle filter proposal: linearised_optimal (each particle Kalman-corrected by the observations) or "
                  "prior (Algorithm 6 as printed)")
      ->capture_default_str();
  sub->add_flag("--pf-kld", a->config.method_options.pf_kld,
                "Particle filter with KLD-sampling: adaptive particle count up to --particles (steps.csv column particles)");
  sub->add_option("--window", a->config.method_options.window, "Window size W of the sliding-window smoother")
      ->capture_default_str()
      ->check(positiveNumber());
  sub->add_option("--observation-model", a->observation_model,
                  "How batch and window use the stereo observations: range_bearing (the thesis's form), pixel_columns "
                  "(u_l, u_r: the same data, no conversion bias) or pixels (also the rows)")
      ->capture_default_str();
  sub->add_option("--out", a->config.out_dir, "Output directory (required)");
  sub->add_flag("--force", a->config.force, "Replace a non-empty output directory");
  sub->add_flag("!--no-progress", a->config.progress, "No progress bar (it is shown only when stderr is a terminal)");

  CLI::App* merge = sub->add_subcommand("merge", "Merge sharded study directories and recompute summary, report and figures");
  merge->add_option("dirs", a->merge_dirs, "Study directories written with --shard")->required()->check(CLI::ExistingDirectory);
  merge->add_option("--out", a->merge_out, "Output directory")->required();
  merge->add_flag("--force", a->merge_force, "Replace a non-empty output directory");
  merge->callback([a] {
    const StudyResult r = mergeStudies(a->merge_dirs, a->merge_out, a->merge_force);
    std::fputs(study::summaryText(r.summary).c_str(), stdout);
    std::printf("merged %zu trial rows from %zu studies; report: %s\n", r.trial_rows, a->merge_dirs.size(), r.report.c_str());
  });

  sub->callback([a, merge, sub] {
    if (merge->parsed()) return;
    if (a->config.out_dir.empty()) throw UsageError("study: --out DIR is required");
    refuseUnused(*sub, "--frontend-landmarks", a->config.frontend == "images", "--frontend images");
    refuseUnused(*sub, "--image-noise", a->config.frontend == "images", "--frontend images");
    bool pf = false, window = false;
    for (const std::string& m : splitCommaList(a->methods)) {
      const std::string name = parseMethodSpec(m, InitMode::Known).first;
      pf |= name == "pf";
      window |= name == "window";
    }
    const std::string listed = " (--methods " + a->methods + ")";
    for (const char* option : {"--particles", "--pf-proposal", "--pf-kld"})
      refuseUnused(*sub, option, pf, "studies with the particle filter", listed);
    refuseUnused(*sub, "--window", window, "studies with the window", listed);
    runFromArgs(*a);
  });
}

}  // namespace stereoloc::cli
