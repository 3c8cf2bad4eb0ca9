#pragma once
// The estimate formats every estimator writes (stereoloc localize / refine / stream):
//  * CSV: step,t,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta (mm, rad),
//    one row per initialised estimate, full precision;
//  * TUM trajectory format (timestamp x y z qx qy qz qw; metres, z = 0), which evo reads.
#include <string>
#include <vector>

#include "src/core/types.h"

namespace stereoloc {

extern const char* const kEstimateCsvHeader;

// Both write atomically (temporary file + rename). Uninitialised estimates are not written.
void writeEstimatesCsv(const std::string& path, const std::vector<Estimate>& estimates);
void writeEstimatesTum(const std::string& path, const std::vector<Estimate>& estimates);

// One CSV row (no newline) / the TUM line of one estimate.
std::string estimateCsvRow(const Estimate& e);
std::string estimateTumRow(const Estimate& e);

// Reads the CSV back; errors name file:line and the reason.
std::vector<Estimate> readEstimatesCsv(const std::string& path);

}  // namespace stereoloc
