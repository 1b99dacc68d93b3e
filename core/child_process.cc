#include "core/child_process.h"

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstring>

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

}  // namespace

std::string ChildFailure::Describe() const {
  if (signal != 0) {
    const char* name = ::strsignal(signal);
    return "signal " + std::to_string(signal) + (name != nullptr ? std::string(", ") + name : "");
  }
  return "exit code " + std::to_string(exit_code);
}

Result<std::string> RunInChildProcess(const std::function<std::string()>& work, ChildFailure* failure) {
  int fds[2];
  if (::pipe(fds) != 0) return Status::IoError(std::string("could not create a pipe: ") + std::strerror(errno));
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
  // Read until the child closes its end (it may write more than a pipe holds), then collect it.
  std::string bytes;
  char buffer[65536];
  for (;;) {
    const ssize_t n = ::read(fds[0], buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fds[0]);
  int wstatus = 0;
  while (::waitpid(pid, &wstatus, 0) < 0) {
    if (errno != EINTR) return Status::IoError(std::string("lost the child process: ") + std::strerror(errno));
  }
  if (WIFEXITED(wstatus) && WEXITSTATUS(wstatus) == 0) return bytes;
  ChildFailure ended;
  if (WIFSIGNALED(wstatus)) ended.signal = WTERMSIG(wstatus);
  if (WIFEXITED(wstatus)) ended.exit_code = WEXITSTATUS(wstatus);
  if (failure != nullptr) *failure = ended;
  return Status::Internal("the child process ended by " + ended.Describe());
}

}  // namespace formloop
