#include "cnc/linuxcnc_run.h"

#include <fcntl.h>
#include <pwd.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>

#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"

extern char** environ;

namespace formloop::cnc {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

constexpr const char* kSessionVariable = "FORMLOOP_LINUXCNC_SESSION";
constexpr const char* kRunLock = "/tmp/formloop-linuxcnc.lock";
constexpr const char* kLinuxCncLock = "/tmp/linuxcnc.lock";

double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }
void Sleep(double s) { std::this_thread::sleep_for(std::chrono::duration<double>(s)); }

// The process table: pid, command name, state, environment (empty when unreadable).
struct ProcessInfo {
  int pid = 0;
  std::string comm;
  char state = '?';
  std::vector<std::string> environment;
};

std::vector<ProcessInfo> Processes(bool with_environment) {
  std::vector<ProcessInfo> out;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/proc", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    ProcessInfo p;
    p.pid = std::atoi(name.c_str());
    std::ifstream stat(entry.path() / "stat");
    std::string line;
    if (!std::getline(stat, line)) continue;
    const auto open = line.find('('), close = line.rfind(')');
    if (open == std::string::npos || close == std::string::npos || close + 2 >= line.size()) continue;
    p.comm = line.substr(open + 1, close - open - 1);
    p.state = line[close + 2];
    if (with_environment) {
      std::ifstream env(entry.path() / "environ", std::ios::binary);
      std::string all((std::istreambuf_iterator<char>(env)), {});
      std::size_t start = 0;
      while (start < all.size()) {
        const std::size_t end = all.find('\0', start);
        p.environment.push_back(all.substr(start, end == std::string::npos ? std::string::npos : end - start));
        if (end == std::string::npos) break;
        start = end + 1;
      }
    }
    out.push_back(std::move(p));
  }
  return out;
}

bool Alive(const ProcessInfo& p) { return p.state != 'Z' && p.state != 'X'; }

std::string MarkerOf(const ProcessInfo& p) {
  const std::string prefix = std::string(kSessionVariable) + "=";
  for (const std::string& e : p.environment) {
    if (e.rfind(prefix, 0) == 0) return e.substr(prefix.size());
  }
  return "";
}

bool IsLinuxCncName(const std::string& comm) {
  static const std::set<std::string> names = {"rtapi_app", "milltask", "linuxcncsvr", "io",
                                              "iov2",      "halui",    "linuxcnc",    "linuxcncrsh"};
  return names.count(comm) > 0;
}

// Sends `signal` to each pid and waits up to `wait_s` for them to end; returns those still alive.
std::vector<int> Stop(const std::vector<int>& pids, int signal, double wait_s) {
  for (int pid : pids) ::kill(pid, signal);
  const auto start = Clock::now();
  std::vector<int> alive = pids;
  while (!alive.empty() && Seconds(start) < wait_s) {
    Sleep(0.05);
    std::vector<int> still;
    const auto table = Processes(false);
    for (int pid : alive) {
      for (const auto& p : table) {
        if (p.pid == pid && Alive(p)) still.push_back(pid);
      }
    }
    alive = still;
  }
  return alive;
}

// The exclusive right to run a controller on this machine (released when destroyed).
class RunLock {
 public:
  ~RunLock() {
    if (fd_ >= 0) ::close(fd_);  // closing releases the flock
  }
  Status Acquire(double wait_s, double* waited_s) {
    fd_ = ::open(kRunLock, O_RDWR | O_CREAT | O_CLOEXEC, 0666);
    if (fd_ < 0) return Status::IoError(std::string("cannot open ") + kRunLock + ": " + std::strerror(errno));
    const auto start = Clock::now();
    bool said = false;
    while (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
      if (Seconds(start) > wait_s) {
        return Status::Failed("another formloop LinuxCNC run held " + std::string(kRunLock) + " for more than " +
                              FormatFixed(wait_s, 0) + " s; nothing was run");
      }
      if (!said) log::Info("linuxcnc: waiting for another formloop run to release the controller");
      said = true;
      Sleep(0.2);
    }
    *waited_s = Seconds(start);
    return Status::Ok();
  }

 private:
  int fd_ = -1;
};

// Refuses while a LinuxCNC that formloop did not start is running; stops the leftovers of earlier
// formloop sessions (the run lock proves their run is over).
Status CheckControllerFree() {
  std::vector<int> stale;
  std::vector<std::string> foreign;
  for (const ProcessInfo& p : Processes(true)) {
    if (!Alive(p) || !IsLinuxCncName(p.comm)) continue;
    if (!MarkerOf(p).empty()) {
      stale.push_back(p.pid);
    } else {
      foreign.push_back(p.comm + " (pid " + std::to_string(p.pid) + ")");
    }
  }
  if (!foreign.empty()) {
    std::string list;
    for (const auto& f : foreign) list += (list.empty() ? "" : ", ") + f;
    return Status::Failed("a LinuxCNC controller that formloop did not start is running (" + list +
                          "); formloop does not stop it. Stop it first (it runs one controller per machine)");
  }
  if (!stale.empty()) {
    log::Warn("linuxcnc: stopping {} process(es) left by an earlier formloop run", stale.size());
    const auto left = Stop(Stop(stale, SIGTERM, 5), SIGKILL, 5);
    if (!left.empty()) return Status::Failed("processes of an earlier formloop LinuxCNC run do not end");
  }
  return Status::Ok();
}

uid_t RtapiUid() {
  if (const passwd* nobody = ::getpwnam("nobody"); nobody != nullptr && nobody->pw_uid != 0) return nobody->pw_uid;
  return 65534;
}

// A short private folder for rtapi_app's socket (a socket path has at most 107 bytes).
class FifoFolder {
 public:
  ~FifoFolder() {
    std::error_code ec;
    if (!path_.empty()) fs::remove_all(path_, ec);
  }
  Status Make(bool as_root, uid_t uid) {
    char pattern[] = "/tmp/formloop-rtapi-XXXXXX";
    if (::mkdtemp(pattern) == nullptr) return Status::IoError(std::string("mkdtemp: ") + std::strerror(errno));
    path_ = pattern;
    if (as_root && ::chown(pattern, uid, static_cast<gid_t>(-1)) != 0) {
      return Status::IoError("cannot give " + path_.string() + " to uid " + std::to_string(uid) + ": " +
                             std::strerror(errno));
    }
    return Status::Ok();
  }
  fs::path socket() const { return path_ / "rtapi.fifo"; }

 private:
  fs::path path_;
};

std::string Tail(const fs::path& file, std::size_t lines) {
  auto text = ReadFile(file);
  if (!text.ok()) return "";
  std::vector<std::string> all;
  std::istringstream in(*text);
  for (std::string line; std::getline(in, line);) {
    if (line.find("fallback_uid") == std::string::npos) all.push_back(line);
  }
  std::string out;
  for (std::size_t i = all.size() > lines ? all.size() - lines : 0; i < all.size(); ++i) out += "\n  " + all[i];
  return out;
}

// `name` on PATH (or as given when it holds a '/').
Result<std::string> FindProgram(const std::string& name) {
  if (name.find('/') != std::string::npos) return name;
  const char* path = std::getenv("PATH");
  std::istringstream dirs(path != nullptr ? path : "/usr/bin:/bin");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const fs::path candidate = fs::path(dir.empty() ? "." : dir) / name;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return Status::NotFound("'" + name + "' is not on PATH: LinuxCNC is not installed (Debian package linuxcnc-uspace)");
}

Status ReadResult(const fs::path& path, LinuxCncRunReport* report) {
  FL_ASSIGN_OR_RETURN(const json r, ReadJsonFile(path));
  if (r.value("format", "") != "formloop linuxcnc result") {
    return Status::BadInput(Where{.file = path.string(), .field = "format"}, "not a formloop LinuxCNC result");
  }
  report->ok = r.value("ok", false);
  report->stage = r.value("stage", "");
  for (const json& e : r.value("errors", json::array())) {
    report->errors.push_back({e.value("stage", ""), e.value("text", ""), e.value("line", 0L), e.value("block", "")});
  }
  for (const json& m : r.value("messages", json::array())) report->messages.push_back(m.get<std::string>());
  const json seconds = r.value("seconds", json::object());
  report->preview_s = seconds.value("preview", 0.0);
  report->start_s = seconds.value("start", 0.0);
  report->run_s = seconds.value("run", 0.0);
  return Status::Ok();
}

}  // namespace

Status LinuxCncRunOptions::Validate() const {
  if (!(timeout_s > 0)) return Status::BadInput(Where{.field = "--timeout-s"}, "must be > 0");
  if (!(lock_wait_s >= 0)) return Status::BadInput(Where{.field = "lock_wait_s"}, "must be >= 0");
  if (launcher.empty()) return Status::BadInput(Where{.field = "launcher"}, "must name the linuxcnc launcher");
  return Status::Ok();
}

json LinuxCncRunReport::ToJson() const {
  json errors_json = json::array();
  for (const auto& e : errors) {
    errors_json.push_back({{"stage", e.stage}, {"text", e.text}, {"line", e.line}, {"block", e.block}});
  }
  return {
      {"ok", ok},
      {"stage", stage},
      {"program", source},
      {"errors", errors_json},
      {"messages", messages},
      {"seconds",
       {{"lock_wait", lock_wait_s}, {"preview", preview_s}, {"start", start_s}, {"run", run_s}, {"total", total_s}}},
      {"exit_code", exit_code},
      {"session", session.string()},
      {"stray_pids", stray_pids}};
}

Status LinuxCncRunReport::ToStatus() const {
  if (ok) return Status::Ok();
  if (errors.empty()) {
    return Status::Failed(source + ": LinuxCNC stopped in stage '" + stage + "' without an error message (exit code " +
                          std::to_string(exit_code) + "); see " + (session / "controller.log").string());
  }
  const LinuxCncError& e = errors.front();
  std::string where = source;
  if (e.line > 0) where += ":" + std::to_string(e.line);
  std::string message = where + ": LinuxCNC (" + e.stage + "): " + e.text;
  if (!e.block.empty()) message += " [" + e.block + "]";
  if (errors.size() > 1)
    message += " (and " + std::to_string(errors.size() - 1) + " more in " + (session / "result.json").string() + ")";
  return Status::Failed(message);
}

std::vector<int> FormloopControllerProcesses(const fs::path& session) {
  std::vector<int> out;
  for (const ProcessInfo& p : Processes(true)) {
    if (!Alive(p)) continue;
    const std::string marker = MarkerOf(p);
    if (!marker.empty() && (session.empty() || marker == session.string())) out.push_back(p.pid);
  }
  return out;
}

std::vector<int> LinuxCncProcesses() {
  std::vector<int> out;
  for (const ProcessInfo& p : Processes(false)) {
    if (Alive(p) && IsLinuxCncName(p.comm)) out.push_back(p.pid);
  }
  return out;
}

bool LinuxCncLeftNothing(double wait_s, std::string* what_is_left) {
  RunLock lock;
  double waited = 0;
  if (const Status s = lock.Acquire(wait_s, &waited); !s.ok()) {
    *what_is_left = s.message();
    return false;
  }
  std::string left;
  for (const ProcessInfo& p : Processes(false)) {
    if (Alive(p) && IsLinuxCncName(p.comm))
      left += (left.empty() ? "" : ", ") + p.comm + " (pid " + std::to_string(p.pid) + ")";
  }
  std::error_code ec;
  if (fs::exists(kLinuxCncLock, ec)) left += (left.empty() ? "" : ", ") + std::string(kLinuxCncLock);
  *what_is_left = left;
  return left.empty();
}

Result<LinuxCncRunReport> RunOnLinuxCnc(const LinuxCncConfig& config, const fs::path& program,
                                        const fs::path& session_in, const LinuxCncRunOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::error_code ec;
  const fs::path session = fs::absolute(session_in, ec);
  if (fs::exists(session, ec) && !fs::is_empty(session, ec)) {
    return Status::BadInput(Where{.file = session.string()}, "the session folder exists and is not empty",
                            "give a new folder; formloop does not run into an existing one");
  }
  FL_ASSIGN_OR_RETURN(const std::string program_text, ReadFile(program));
  LinuxCncRunReport report;
  report.source = program.string();
  report.session = session;
  report.program = session / program.filename();
  // The controller first (nothing is written while it is busy), then the session: the configuration's
  // files, the program, HOME.
  const auto start = Clock::now();
  RunLock lock;
  FL_RETURN_IF_ERROR(lock.Acquire(options.lock_wait_s, &report.lock_wait_s));
  FL_RETURN_IF_ERROR(CheckControllerFree());
  FL_RETURN_IF_ERROR(MakeDirectories(session / "home"));
  for (const std::string& f : config.files) {
    fs::copy_file(config.dir / f, session / f, fs::copy_options::overwrite_existing, ec);
    if (ec) return Status::IoError("cannot copy " + (config.dir / f).string() + " into the session: " + ec.message());
  }
  if (fs::exists(config.dir / "formloop.var", ec))
    fs::copy_file(config.dir / "formloop.var", session / "formloop.var", ec);
  if (config.files.empty() || !fs::exists(session / kLinuxCncIniName, ec)) {
    return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] FILES"},
                            "does not list formloop.ini");
  }
  if (fs::exists(report.program, ec)) {
    return Status::BadInput(Where{.file = program.string()}, "has the name of a configuration file",
                            "rename the program");
  }
  FL_RETURN_IF_ERROR(WriteFileAtomic(report.program, program_text));

  const bool as_root = ::geteuid() == 0;
  const uid_t rtapi_uid = RtapiUid();
  FifoFolder fifo;
  FL_RETURN_IF_ERROR(fifo.Make(as_root, rtapi_uid));

  // The environment: ours, without an X display, plus the session's variables.
  std::vector<std::string> env;
  const std::set<std::string> replaced = {"HOME",
                                          "RTAPI_FIFO_PATH",
                                          "DISPLAY",
                                          "WAYLAND_DISPLAY",
                                          "FORMLOOP_PROGRAM",
                                          "FORMLOOP_RESULT",
                                          "FORMLOOP_TIMEOUT_S",
                                          "FORMLOOP_LINK_SOCKET",
                                          kSessionVariable};
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry(*e);
    if (replaced.count(entry.substr(0, entry.find('='))) == 0) env.push_back(entry);
  }
  env.push_back("HOME=" + (session / "home").string());
  env.push_back("RTAPI_FIFO_PATH=" + fifo.socket().string());
  if (as_root && std::getenv("RTAPI_UID") == nullptr) env.push_back("RTAPI_UID=" + std::to_string(rtapi_uid));
  env.push_back("FORMLOOP_PROGRAM=" + report.program.string());
  env.push_back("FORMLOOP_RESULT=" + (session / "result.json").string());
  env.push_back("FORMLOOP_TIMEOUT_S=" + FormatExact(options.timeout_s));
  env.push_back(std::string(kSessionVariable) + "=" + session.string());
  if (!options.link_socket.empty()) env.push_back("FORMLOOP_LINK_SOCKET=" + options.link_socket.string());
  std::vector<char*> envp;
  for (std::string& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  // The launcher's path is found before fork(): the child of a process with threads (a collector may run
  // beside) only calls what is safe there.
  FL_ASSIGN_OR_RETURN(std::string launcher, FindProgram(options.launcher));
  std::string flag = "-r", ini = (session / kLinuxCncIniName).string();
  char* argv[] = {launcher.data(), flag.data(), ini.data(), nullptr};
  const std::string log_path = (session / "controller.log").string();

  log::Info("linuxcnc: starting the controller for {} (session {})", program.string(), session.string());
  const pid_t child = ::fork();
  if (child < 0) return Status::IoError(std::string("fork: ") + std::strerror(errno));
  if (child == 0) {
    ::setsid();  // its own process group: a stop reaches the launcher and its children
    if (::chdir(session.c_str()) != 0) ::_exit(126);
    const int out = ::open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int in = ::open("/dev/null", O_RDONLY);
    if (out < 0 || in < 0) ::_exit(126);
    ::dup2(in, 0);
    ::dup2(out, 1);
    ::dup2(out, 2);
    ::execve(argv[0], argv, envp.data());
    static const char kMessage[] = "formloop: cannot start the LinuxCNC launcher (is linuxcnc-uspace installed?)\n";
    (void)!::write(2, kMessage, sizeof(kMessage) - 1);
    ::_exit(127);
  }
  // Wait for the launcher, with a limit well beyond the program's own.
  const double limit_s = options.timeout_s + 120;
  int status = 0;
  bool ended = false, stopped = false;
  while (!ended) {
    const pid_t r = ::waitpid(child, &status, WNOHANG);
    if (r == child) {
      ended = true;
    } else if (r < 0 && errno != EINTR) {
      return Status::Internal(std::string("waitpid: ") + std::strerror(errno));
    } else if (Seconds(start) > limit_s && !stopped) {
      log::Warn("linuxcnc: the controller did not end within {} s; stopping it", FormatFixed(limit_s, 0));
      ::kill(-child, SIGTERM);  // the launcher's trap runs LinuxCNC's Cleanup
      stopped = true;
    } else if (stopped && Seconds(start) > limit_s + 30) {
      ::kill(-child, SIGKILL);
      ::waitpid(child, &status, 0);
      ended = true;
    } else {
      Sleep(0.05);
    }
  }
  report.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);

  // Nothing of the session may outlive the run.
  std::vector<int> left = FormloopControllerProcesses(session);
  const auto sweep = Clock::now();
  while (!left.empty() && Seconds(sweep) < 15) {
    Sleep(0.1);
    left = FormloopControllerProcesses(session);
  }
  if (!left.empty()) {
    report.stray_pids = left;
    log::Warn("linuxcnc: {} process(es) of the session outlived the launcher; stopping them", left.size());
    left = Stop(Stop(left, SIGTERM, 5), SIGKILL, 5);
    if (!left.empty()) return Status::Internal("controller processes of session " + session.string() + " do not end");
  }
  // The launcher removes its lock file in Cleanup; after a forced stop it may still be there, and it is ours.
  if (stopped) fs::remove(kLinuxCncLock, ec);
  report.total_s = Seconds(start);

  const fs::path result = session / "result.json";
  if (!fs::exists(result, ec)) {
    return Status::Failed("LinuxCNC ended (exit code " + std::to_string(report.exit_code) +
                          ") without running the program" +
                          (stopped ? " and was stopped after " + FormatFixed(limit_s, 0) + " s" : "") +
                          "; the end of " + log_path + ":" + Tail(log_path, 12));
  }
  FL_RETURN_IF_ERROR(ReadResult(result, &report));
  std::vector<std::string> lines;
  std::istringstream program_lines(program_text);
  for (std::string l; std::getline(program_lines, l);) lines.push_back(l);
  for (LinuxCncError& e : report.errors) {
    if (e.block.empty() && e.line > 0 && e.line <= static_cast<long>(lines.size())) {
      e.block = lines[static_cast<std::size_t>(e.line - 1)];
      while (!e.block.empty() && (e.block.back() == '\r' || e.block.back() == ' ')) e.block.pop_back();
    }
  }
  if (report.ok && report.exit_code != 0) {
    report.ok = false;
    report.errors.push_back({"shutdown", "linuxcnc exited with code " + std::to_string(report.exit_code), 0, ""});
  }
  log::Info("linuxcnc: {} in {:.1f} s (start {:.1f} s, program {:.1f} s)", report.ok ? "done" : "failed",
            report.total_s, report.start_s, report.run_s);
  return report;
}

}  // namespace formloop::cnc
