#pragma once
// Runs work that may crash or hang in a child process, so that a crash becomes an error instead of the end of
// formloop (issue 17: no input may crash the program) and a hang ends at a deadline instead of blocking it.
// Used around third-party parsers that formloop cannot fix or check in full beforehand (OpenCASCADE's STEP
// and IGES readers): a null dereference, an out-of-bounds read or an abort inside them ends only the child,
// an endless loop ends when the time limit kills the child, and the parent reports which file the parser
// failed on.
//
// The child is a fork(2) of the caller: it sees the caller's memory as it was (copy on write), runs `work`,
// writes the bytes `work` returns through a pipe and ends with _exit (no exit handlers, no flushing of the
// parent's stdio buffers). Call it while no other thread of the process holds a lock the work needs (formloop
// reads its input files before any parallel loop starts).

#include <functional>
#include <string>

#include "core/status.h"

namespace formloop {

// How the child ended when it did not return its bytes.
struct ChildFailure {
  int signal = 0;                // the signal that ended it (11: segmentation fault, 6: abort, ...), 0 when it exited
  int exit_code = 0;             // its exit code when it exited without a signal
  bool timed_out = false;        // it was still running at the time limit and was killed (signal 9, SIGKILL)
  double limit_s = 0;            // that limit, when timed_out
  std::string Describe() const;  // "signal 11, Segmentation fault" / "exit code 3" / "no answer within 120 s"
};

// The bytes `work` returned in the child, or the ChildFailure (as `failure`) and a non-ok Status when the
// child did not finish (crashed, was killed, threw, or was still running `timeout_s` seconds after it was
// started: then the parent kills it with SIGKILL and reaps it, so no process is left behind). timeout_s <= 0:
// no limit. The Status is kInternal ("the child process ended by signal 11, Segmentation fault"); callers
// replace it by a message that names their input. IoError when no child could be started.
Result<std::string> RunInChildProcess(const std::function<std::string()>& work, ChildFailure* failure,
                                      double timeout_s = 0);

}  // namespace formloop
