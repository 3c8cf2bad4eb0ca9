#pragma once
// The accuracy study's report: summary.csv, report.md (per scenario the summary table, the
// thesis's Tables 6.14-6.16 beside ours, and the figures: trajectories of trial 0 with 3-sigma
// ellipses, error against step with +-3 sigma, mean NEES per step with its chi-square band, and
// for the kidnap scenario the EKF's innovations), all recomputed from the rows.
#include <string>
#include <vector>

#include "src/study/study.h"
#include "src/study/study_rows.h"
#include "src/study/study_trial.h"

namespace stereoloc::study {

// Writes summary.csv, report.md and the PNG figures into `dir`; returns the summary rows.
// `calibration`: the self-calibrating methods' rows (calibration.csv), may be empty. `cache`
// (may be null) only speeds up re-simulating trial 0 for the figures.
std::vector<SummaryRow> writeReport(const StudyConfig& c, const std::vector<TrialRow>& rows, const std::vector<StepRow>& steps,
                                    const std::vector<CalibrationRow>& calibration, const RenderCache* cache,
                                    const std::string& dir);

}  // namespace stereoloc::study
