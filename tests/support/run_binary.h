#pragma once
// Test support: run the formloop binary (FORMLOOP_BINARY) with arguments through the shell and
// collect its exit code, stdout and (optionally) stderr.

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <sys/wait.h>
#include <unistd.h>

namespace formloop::testing {

// Returns the exit code (-1 when the process did not exit normally). stderr goes to *err when given
// (through a temporary file next to the system's temp directory), else it is discarded.
inline int RunFormloop(const std::string& args, std::string* out, std::string* err = nullptr) {
  const std::filesystem::path err_file =
      std::filesystem::temp_directory_path() / ("formloop-stderr-" + std::to_string(::getpid()) + ".txt");
  const std::string command = std::string(FORMLOOP_BINARY) + " " + args + " 2>" +
                              (err != nullptr ? err_file.string() : std::string("/dev/null"));
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return -1;
  std::array<char, 4096> buffer{};
  if (out != nullptr) out->clear();
  std::size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) {
    if (out != nullptr) out->append(buffer.data(), n);
  }
  const int status = ::pclose(pipe);
  if (err != nullptr) {
    std::ifstream in(err_file);
    err->assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    std::filesystem::remove(err_file);
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace formloop::testing
