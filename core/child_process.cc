#include "core/child_process.h"

#include <fcntl.h>
#include <poll.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstring>

#include "core/number_text.h"

namespace formloop {
namespace {

// Writes all of `bytes` to `fd`; false when the pipe fails (the parent went away).
bool WriteAll(int fd, const std::string& bytes) {
  std::size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    done += static_cast<std::size_t>(n);
  }
  return true;
}

// Reaps `pid`, retrying on EINTR; false (errno set) when it is not our child.
bool Reap(pid_t pid, int* wstatus) {
  while (::waitpid(pid, wstatus, 0) < 0) {
    if (errno != EINTR) return false;
  }
  return true;
}

// "120 s", "0.25 s": the limit as the user set it, locale-free.
std::string Seconds(double s) { return FormatSignificant(s, 6) + " s"; }

}  // namespace

std::string ChildFailure::Describe() const {
  if (timed_out) return "no answer within " + Seconds(limit_s) + ", stopped with signal 9";
  if (signal != 0) {
    const char* name = ::strsignal(signal);
    return "signal " + std::to_string(signal) + (name != nullptr ? std::string(", ") + name : "");
  }
  return "exit code " + std::to_string(exit_code);
}

Result<std::string> RunInChildProcess(const std::function<std::string()>& work, ChildFailure* failure,
                                      double timeout_s) {
  using Clock = std::chrono::steady_clock;
  const bool limited = timeout_s > 0 && std::isfinite(timeout_s);
  const Clock::time_point deadline =
      limited ? Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(timeout_s))
              : Clock::time_point::max();
  int fds[2];
  // Close-on-exec: a program another thread starts must not hold the pipe open (the parent waits for its end).
  if (::pipe2(fds, O_CLOEXEC) != 0) {
    return Status::IoError(std::string("could not create a pipe: ") + std::strerror(errno));
  }
  const pid_t pid = ::fork();
  if (pid < 0) {
    const int error = errno;
    ::close(fds[0]);
    ::close(fds[1]);
    return Status::IoError(std::string("could not start a child process: ") + std::strerror(error));
  }
  if (pid == 0) {
    ::close(fds[0]);
    // Exit code 0 only when `work` finished and every byte reached the parent: a partial message is a failure.
    int code = 3;
    try {
      code = WriteAll(fds[1], work()) ? 0 : 4;
    } catch (...) {
      code = 5;
    }
    ::close(fds[1]);
    ::_exit(code);
  }
  ::close(fds[1]);
  // Read until the child closes its end (it may write more than a pipe holds) or the time is up, then
  // collect it. The child closes its end only by ending, so a closed pipe means it has ended or is ending.
  std::string bytes;
  char buffer[65536];
  bool timed_out = false;
  for (;;) {
    int wait_ms = -1;
    if (limited) {
      const auto left_us = std::chrono::duration_cast<std::chrono::microseconds>(deadline - Clock::now()).count();
      if (left_us <= 0) {
        timed_out = true;
        break;
      }
      wait_ms = static_cast<int>(std::min<long long>((left_us + 999) / 1000, 60'000));  // rounded up: not early
    }
    pollfd ready{.fd = fds[0], .events = POLLIN, .revents = 0};
    const int polled = ::poll(&ready, 1, wait_ms);
    if (polled < 0 && errno == EINTR) continue;
    if (polled == 0) continue;  // the deadline is checked above
    if (polled < 0) break;      // cannot happen with a valid descriptor; the child is reaped below
    const ssize_t n = ::read(fds[0], buffer, sizeof buffer);
    if (n < 0 && (errno == EINTR || errno == EAGAIN)) continue;
    if (n <= 0) break;
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fds[0]);
  // A child past its deadline is killed; SIGKILL cannot be caught or ignored, so the wait below ends.
  if (timed_out) ::kill(pid, SIGKILL);
  int wstatus = 0;
  if (!Reap(pid, &wstatus)) return Status::IoError(std::string("lost the child process: ") + std::strerror(errno));
  if (!timed_out && WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0) return bytes;
  ChildFailure ended;
  if (WIFSIGNALED(wstatus)) ended.signal = WTERMSIG(wstatus);
  if (WIFEXITED(wstatus)) ended.exit_code = WEXITSTATUS(wstatus);
  ended.timed_out = timed_out;
  ended.limit_s = timed_out ? timeout_s : 0;
  if (failure != nullptr) *failure = ended;
  if (timed_out) return Status::Internal("the child process gave " + ended.Describe());
  return Status::Internal("the child process ended by " + ended.Describe());
}

}  // namespace formloop
