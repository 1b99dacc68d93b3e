#pragma once
// Test support for the link's real-process tests: start `formloop` as a child process (posix_spawn,
// stdout and stderr to files), wait for it with a deadline, kill it by pid, and reap it, so no test
// leaves a process behind.

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "core/atomic_file.h"
#include "core/json_io.h"

extern char** environ;

namespace formloop::cnc::testing {

// Starts FORMLOOP_BINARY with `args`; stdout/stderr go to the given files. Returns the pid (−1 on failure).
inline pid_t SpawnFormloop(const std::vector<std::string>& args, const std::filesystem::path& out,
                           const std::filesystem::path& err) {
  std::vector<std::string> argv_s = {FORMLOOP_BINARY};
  argv_s.insert(argv_s.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : argv_s) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_addopen(&actions, 2, err.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, FORMLOOP_BINARY, &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  return rc == 0 ? pid : -1;
}

// Waits up to timeout_s; returns the exit code, 128 + signal when killed, or −1 on timeout.
inline int WaitFor(pid_t pid, double timeout_s) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  for (;;) {
    int status = 0;
    const pid_t r = ::waitpid(pid, &status, WNOHANG);
    if (r == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    if (r < 0) return -1;
    if (std::chrono::steady_clock::now() > deadline) return -1;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

// SIGKILL and reap (a no-op when the process already ended and was reaped).
inline void KillAndReap(pid_t pid) {
  if (pid <= 0) return;
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
}

// Kills and reaps every pid still registered when it goes out of scope (a failing test leaves nothing).
struct ProcessGuard {
  std::vector<pid_t> pids;
  ~ProcessGuard() {
    for (const pid_t p : pids) {
      int status = 0;
      if (::waitpid(p, &status, WNOHANG) == 0) KillAndReap(p);
    }
  }
};

// Starts `formloop link emulate --port 0 --ready-file F ...` and waits for its port.
inline std::string StartEmulator(const std::filesystem::path& dir, std::vector<std::string> args, ProcessGuard* guard,
                                 pid_t* pid) {
  const auto ready = dir / "ready.json";
  std::filesystem::remove(ready);
  std::vector<std::string> all = {"link", "emulate", "--port", "0", "--ready-file", ready.string()};
  all.insert(all.end(), args.begin(), args.end());
  *pid = SpawnFormloop(all, dir / "emulate.out", dir / "emulate.err");
  if (*pid > 0) guard->pids.push_back(*pid);
  for (int k = 0; k < 1000 && !std::filesystem::exists(ready); ++k)
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  const auto json = ReadJsonFile(ready);
  return json.ok() ? (*json)["address"].get<std::string>() : std::string();
}

}  // namespace formloop::cnc::testing
