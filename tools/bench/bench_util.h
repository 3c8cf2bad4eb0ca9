#pragma once
// Helpers the benchmark programs share: per-thread CPU time and order statistics of timings.
#include <time.h>

#include <algorithm>
#include <cstddef>
#include <vector>

namespace stereoloc::bench {

// CPU time of this thread (ms): unlike the wall clock, not inflated when other processes
// preempt the benchmark on a shared machine.
inline double threadCpuMs() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

// The q-quantile (0..1, nearest rank) of v; 0 for an empty v.
inline double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  return v[i];
}

}  // namespace stereoloc::bench
