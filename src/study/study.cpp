#include "src/study/study.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <tuple>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/core/yaml_util.h"
#include "src/pipeline/frontend_source.h"
#include "src/pipeline/usage_error.h"
#include "src/sim/error_profile.h"
#include "src/sim/scenario.h"
#include "src/study/study_report.h"
#include "src/study/study_rows.h"
#include "src/study/study_trial.h"

namespace stereoloc {
namespace fs = std::filesystem;
using namespace study;
namespace {

// ---------------------------------------------------------------------------------------------
// Config persistence (study.yaml), so that merge can check the shards belong together.

std::string joinList(const std::vector<std::string>& v) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? "," : "") + v[i];
  return s;
}

void writeStudyYaml(const StudyConfig& c, const std::string& path) {
  YamlWriter w;
  w.comment("stereoloc study configuration (written by `stereoloc study`; read by `study merge`)");
  w.put("scenarios", joinList(c.scenarios));
  w.put("methods", joinList(c.methods));
  w.put("trials", c.trials);
  w.put("seed", std::to_string(c.seed));
  w.put("profiles", joinList(c.profiles));
  w.put("frontend", c.frontend);
  w.put("frontend_landmarks", c.frontend_landmarks);
  w.put("image_noise", c.image_noise);
  w.put("shard_index", c.shard_index);
  w.put("shard_count", c.shard_count);
  w.put("particles", c.method_options.particles);
  w.put("window", c.method_options.window);
  w.put("init", toString(c.method_options.init));
  w.put("observation_model", toString(c.method_options.observation_model));
  w.put("pf_proposal", toString(c.method_options.pf_proposal));
  w.put("pf_kld", std::string(c.method_options.pf_kld ? "true" : "false"));
  w.writeAtomically(path);
}

StudyConfig readStudyYaml(const std::string& path) {
  YamlReader in(path);
  StudyConfig c;
  c.scenarios = splitCommaList(in.getString("scenarios"));
  c.methods = splitCommaList(in.getString("methods"));
  c.trials = in.getInt("trials");
  try {
    c.seed = std::stoull(in.getString("seed"));
  } catch (const std::exception&) {
    in.fail("seed", "not an unsigned integer");
  }
  c.profiles = splitCommaList(in.getString("profiles", "ideal"));
  c.frontend = in.getString("frontend");
  c.frontend_landmarks = in.getString("frontend_landmarks", "all");
  c.image_noise = in.getDouble("image_noise", StudyConfig().image_noise);
  c.shard_index = in.getInt("shard_index");
  c.shard_count = in.getInt("shard_count");
  c.method_options.particles = in.getInt("particles");
  c.method_options.window = in.getInt("window");
  c.method_options.init = initModeFromString(in.getString("init"));
  const std::string model = in.getString("observation_model", "range_bearing");  // study.yaml files without the field
  try {
    c.method_options.observation_model = observationModelFromString(model);
  } catch (const Error& e) {
    in.fail("observation_model", e.what());
  }
  // Absent fields: the defaults.
  try {
    c.method_options.pf_proposal =
        particleProposalFromString(in.getString("pf_proposal", toString(MethodOptions().pf_proposal)));
  } catch (const Error& e) {
    in.fail("pf_proposal", e.what());
  }
  const std::string kld = in.getString("pf_kld", "false");
  if (kld != "true" && kld != "false") in.fail("pf_kld", "expected true or false");
  c.method_options.pf_kld = kld == "true";
  return c;
}

void prepareOutDir(const std::string& dir, bool force) {
  if (dir.empty()) throw UsageError("--out DIR is required");
  if (fs::exists(dir) && !fs::is_directory(dir)) throw Error(dir + ": exists and is not a directory");
  if (fs::exists(dir) && !fs::is_empty(dir)) {
    if (!force) throw UsageError(dir + ": directory is not empty (use --force to overwrite)");
    for (const auto& e : fs::directory_iterator(dir)) fs::remove_all(e.path());
  }
  fs::create_directories(dir);
}

// Sorts rows into the canonical order (scenario order of the config, trial, method order).
template <typename Row>
void canonicalOrder(const StudyConfig& c, std::vector<Row>& rows) {
  auto index = [](const std::vector<std::string>& v, const std::string& s) {
    return static_cast<int>(std::find(v.begin(), v.end(), s) - v.begin());
  };
  std::stable_sort(rows.begin(), rows.end(), [&](const Row& a, const Row& b) {
    const int sa = index(c.scenarios, a.scenario), sb = index(c.scenarios, b.scenario);
    if (sa != sb) return sa < sb;
    const int pa = index(c.profiles, a.profile), pb = index(c.profiles, b.profile);
    if (pa != pb) return pa < pb;
    if (a.trial != b.trial) return a.trial < b.trial;
    return index(c.methods, a.method) < index(c.methods, b.method);
  });
}


// calibration.csv, only when a method self-calibrates.
void writeCalibrationCsv(const std::vector<CalibrationRow>& rows, const std::string& path) {
  if (rows.empty()) return;
  AtomicOutputFile out(path);
  out.stream() << kCalibrationHeader << "\n";
  for (const CalibrationRow& r : rows) out.stream() << toCsv(r) << "\n";
  out.commit();
}

void validateStudyConfig(const StudyConfig& c) {
  if (c.trials < 1) throw UsageError("--trials must be at least 1");
  if (c.shard_count < 1 || c.shard_index < 0 || c.shard_index >= c.shard_count)
    throw UsageError("--shard I/N needs 0 <= I < N");
  if (c.frontend != "pixels" && c.frontend != "images") throw UsageError("--frontend must be pixels or images");
  frontendLandmarksFromString(c.frontend_landmarks);
  if (!(c.image_noise >= 0) || !std::isfinite(c.image_noise)) throw UsageError("--image-noise must be >= 0");
  const std::vector<std::string> known = scenarioNames();
  for (const std::string& s : c.scenarios)
    if (std::find(known.begin(), known.end(), s) == known.end()) throw UsageError("unknown scenario '" + s + "'");
  for (const std::string& m : c.methods) parseMethodSpec(m, c.method_options.init);
  if (c.profiles.empty()) throw UsageError("--profile is empty");
  for (const std::string& p : c.profiles) {
    if (std::count(c.profiles.begin(), c.profiles.end(), p) > 1) throw UsageError("--profile: '" + p + "' appears twice");
    try {
      ErrorProfile::named(p);
    } catch (const Error& e) {
      throw UsageError(std::string("--profile: ") + e.what());
    }
  }
}

struct StudyTask {
  std::string scenario, profile;
  int trial;
};

// This shard's trials, scenario by scenario, profile by profile.
std::vector<StudyTask> studyTasks(const StudyConfig& c) {
  std::vector<StudyTask> tasks;
  for (const std::string& s : c.scenarios)
    for (const std::string& p : c.profiles)
      for (int t = c.shard_index; t < c.trials; t += c.shard_count) tasks.push_back({s, p, t});
  return tasks;
}

// Runs the tasks on `threads` workers and hands each one's output (or its error message) to
// `take` in task order, as soon as it and every earlier task are done.
void runTasksInOrder(const StudyConfig& c, const std::vector<StudyTask>& tasks, const RenderCache& cache, int threads,
                     const std::function<void(size_t, TrialOutput&&, const std::string&)>& take) {
  std::vector<std::optional<TrialOutput>> results(tasks.size());
  std::vector<std::string> errors(tasks.size());
  std::mutex mu;
  std::condition_variable cv;
  std::atomic<size_t> next{0};
  std::vector<std::thread> pool;
  for (int i = 0; i < threads; ++i) {
    pool.emplace_back([&] {
      for (size_t k = next++; k < tasks.size(); k = next++) {
        TrialOutput out;
        std::string err;
        try {
          out = runTrial(c, tasks[k].profile, tasks[k].scenario, tasks[k].trial, &cache);
        } catch (const std::exception& e) {
          err = tasks[k].scenario + (tasks[k].profile == "ideal" ? "" : " (" + tasks[k].profile + ")") + " trial " +
                std::to_string(tasks[k].trial) + ": " + e.what();
        }
        std::lock_guard<std::mutex> lock(mu);
        results[k] = std::move(out);
        errors[k] = err;
        cv.notify_all();
      }
    });
  }
  for (size_t k = 0; k < tasks.size(); ++k) {
    std::unique_lock<std::mutex> lock(mu);
    cv.wait(lock, [&] { return results[k].has_value(); });
    TrialOutput out = std::move(*results[k]);
    const std::string err = errors[k];
    lock.unlock();
    take(k, std::move(out), err);
  }
  for (std::thread& t : pool) t.join();
}

// Rows are written in task order as soon as they are complete: the files do not depend on the
// thread count, and an interrupted study keeps every trial it finished.
class StudyCollector {
 public:
  StudyCollector(const StudyConfig& c, const std::vector<StudyTask>& tasks)
      : c_(c), tasks_(tasks), trials_csv_(c.out_dir + "/trials.csv"), steps_csv_(c.out_dir + "/steps.csv"),
        bar_(c.progress && c.log && ::isatty(::fileno(c.log))) {
    if (!trials_csv_ || !steps_csv_) throw Error(c.out_dir + ": cannot create trials.csv / steps.csv");
    trials_csv_ << kTrialHeader << "\n" << std::flush;
    steps_csv_ << kStepHeader << "\n" << std::flush;
  }

  void startClock() { start_ = std::chrono::steady_clock::now(); }  // progress and "trials done in"

  void take(size_t k, TrialOutput&& out, const std::string& err) {
    if (!err.empty()) {
      if (first_error_.empty()) first_error_ = err;
      return;
    }
    const StudyTask& task = tasks_[k];
    if (c_.log)
      for (const std::string& f : out.failures)
        std::fprintf(c_.log, "%sstudy: %s%s trial %d: %s\n", bar_ ? "\n" : "", task.scenario.c_str(),
                     task.profile == "ideal" ? "" : (" (" + task.profile + ")").c_str(), task.trial, f.c_str());
    for (const TrialRow& r : out.rows) trials_csv_ << toCsv(r) << "\n";
    for (const StepRow& s : out.steps) steps_csv_ << toCsv(s) << "\n";
    trials_csv_.flush();
    steps_csv_.flush();
    rows.insert(rows.end(), out.rows.begin(), out.rows.end());
    steps.insert(steps.end(), out.steps.begin(), out.steps.end());
    calibration.insert(calibration.end(), out.calibration.begin(), out.calibration.end());
    frontend.merge(out.frontend);
    if (bar_) printProgress(k + 1);
  }

  // After the last task: ends the progress bar, throws the first trial's error, logs the
  // frontend's figures.
  void finish() const {
    if (bar_) std::fprintf(c_.log, "\n");
    if (!first_error_.empty()) throw Error(first_error_);
    if (frontend.pairs > 0 && c_.log) {
      const double n = static_cast<double>(frontend.pairs);
      std::fprintf(c_.log,
                   "image frontend: %ld stereo pairs, %.2f observations per pair (%.2f goal corners), rendering %.1f "
                   "ms/pair, frontend %.2f ms/pair; trials done in %.1f s\n",
                   frontend.pairs, frontend.observations / n, frontend.identified / n, frontend.ms_render / n,
                   frontend.ms_frontend / n, elapsedS());
    }
  }

  std::vector<TrialRow> rows;
  std::vector<StepRow> steps;
  std::vector<CalibrationRow> calibration;
  ImageFrontendStats frontend;

 private:
  double elapsedS() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }

  void printProgress(size_t done) const {
    const double el = elapsedS();
    const double eta = el / done * (tasks_.size() - done);
    const int width = 30, filled = static_cast<int>(width * done / tasks_.size());
    std::fprintf(c_.log, "\r[%s%s] %zu/%zu trials, %.0f s elapsed, ETA %.0f s ", std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), done, tasks_.size(), el, eta);
  }

  const StudyConfig& c_;
  const std::vector<StudyTask>& tasks_;
  std::ofstream trials_csv_, steps_csv_;
  const bool bar_;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
  std::string first_error_;
};

}  // namespace

uint64_t trialSeed(uint64_t study_seed, const std::string& scenario, int trial) {
  return splitmix64(splitmix64(study_seed) ^ hashString(scenario) ^ splitmix64(static_cast<uint64_t>(trial) + 0x51ED));
}

StudyResult runStudy(const StudyConfig& c) {
  validateStudyConfig(c);
  prepareOutDir(c.out_dir, c.force);
  writeStudyYaml(c, c.out_dir + "/study.yaml");
  const std::vector<StudyTask> tasks = studyTasks(c);
  StudyCollector collected(c, tasks);
  const int threads = c.threads > 0 ? c.threads : std::max(1u, std::thread::hardware_concurrency());
  const auto cache_start = std::chrono::steady_clock::now();
  const RenderCache cache = buildRenderCache(c, threads);
  if (!cache.empty() && c.log)
    std::fprintf(c.log, "study: rendered the noise-free pairs of %zu scenario(s) in %.1f s; each trial adds its own sensor noise\n",
                 cache.size(), std::chrono::duration<double>(std::chrono::steady_clock::now() - cache_start).count());
  collected.startClock();
  runTasksInOrder(c, tasks, cache, threads,
                  [&](size_t k, TrialOutput&& out, const std::string& err) { collected.take(k, std::move(out), err); });
  collected.finish();
  writeCalibrationCsv(collected.calibration, c.out_dir + "/calibration.csv");
  StudyResult result;
  result.summary = writeReport(c, collected.rows, collected.steps, collected.calibration, &cache, c.out_dir);
  result.report = c.out_dir + "/report.md";
  result.trial_rows = collected.rows.size();
  return result;
}

StudyResult mergeStudies(const std::vector<std::string>& dirs, const std::string& out_dir, bool force) {
  if (dirs.empty()) throw UsageError("study merge needs at least one study directory");
  StudyConfig c = readStudyYaml(dirs.front() + "/study.yaml");
  std::vector<TrialRow> rows;
  std::vector<StepRow> steps;
  std::vector<CalibrationRow> calibration;
  using TrialKey = std::tuple<std::string, std::string, int>;  // scenario, profile, trial
  std::set<TrialKey> seen;
  for (const std::string& d : dirs) {
    const StudyConfig o = readStudyYaml(d + "/study.yaml");
    if (o.scenarios != c.scenarios || o.profiles != c.profiles || o.methods != c.methods || o.trials != c.trials || o.seed != c.seed ||
        o.frontend != c.frontend || o.frontend_landmarks != c.frontend_landmarks || o.image_noise != c.image_noise ||
        o.method_options.particles != c.method_options.particles ||
        o.method_options.window != c.method_options.window || o.method_options.init != c.method_options.init ||
        o.method_options.observation_model != c.method_options.observation_model ||
        o.method_options.pf_proposal != c.method_options.pf_proposal || o.method_options.pf_kld != c.method_options.pf_kld)
      throw Error(d + "/study.yaml: configuration differs from " + dirs.front() + "/study.yaml");
    std::set<TrialKey> here;
    for (const TrialRow& r : readTrialRows(d + "/trials.csv")) {
      const TrialKey key{r.scenario, r.profile, r.trial};
      if (seen.count(key) && !here.count(key))
        throw Error(d + "/trials.csv: trial " + std::to_string(r.trial) + " of " + r.scenario + " appears in two studies");
      here.insert(key);
      rows.push_back(r);
    }
    seen.insert(here.begin(), here.end());
    for (const StepRow& s : readStepRows(d + "/steps.csv")) steps.push_back(s);
    if (fs::exists(d + "/calibration.csv"))
      for (const CalibrationRow& r : readCalibrationRows(d + "/calibration.csv")) calibration.push_back(r);
  }
  canonicalOrder(c, rows);
  canonicalOrder(c, steps);
  canonicalOrder(c, calibration);
  c.shard_index = 0;
  c.shard_count = 1;
  prepareOutDir(out_dir, force);
  writeStudyYaml(c, out_dir + "/study.yaml");
  {
    AtomicOutputFile t(out_dir + "/trials.csv"), s(out_dir + "/steps.csv");
    t.stream() << kTrialHeader << "\n";
    for (const TrialRow& r : rows) t.stream() << toCsv(r) << "\n";
    s.stream() << kStepHeader << "\n";
    for (const StepRow& r : steps) s.stream() << toCsv(r) << "\n";
    t.commit();
    s.commit();
  }
  writeCalibrationCsv(calibration, out_dir + "/calibration.csv");
  StudyResult result;
  result.summary = writeReport(c, rows, steps, calibration, nullptr, out_dir);
  result.report = out_dir + "/report.md";
  result.trial_rows = rows.size();
  return result;
}

}  // namespace stereoloc
