#pragma once
// The bad-input suite's machinery: a case is a command line with the files it needs; running it in a
// fresh folder tells whether formloop refused it the way a shop floor needs (the exit code, a message
// that names the file, line or field, nothing written or deleted) or how it failed (catalogue classes
// of issue 17: crash, partial, silent, vague, clear).
//
// Fixtures that need formloop itself (a small run folder, a starter case library, a calibrated probe
// profile) are made once per formloop binary under the test binary's folder (bad-input-fixtures/<key>),
// guarded by a file lock so parallel ctest processes share them; they are read-only for the cases, and
// any change to them fails the case that made it.

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace formloop::bad_input {
namespace fs = std::filesystem;

inline std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void WriteText(const fs::path& path, const std::string& text) {
  if (path.has_parent_path()) fs::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

// Replaces the first occurrence of `from` (which must be there) by `to`.
inline std::string ReplaceOnce(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  if (at == std::string::npos) return text + "\n(replace target '" + from + "' not found)\n";
  return text.replace(at, from.size(), to);
}

// The data rows of a CSV text (after the header and comments), each as a line.
inline std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::stringstream in(text);
  std::string line;
  while (std::getline(in, line)) lines.push_back(line);
  return lines;
}

inline std::string Join(const std::vector<std::string>& lines) {
  std::string out;
  for (const auto& l : lines) out += l + "\n";
  return out;
}

struct Fixtures {
  fs::path dir;
  std::string Read(const std::string& name) const { return ReadText(dir / name); }
};

// The contents of a file a case writes, possibly made from a fixture.
using Content = std::function<std::string(const Fixtures&)>;
inline Content Text(std::string text) {
  return [text](const Fixtures&) { return text; };
}

struct Case {
  std::string name;                                    // unique, [A-Za-z0-9_]
  std::string reader;                                  // what is tried: "point file", "part JSON", "output folder", ...
  std::vector<std::pair<std::string, Content>> files;  // written into the case folder first
  std::vector<std::string> copies;                     // fixture entries copied into the case folder
  std::vector<std::string> setup;                      // shell commands run in the case folder first
  std::string args;  // after the binary; {F} fixture folder, {D} case folder, {DATA} the project's data/
  int exit_code = 2;
  std::vector<std::string> mentions;  // substrings the message (stderr) must hold
  std::string cwd;                    // relative to the case folder (empty: the case folder)
  int timeout_s = 120;
  // A run that can see the problem only mid-way (a measured log against Q) fails into "<failed>" (a folder
  // formloop wrote, with the run's log and the error): that one new folder is then allowed.
  std::string failed;
  // The input crashes a third-party parser on purpose (OpenCASCADE, inside formloop's child process): the case
  // checks formloop's handling of that crash. In a sanitizer build ASan's SEGV handler would report the crash of
  // the uninstrumented library; the case runs with handle_segv=0 so the child dies by the signal as in Release.
  bool third_party_crash = false;
};

enum class Outcome { kClear, kVague, kSilent, kPartial, kCrash };
inline const char* OutcomeName(Outcome o) {
  switch (o) {
    case Outcome::kClear:
      return "clear";
    case Outcome::kVague:
      return "vague";
    case Outcome::kSilent:
      return "silent";
    case Outcome::kPartial:
      return "partial";
    case Outcome::kCrash:
      return "crash";
  }
  return "?";
}

struct Result {
  Outcome outcome = Outcome::kClear;
  int exit_code = 0;  // -1: no normal exit
  int signal = 0;
  bool timed_out = false;
  std::string err, out;
  std::vector<std::string> changes;  // "+ added", "- removed", "~ changed" relative paths
  std::vector<std::string> missing;  // mentions not in the message
  std::string Describe() const;
};

// ---------------------------------------------------------------------------------------------------
// Processes

struct Exit {
  int code = -1;
  int signal = 0;
  bool timed_out = false;
};

// Runs `command` through /bin/sh in `cwd` with stdout/stderr to files, in its own process group, under
// an address-space limit (none when `limit_memory` is false: sanitizer builds reserve terabytes) and a
// timeout after which the group is killed.
inline Exit RunShell(const std::string& command, const fs::path& cwd, const fs::path& out, const fs::path& err,
                     int timeout_s, bool limit_memory) {
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::setpgid(0, 0);
    if (::chdir(cwd.c_str()) != 0) ::_exit(126);
    const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (o < 0 || e < 0) ::_exit(126);
    ::dup2(o, 1);
    ::dup2(e, 2);
    const int devnull = ::open("/dev/null", O_RDONLY);
    if (devnull >= 0) ::dup2(devnull, 0);
    if (limit_memory) {
      const rlimit limit{6ull << 30, 6ull << 30};
      ::setrlimit(RLIMIT_AS, &limit);
    }
    ::setenv("LC_ALL", "C", 1);
    ::execl("/bin/sh", "sh", "-c", command.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  Exit exit;
  if (pid < 0) return exit;
  const auto start = std::chrono::steady_clock::now();
  int status = 0;
  while (true) {
    const pid_t done = ::waitpid(pid, &status, WNOHANG);
    if (done == pid) break;
    if (std::chrono::steady_clock::now() - start > std::chrono::seconds(timeout_s)) {
      ::kill(-pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      exit.timed_out = true;
      return exit;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (WIFEXITED(status)) {
    exit.code = WEXITSTATUS(status);
    // sh reports a child killed by a signal as 128 + signal.
    if (exit.code > 128 && exit.code < 128 + 64) exit.signal = exit.code - 128;
  } else if (WIFSIGNALED(status)) {
    exit.signal = WTERMSIG(status);
  }
  return exit;
}

inline bool SanitizedBuild() {
#if defined(__SANITIZE_ADDRESS__)
  return true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
  return true;
#else
  return false;
#endif
#else
  return false;
#endif
}

// ---------------------------------------------------------------------------------------------------
// Snapshots: what a folder holds (relative path -> kind, size and content hash).

inline std::uint64_t Hash(const std::string& bytes) {
  std::uint64_t h = 1469598103934665603ull;  // FNV-1a
  for (unsigned char c : bytes) h = (h ^ c) * 1099511628211ull;
  return h;
}

using Snapshot = std::map<std::string, std::string>;

// `contents`: hash the files (the case folder); else size and modification time only (the fixtures).
inline Snapshot Take(const fs::path& dir, bool contents) {
  Snapshot s;
  std::error_code ec;
  if (!fs::exists(dir, ec)) return s;
  for (auto it = fs::recursive_directory_iterator(dir, fs::directory_options::skip_permission_denied, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const fs::path rel = fs::relative(it->path(), dir, ec);
    const auto st = it->symlink_status(ec);
    std::string value;
    if (fs::is_symlink(st)) {
      value = "link " + fs::read_symlink(it->path(), ec).string();
      it.disable_recursion_pending();
    } else if (fs::is_directory(st)) {
      value = "dir";
    } else {
      struct stat info {};
      ::lstat(it->path().c_str(), &info);
      value = "file " + std::to_string(info.st_size);
      if (contents) {
        value += " " + std::to_string(Hash(ReadText(it->path())));
      } else {
        value += " " + std::to_string(info.st_mtim.tv_sec) + "." + std::to_string(info.st_mtim.tv_nsec);
      }
    }
    s[rel.string()] = value;
  }
  return s;
}

inline std::vector<std::string> Diff(const Snapshot& before, const Snapshot& after, const std::string& prefix) {
  std::vector<std::string> changes;
  for (const auto& [path, value] : before) {
    const auto it = after.find(path);
    if (it == after.end())
      changes.push_back("- " + prefix + path);
    else if (it->second != value)
      changes.push_back("~ " + prefix + path);
  }
  for (const auto& [path, value] : after) {
    if (!before.count(path)) changes.push_back("+ " + prefix + path);
  }
  return changes;
}

// ---------------------------------------------------------------------------------------------------
// Fixtures

inline std::string Quote(const fs::path& p) { return "'" + p.string() + "'"; }

// A small part: a saddle with a coarse tool path and an 8 x 8 probe grid, two cycles on a virtual
// machine that leaves a systematic error (so loop 0 has a compensated program and side file).
inline std::string LeanPart() {
  return R"({
  "name": "lean",
  "surface": {"reference": "saddle"},
  "material": "H13",
  "tolerance_mm": 0.010,
  "seed": 7,
  "fit": {"samples_u": 20, "samples_v": 20, "check_points": 100},
  "tool": {"number": 1, "radius_mm": 3.0},
  "toolpath": {"scallop_um": 20, "chord_tolerance_um": 5, "max_point_spacing_mm": 2, "feed_mm_per_min": 1500,
               "plunge_feed_mm_per_min": 300, "spindle_rpm": 12000, "clearance_mm": 5},
  "machine": {"name": "virtual-3axis", "travel_min_mm": [-300, -300, -150], "travel_max_mm": [300, 300, 150],
              "max_feed_mm_per_min": 10000, "max_spindle_rpm": 24000,
              "effects": {"tool_radius_error_um": 8, "deflection_um": 20, "thermal_amplitude_um": 6,
                          "thermal_tau_s": 900, "surface_noise_um": 1.0, "probe_noise_um": 0.5}},
  "probing": {"grid": [8, 8], "inset_fraction": 0.05, "ball_radius_mm": 1.0, "clearance_mm": 3, "search_mm": 2,
              "feed_mm_per_min": 200},
  "analysis": {"neighbours": 8, "max_control_net": 4, "coverage_factor": 2},
  "loops": {"max": 2, "max_offset_um": 200}
}
)";
}

// Makes (once per binary) and returns the fixture folder; `error` tells what failed.
inline fs::path EnsureFixtures(const std::string& binary, const fs::path& root, std::string* error) {
  std::error_code ec;
  const auto size = fs::file_size(binary, ec);
  struct stat info {};
  ::stat(binary.c_str(), &info);
  const std::string key =
      std::to_string(Hash(binary + ":" + std::to_string(size) + ":" + std::to_string(info.st_mtim.tv_sec) + "." +
                          std::to_string(info.st_mtim.tv_nsec)));
  fs::create_directories(root, ec);
  const fs::path dir = root / key;
  const int lock = ::open((root / "lock").c_str(), O_RDWR | O_CREAT, 0644);
  if (lock >= 0) ::flock(lock, LOCK_EX);
  if (!fs::exists(dir / "ready")) {
    // Fixtures of other binaries (older builds) go; this one is made afresh.
    for (const auto& entry : fs::directory_iterator(root, ec)) {
      if (entry.is_directory()) fs::remove_all(entry.path(), ec);
    }
    fs::create_directories(dir, ec);
    WriteText(dir / "part.json", LeanPart());
    const std::string b = Quote(binary);
    const std::vector<std::string> steps = {
        b + " -q run part.json --out run --no-report",
        b + " -q kb init kb.sqlite --starter",
        b + " -q calibrate synth-sphere --out sphere.csv --points 40",
        b + " -q calibrate sphere sphere.csv --radius 12.5 --ball 1 --out profile.json",
        b + " -q surfaces sample saddle --nu 20 --nv 20 --out scan.csv",
        "cp run/surface/Q.step Q.step && cp run/toolpath/toolpath.csv tp.csv && "
        "cp run/loop-0/probe_log.csv log.csv && cp run/toolpath/probing_plan.json plan.json && "
        "cp run/toolpath/program.ngc prog.ngc && cp run/loop-0/program_compensated.ngc comp.ngc && "
        "cp run/loop-0/compensation_side.bin side.bin",
    };
    for (const std::string& step : steps) {
      const Exit e = RunShell(step, dir, dir / "step.out", dir / "step.err", 600, false);
      if (e.code != 0) {
        *error = "fixture step failed (" + std::to_string(e.code) + "): " + step + "\n" + ReadText(dir / "step.err");
        if (lock >= 0) ::close(lock);
        return {};
      }
    }
    // A field u,v,ds_um over the plan's (u, v) (a gentle slope), and a model file.
    std::string field = "u,v,ds_um\n";
    std::stringstream rows(ReadText(dir / "run" / "loop-0" / "deviations.csv"));
    std::string line;
    while (std::getline(rows, line) && line.rfind('#', 0) == 0) continue;  // formloop's marker; `line` = the header
    int n = 0;
    while (std::getline(rows, line) && n < 64) {
      std::vector<std::string> cells;
      std::stringstream cs(line);
      std::string cell;
      while (std::getline(cs, cell, ',')) cells.push_back(cell);
      if (cells.size() > 8) field += cells[7] + "," + cells[8] + "," + std::to_string(0.05 * n++) + "\n";
    }
    WriteText(dir / "field.csv", field);
    WriteText(
        dir / "model.json",
        R"({"format": "formloop-model", "version": 1, "effects": [{"name": "tool_radius", "parameters": {"delta_r_um": -5}}]})"
        "\n");
    fs::remove(dir / "step.out", ec);
    fs::remove(dir / "step.err", ec);
    WriteText(dir / "ready", key);
  }
  if (lock >= 0) ::close(lock);
  return dir;
}

// ---------------------------------------------------------------------------------------------------
// Running a case

inline std::string Expand(std::string text, const fs::path& fixtures, const fs::path& dir, const fs::path& data) {
  auto replace_all = [&text](const std::string& from, const std::string& to) {
    for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size())) {
      text.replace(at, from.size(), to);
    }
  };
  replace_all("{F}", fixtures.string());
  replace_all("{D}", dir.string());
  replace_all("{DATA}", data.string());
  return text;
}

inline std::string Result::Describe() const {
  std::string text = std::string(OutcomeName(outcome)) + ": exit " + std::to_string(exit_code);
  if (signal) text += " (signal " + std::to_string(signal) + ")";
  if (timed_out) text += " (timed out)";
  for (const auto& m : missing) text += "\n  message lacks '" + m + "'";
  for (const auto& c : changes) text += "\n  " + c;
  text += "\n  stderr: " + err.substr(0, 2000);
  return text;
}

// Runs one case with `binary` in a fresh folder under `work` and classifies what happened.
inline Result RunCase(const Case& c, const std::string& binary, const fs::path& fixtures, const fs::path& work,
                      const fs::path& data) {
  Result r;
  std::error_code ec;
  const fs::path dir = work / c.name;
  fs::remove_all(dir, ec);
  fs::create_directories(dir);
  const Fixtures f{fixtures};
  for (const std::string& copy : c.copies) {
    fs::copy(fixtures / copy, dir / fs::path(copy).filename(), fs::copy_options::recursive, ec);
  }
  for (const auto& [name, content] : c.files) WriteText(dir / name, Expand(content(f), fixtures, dir, data));
  for (const std::string& command : c.setup) {
    RunShell(Expand(command, fixtures, dir, data), dir, work / (c.name + ".setup.out"), work / (c.name + ".setup.err"),
             60, false);
  }
  const fs::path cwd = c.cwd.empty() ? dir : dir / c.cwd;
  const Snapshot before = Take(dir, true);
  const Snapshot fixtures_before = Take(fixtures, false);
  const fs::path out = work / (c.name + ".stdout"), err = work / (c.name + ".stderr");
  const std::string env =
      c.third_party_crash && SanitizedBuild() ? "ASAN_OPTIONS=\"${ASAN_OPTIONS:+$ASAN_OPTIONS:}handle_segv=0\" " : "";
  const Exit e = RunShell(env + "'" + binary + "' " + Expand(c.args, fixtures, dir, data), cwd, out, err, c.timeout_s,
                          !SanitizedBuild());
  r.exit_code = e.code;
  r.signal = e.signal;
  r.timed_out = e.timed_out;
  r.out = ReadText(out);
  r.err = ReadText(err);
  r.changes = Diff(before, Take(dir, true), "");
  if (!c.failed.empty() && fs::exists(dir / c.failed / ".formloop-output")) {
    std::erase_if(r.changes, [&](const std::string& change) {
      return change.rfind("+ " + c.failed + "/", 0) == 0 || change == "+ " + c.failed;
    });
  }
  // The fixtures are shared by every case, and ctest runs cases in parallel: SQLite's -wal/-shm files beside a
  // fixture library come and go with whichever case has it open. They are not this case's writes; a change of the
  // library itself still shows as "~ FIXTURE/kb.sqlite".
  const auto sqlite_side_file = [](const std::string& change) {
    return change.size() > 4 && (change.ends_with(".sqlite-wal") || change.ends_with(".sqlite-shm"));
  };
  for (const auto& change : Diff(fixtures_before, Take(fixtures, false), "FIXTURE/")) {
    if (!sqlite_side_file(change)) r.changes.push_back(change);
  }
  for (const std::string& m : c.mentions) {
    const std::string want = Expand(m, fixtures, dir, data);
    if (r.err.find(want) == std::string::npos) r.missing.push_back(want);
  }
  bool partial = false;
  for (const auto& change : r.changes) {
    if (change[0] == '+' &&
        (change.find(".partial") != std::string::npos || change.find(".tmp-") != std::string::npos)) {
      partial = true;
    }
  }
  const bool crashed =
      e.timed_out || e.signal != 0 || (e.code != 0 && e.code != 1 && e.code != 2) ||
      r.err.find("unexpected exception") != std::string::npos || r.err.find("terminate called") != std::string::npos ||
      r.err.find("runtime error:") != std::string::npos || r.err.find("AddressSanitizer") != std::string::npos;
  if (crashed) {
    r.outcome = Outcome::kCrash;
  } else if (partial) {
    r.outcome = Outcome::kPartial;
  } else if (e.code == 0 || !r.changes.empty()) {
    r.outcome = Outcome::kSilent;
  } else if (e.code != c.exit_code || !r.missing.empty()) {
    r.outcome = Outcome::kVague;
  } else {
    r.outcome = Outcome::kClear;
  }
  return r;
}

// The fixture root beside the running executable.
inline fs::path FixtureRoot() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return (ec ? fs::temp_directory_path() : self.parent_path()) / "bad-input-fixtures";
}

}  // namespace formloop::bad_input
