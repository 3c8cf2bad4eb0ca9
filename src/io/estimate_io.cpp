#include "src/io/estimate_io.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "src/core/atomic_file.h"
#include "src/core/error.h"

namespace stereoloc {

const char* const kEstimateCsvHeader = "step,t,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta";

std::string estimateCsvRow(const Estimate& e) {
  char buf[512];
  const Eigen::Matrix3d& P = e.covariance;
  std::snprintf(buf, sizeof(buf), "%ld,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g", e.step, e.t,
                e.pose.x, e.pose.y, e.pose.theta, P(0, 0), P(0, 1), P(0, 2), P(1, 1), P(1, 2), P(2, 2));
  return buf;
}

std::string estimateTumRow(const Estimate& e) {
  // Rotation about z by theta: q = (0, 0, sin(theta/2), cos(theta/2)).
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%.9f %.9f %.9f 0 0 0 %.12f %.12f", e.t, e.pose.x * 1e-3, e.pose.y * 1e-3,
                std::sin(0.5 * e.pose.theta), std::cos(0.5 * e.pose.theta));
  return buf;
}

void writeEstimatesCsv(const std::string& path, const std::vector<Estimate>& estimates) {
  AtomicOutputFile out(path);
  out.stream() << kEstimateCsvHeader << "\n";
  for (const Estimate& e : estimates)
    if (e.status != EstimateStatus::Uninitialised) out.stream() << estimateCsvRow(e) << "\n";
  out.commit();
}

void writeEstimatesTum(const std::string& path, const std::vector<Estimate>& estimates) {
  AtomicOutputFile out(path);
  out.stream() << "# timestamp x y z qx qy qz qw (stereoloc estimates, metres)\n";
  for (const Estimate& e : estimates)
    if (e.status != EstimateStatus::Uninitialised) out.stream() << estimateTumRow(e) << "\n";
  out.commit();
}

std::vector<Estimate> readEstimatesCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open");
  std::string line;
  if (!std::getline(in, line) || line != kEstimateCsvHeader)
    throw Error(path + ":1: expected header '" + std::string(kEstimateCsvHeader) + "'");
  std::vector<Estimate> out;
  long lineno = 1;
  while (std::getline(in, line)) {
    ++lineno;
    const std::string where = path + ":" + std::to_string(lineno) + ": ";
    if (line.empty()) throw Error(where + "empty line");
    std::vector<double> v;
    std::stringstream ss(line);
    std::string field;
    while (std::getline(ss, field, ',')) {
      char* end = nullptr;
      const double d = std::strtod(field.c_str(), &end);
      if (field.empty() || end != field.c_str() + field.size()) throw Error(where + "field " + std::to_string(v.size() + 1) + " is not a number");
      if (!std::isfinite(d)) throw Error(where + "field " + std::to_string(v.size() + 1) + " is not finite");
      v.push_back(d);
    }
    if (v.size() != 11) throw Error(where + "expected 11 columns, got " + std::to_string(v.size()));
    Estimate e;
    e.step = static_cast<long>(v[0]);
    if (static_cast<double>(e.step) != v[0]) throw Error(where + "step is not an integer");
    if (!out.empty() && e.step <= out.back().step) throw Error(where + "steps out of order");
    e.t = v[1];
    e.pose = Pose2(v[2], v[3], v[4]);
    e.covariance << v[5], v[6], v[7], v[6], v[8], v[9], v[7], v[9], v[10];
    e.status = EstimateStatus::Tracking;
    out.push_back(e);
  }
  return out;
}

}  // namespace stereoloc
