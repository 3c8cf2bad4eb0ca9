#include "src/io/estimate_io.h"

#include <charconv>
#include <cmath>
#include <fstream>

#include "src/core/atomic_file.h"
#include "src/core/error.h"
#include "src/io/csv.h"

namespace stereoloc {

const char* const kEstimateCsvHeader = "step,t,x,y,theta,cov_xx,cov_xy,cov_xtheta,cov_yy,cov_ytheta,cov_thetatheta";

namespace {

// printf("%.17g") / printf("%.<precision>f") digits, -0 kept as "-0" (std::to_chars is
// specified as printf with the same conversion).
char* general17(double v, char* out) {
  return std::to_chars(out, out + kFormatDoubleMaxChars, v, std::chars_format::general, 17).ptr;
}
char* fixed(double v, int precision, char* out, char* end) {
  return std::to_chars(out, end, v, std::chars_format::fixed, precision).ptr;
}

// The longest CSV row: 10 doubles and a step, with separators.
constexpr size_t kMaxCsvRow = 11 * kFormatDoubleMaxChars + 16;

char* writeCsvRow(const Estimate& e, char* out) {
  const Eigen::Matrix3d& P = e.covariance;
  out = formatLong(e.step, out);
  for (const double v : {e.t, e.pose.x, e.pose.y, e.pose.theta, P(0, 0), P(0, 1), P(0, 2), P(1, 1), P(1, 2), P(2, 2)}) {
    *out++ = ',';
    out = general17(v, out);
  }
  return out;
}

// Rotation about z by theta: q = (0, 0, sin(theta/2), cos(theta/2)).
std::string tumRow(const Estimate& e) {
  char buf[512];
  char* const end = buf + sizeof(buf);
  char* p = fixed(e.t, 9, buf, end);
  *p++ = ' ';
  p = fixed(e.pose.x * 1e-3, 9, p, end);
  *p++ = ' ';
  p = fixed(e.pose.y * 1e-3, 9, p, end);
  for (const char c : std::string(" 0 0 0 ")) *p++ = c;
  p = fixed(std::sin(0.5 * e.pose.theta), 12, p, end);
  *p++ = ' ';
  p = fixed(std::cos(0.5 * e.pose.theta), 12, p, end);
  return std::string(buf, p);
}

// Writes the rows through a buffer of about a megabyte: a million-row file is neither built in
// memory nor written a row at a time.
template <typename Row>
void writeRows(const std::string& path, const char* header, const std::vector<Estimate>& estimates, Row&& row) {
  AtomicOutputFile out(path);
  out.stream() << header << "\n";
  std::string buf;
  buf.reserve(1 << 20);
  for (const Estimate& e : estimates) {
    if (e.status == EstimateStatus::Uninitialised) continue;
    row(e, &buf);
    buf += '\n';
    if (buf.size() > (1 << 20) - 1024) {
      out.stream().write(buf.data(), static_cast<std::streamsize>(buf.size()));
      buf.clear();
    }
  }
  out.stream().write(buf.data(), static_cast<std::streamsize>(buf.size()));
  out.commit();
}

}  // namespace

std::string estimateCsvRow(const Estimate& e) {
  char buf[kMaxCsvRow];
  return std::string(buf, writeCsvRow(e, buf));
}

std::string estimateTumRow(const Estimate& e) { return tumRow(e); }

void writeEstimatesCsv(const std::string& path, const std::vector<Estimate>& estimates) {
  writeRows(path, kEstimateCsvHeader, estimates, [](const Estimate& e, std::string* buf) {
    char row[kMaxCsvRow];
    buf->append(row, writeCsvRow(e, row));
  });
}

void writeEstimatesTum(const std::string& path, const std::vector<Estimate>& estimates) {
  writeRows(path, "# timestamp x y z qx qy qz qw (stereoloc estimates, metres)", estimates,
            [](const Estimate& e, std::string* buf) { *buf += tumRow(e); });
}

std::vector<Estimate> readEstimatesCsv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open");
  std::string line;
  if (!std::getline(in, line) || line != kEstimateCsvHeader)
    throw Error(path + ":1: expected header '" + std::string(kEstimateCsvHeader) + "'");
  std::vector<Estimate> out;
  std::vector<double> v;
  std::string field;
  long lineno = 1;
  while (std::getline(in, line)) {
    ++lineno;
    // Built only for an error: a million-row file would spend its time here.
    const auto where = [&] { return path + ":" + std::to_string(lineno) + ": "; };
    if (line.empty()) throw Error(where() + "empty line");
    v.clear();
    size_t start = 0;
    while (true) {
      const size_t comma = line.find(',', start);
      const size_t stop = comma == std::string::npos ? line.size() : comma;
      field.assign(line, start, stop - start);
      double d = 0;
      if (!parseDouble(field, &d)) throw Error(where() + "field " + std::to_string(v.size() + 1) + " is not a number");
      if (!std::isfinite(d)) throw Error(where() + "field " + std::to_string(v.size() + 1) + " is not finite");
      v.push_back(d);
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    if (v.size() != 11) throw Error(where() + "expected 11 columns, got " + std::to_string(v.size()));
    Estimate e;
    e.step = static_cast<long>(v[0]);
    if (static_cast<double>(e.step) != v[0]) throw Error(where() + "step is not an integer");
    if (!out.empty() && e.step <= out.back().step) throw Error(where() + "steps out of order");
    e.t = v[1];
    e.pose = Pose2(v[2], v[3], v[4]);
    e.covariance << v[5], v[6], v[7], v[6], v[8], v[9], v[7], v[9], v[10];
    e.status = EstimateStatus::Tracking;
    out.push_back(e);
  }
  return out;
}

}  // namespace stereoloc
