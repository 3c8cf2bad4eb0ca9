#pragma once
// Runs the built `stereoloc` binary and captures its exit code and combined output.
#include <array>
#include <cstdio>
#include <string>
#include <sys/wait.h>

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

}  // namespace stereoloc::test
