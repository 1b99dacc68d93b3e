#pragma once
// Running one program on a formloop LinuxCNC configuration (cnc/linuxcnc_config.h), headless, and
// leaving nothing behind.
//
// A run works in its own session folder: the configuration's files and the program are copied there,
// LinuxCNC runs with that folder as its working directory (so the program's (PROBEOPEN) and (LOGOPEN)
// files land there), HOME points at session/home (LinuxCNC's linuxcnc_print.txt and _debug.txt), and
// the launcher's output goes to session/controller.log. The display program (cnc/linuxcnc_display.py)
// writes session/result.json; LinuxCNC shuts itself down when the display program exits.
//
// What it takes on this kind of machine (measured with LinuxCNC 2.9.0~pre1, Debian 12, as root):
//   - `linuxcnc -r INI` (-r: no redirection of the output to ~/linuxcnc_print.txt);
//   - as root, RTAPI_UID set to a non-zero uid (rtapi_app then runs with that real uid, "Running with
//     fallback_uid") and RTAPI_FIFO_PATH the path of rtapi_app's socket (not a folder), in a folder that
//     uid may write and short enough for a socket address (108 bytes). Without them rtapi_app never
//     becomes ready and `linuxcnc` waits 3 s per retry for minutes;
//   - DISPLAY (X11) unset, so a stale instance is never answered through a Tk dialog.
//
// One controller per machine. LinuxCNC's shared memory and its lock file (/tmp/linuxcnc.lock) are
// global, so runs take an exclusive lock (flock on /tmp/formloop-linuxcnc.lock; other formloop runs
// wait) and refuse to start while any LinuxCNC process that formloop did not start is alive: the
// `linuxcnc` script would otherwise "clean up the other instance", i.e. stop someone else's controller.
// Every process of a run inherits FORMLOOP_LINUXCNC_SESSION=<session folder>; that is how a run finds
// its own processes (never by name alone).
//
// Ending. Normally the display program exits and `linuxcnc` stops the controller (its Cleanup). After
// the launcher has exited, the run waits up to 15 s for every process of the session to end and then
// stops what is left (SIGTERM, 5 s, SIGKILL), reporting their ids (stray_pids). If the launcher itself
// outlives timeout_s + 120 s it gets SIGTERM (its trap runs Cleanup), then SIGKILL.

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cnc/linuxcnc_config.h"
#include "core/status.h"

namespace formloop::cnc {

struct LinuxCncRunOptions {
  double timeout_s = 600;     // the program's time limit; the display program aborts it beyond
  double lock_wait_s = 1800;  // how long to wait for another formloop run to free the controller
  std::string launcher = "linuxcnc";
  // The link component's socket (FORMLOOP_LINK_SOCKET; cnc/linuxcnc_link.h); empty: the link serves none.
  std::filesystem::path link_socket;
  Status Validate() const;
};

struct LinuxCncError {
  std::string stage;  // preview (LinuxCNC's interpreter reading the program), reset, on, home, run, ...
  std::string text;   // the controller's message
  long line = 0;      // 1-based program line; 0 = unknown
  std::string block;  // the line's text when known
};

struct LinuxCncRunReport {
  bool ok = false;  // the program ran to its end without an error
  std::string stage;
  std::vector<LinuxCncError> errors;
  std::vector<std::string> messages;  // what the program printed (MSG, DEBUG)
  double lock_wait_s = 0, preview_s = 0, start_s = 0, run_s = 0, total_s = 0;
  int exit_code = -1;             // of `linuxcnc`
  std::filesystem::path session;  // the session folder
  std::filesystem::path program;  // the copy that ran
  std::string source;             // the program as the caller named it (messages)
  std::vector<int> stray_pids;    // session processes that outlived the launcher and were stopped
  nlohmann::json ToJson() const;
  // Ok, or Failed naming the program, the line, the block and the controller's text.
  Status ToStatus() const;
};

// Runs `program` on `config` in a new session folder `session` (must not exist or be empty).
// Non-ok Result: the run could not take place (launcher missing, controller busy, no result); a
// program that ran and failed is an ok Result with report.ok = false (see ToStatus).
Result<LinuxCncRunReport> RunOnLinuxCnc(const LinuxCncConfig& config, const std::filesystem::path& program,
                                        const std::filesystem::path& session, const LinuxCncRunOptions& options);

// Live (not zombie) processes started by formloop LinuxCNC sessions (the environment marker); with a
// non-empty `session`, only that session's.
std::vector<int> FormloopControllerProcesses(const std::filesystem::path& session = {});
// Live processes of any LinuxCNC controller, by name (rtapi_app, milltask, linuxcncsvr, io, halui,
// the linuxcnc launcher), whoever started them.
std::vector<int> LinuxCncProcesses();

// After runs: is the machine's controller side clean? Takes the run lock (waiting up to `wait_s` for
// other formloop runs, which may be busy with their own controller), then no LinuxCNC process may be
// alive and LinuxCNC's lock file must be gone. *what_is_left says otherwise.
bool LinuxCncLeftNothing(double wait_s, std::string* what_is_left);

}  // namespace formloop::cnc
