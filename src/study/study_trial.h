#pragma once
// One trial of the accuracy study (src/study/study.h): simulate the scenario with the trial's
// seed, optionally render every step's stereo pair and run the vision frontend, run every
// method on the same data and compare it with the ground truth. Every random draw derives from
// trialSeed(), so a trial's rows depend neither on the thread count nor on the render cache.
#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "src/io/dataset.h"
#include "src/pipeline/frontend_source.h"
#include "src/study/study.h"
#include "src/study/study_rows.h"

namespace stereoloc::study {

uint64_t splitmix64(uint64_t x);
uint64_t hashString(const std::string& s);  // FNV-1a

// The seed of one method on one trial: the same for the rows and the report's figures, and the
// same for a method and its self-calibrating variant ("batch", "batch:calib"), so that the two
// start from the same known-start draw.
uint64_t methodSeed(const StudyConfig& c, const std::string& scenario, int trial, const std::string& method);

struct TrialOutput {
  std::vector<TrialRow> rows;
  std::vector<StepRow> steps;
  ImageFrontendStats frontend;  // images: what rendering and the frontend did (timings: stderr only)
  std::vector<std::string> failures;  // "method: reason" of each method that failed on the trial
  std::vector<CalibrationRow> calibration;  // self-calibrating methods: estimate against truth
};

// The calibration of the world a trace drew, in the parameters of solvers/self_calibration.h
// (kCalibrationParameters): wheel scales c_l, c_r, wheel base w (mm), tilt correction dbeta
// (rad), baseline scale k, focal scale psi (the left camera's focal length error), the right
// camera's exposure offset (s), and the field's dimensions' change against the map (mm). The
// ideal world's is the nominal one.
std::array<double, kCalibrationParameterCount> trueCalibration(const Dataset& d, const SimulationTrace& trace);

// An estimate in the same parameters: values, variances, and which of them the run estimated
// (the exposure offset: the rig's plus the image block's entry, where its sigma was stated).
struct CalibrationValues {
  std::array<double, kCalibrationParameterCount> value{}, variance{};
  std::array<bool, kCalibrationParameterCount> estimated{};
};
CalibrationValues calibrationValues(const CalibrationEstimate& estimate, const StereoRig& rig);

// The study's method options in the world of `profile`: its stated sigmas as the noise model
// and calibration priors (applyErrorProfile, src/pipeline/methods.h) on the dataset's rig.
MethodOptions methodOptionsFor(const StudyConfig& c, const std::string& profile, const Dataset& d);

// Noise-free renders of the scenarios whose true path does not depend on the seed, by
// "scenario#thesis trial" (see CleanRenders in frontend_source.h).
using RenderCache = std::map<std::string, std::shared_ptr<const CleanRenders>>;

// A study trial is a Monte Carlo run; scenarios with several thesis trials cycle through them.
int thesisTrial(const std::string& scenario, int trial);

// Simulates one trial in the world of `profile` (StudyConfig::profiles). With the image
// frontend, every step's pair is rendered from the true pose (or taken from `cache`, ideal world
// only) with sensor noise seeded from the trial seed and run through the frontend; a non-ideal
// profile renders raw pairs through the true cameras (src/sim/raw_render.h), which the frontend
// rectifies with the given calibration. `render_threads` only splits the rendering of a pair.
// `trace`, when given, receives the simulation trace (the drawn errors).
Dataset simulateTrial(const StudyConfig& c, const std::string& profile, const std::string& scenario, int trial,
                      const RenderCache* cache, int render_threads = 1, ImageFrontendStats* stats = nullptr,
                      SimulationTrace* trace = nullptr);

// The frontend's observations of a non-ideal world (trace.profile): every step's raw pair rendered
// through the true cameras (src/sim/raw_render.h) with sensor noise `image_noise` seeded
// noise_seed + step index, rectified by the frontend with the dataset's (given) calibration.
// Replaces the observations of `d`, the dataset simulated with `trace`.
ImageFrontendStats observeRawImages(Dataset& d, const SimulationTrace& trace, double image_noise, uint64_t noise_seed,
                                    const ImageFrontendOptions& options, int render_threads = 1);

// Renders once, noise-free, every scenario of the study whose true path and head pans are the
// same for any seed (all thesis scenarios; not random-walk); empty for the pixel frontend.
RenderCache buildRenderCache(const StudyConfig& c, int threads);

// Runs every method of the config on one trial in the world of `profile`.
TrialOutput runTrial(const StudyConfig& c, const std::string& profile, const std::string& scenario, int trial,
                     const RenderCache* cache);

}  // namespace stereoloc::study
