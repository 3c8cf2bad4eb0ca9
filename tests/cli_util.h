#pragma once
// Runs the built `stereoloc` binary and captures its exit code and combined output; reads the
// CSV files it writes.
#include <array>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <vector>

namespace stereoloc::test {

struct CliRun {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

inline CliRun runCli(const std::string& args, const std::string& stdin_file = "") {
  std::string cmd = std::string(STEREOLOC_BIN_DIR) + "/stereoloc " + args + " 2>&1";
  if (!stdin_file.empty()) cmd += " < '" + stdin_file + "'";
  CliRun r;
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// The position RMSE (mm) a command prints against the ground truth ("position RMSE 4.2 mm"); NaN
// when it prints none.
inline double printedPositionRmse(const std::string& output) {
  const size_t at = output.find("position RMSE ");
  return at == std::string::npos ? std::nan("") : std::stod(output.substr(at + 14));
}

// Rows of a CSV with a header (an estimate CSV, groundtruth.csv): step -> the numeric fields.
inline std::map<long, std::vector<double>> readRows(const std::string& path) {
  std::map<long, std::vector<double>> rows;
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::stringstream ls(line);
    std::string f;
    std::vector<double> v;
    while (std::getline(ls, f, ',')) v.push_back(std::stod(f));
    if (!v.empty()) rows[static_cast<long>(v[0])] = v;
  }
  return rows;
}

}  // namespace stereoloc::test
