#pragma once
// What the bench programs share: the process's CPU time and running a peer (a Python script through
// /usr/bin/python3) that prints one JSON line.

#include <sys/resource.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace formloop::bench {

// User + system CPU time of this process (all threads): the figure to trust when other jobs share the cores.
inline double CpuSeconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

// Runs `command` and returns its stdout; false when it could not start or exited non-zero.
inline bool RunPeer(const std::string& command, std::string* out) {
  FILE* pipe = ::popen(command.c_str(), "r");
  if (!pipe) return false;
  char buffer[4096];
  while (std::fgets(buffer, sizeof buffer, pipe)) *out += buffer;
  return ::pclose(pipe) == 0;
}

// A number from a one-line JSON object ("key": value), NaN when absent.
inline double JsonNumber(const std::string& line, const std::string& key) {
  const auto at = line.find("\"" + key + "\":");
  return at == std::string::npos ? std::nan("") : std::strtod(line.c_str() + at + key.size() + 3, nullptr);
}

}  // namespace formloop::bench
