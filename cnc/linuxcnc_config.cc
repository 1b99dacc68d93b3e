#include "cnc/linuxcnc_config.h"

#include <fstream>
#include <sstream>
#include <system_error>

#include "cnc/linuxcnc_display_script.h"  // generated from cnc/linuxcnc_display.py
#include "core/atomic_file.h"
#include "core/json_io.h"
#include "core/point_io.h"

namespace formloop::cnc {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// Every file formloop writes into a configuration carries this phrase; a file without it is not ours.
constexpr const char* kMarker = "formloop LinuxCNC configuration";

constexpr const char* kHalFile = "formloop.hal";
constexpr const char* kDisplayFile = "formloop_display.py";
constexpr const char* kLinkFile = "formloop_link.py";
constexpr const char* kToolTable = "tool.tbl";
constexpr const char* kVarFile = "formloop.var";
constexpr const char* kSurfaceFile = "probe_surface.json";

std::string Num(double v) { return FormatExact(v); }

std::string Ini(const LinuxCncMachineOptions& o, const std::vector<std::string>& files,
                const std::optional<ProbeSurfaceReport>& probe) {
  std::ostringstream s;
  s << "# " << kMarker << " (formloop machine linuxcnc config): " << o.name << "\n"
    << "# A simulated XYZ mill for LinuxCNC 2.9 (linuxcnc-uspace); run it with `formloop machine linuxcnc run`.\n\n";
  s << "[EMC]\nVERSION = 1.1\nMACHINE = " << o.name << "\nDEBUG = 0\n\n";
  s << "[DISPLAY]\n# formloop's display program: runs FORMLOOP_PROGRAM, writes FORMLOOP_RESULT, then LinuxCNC stops.\n"
    << "DISPLAY = ./" << kDisplayFile << "\n\n";
  s << "[TASK]\nTASK = milltask\nCYCLE_TIME = 0.001\n\n";
  s << "[RS274NGC]\nPARAMETER_FILE = " << kVarFile << "\n\n";
  s << "[EMCMOT]\nEMCMOT = motmod\nCOMM_TIMEOUT = 1.0\nSERVO_PERIOD = " << o.servo_period_ns << "\n\n";
  s << "[EMCIO]\nEMCIO = io\nCYCLE_TIME = 0.100\nTOOL_TABLE = " << kToolTable << "\n\n";
  s << "[HAL]\nHALFILE = " << kHalFile << "\n\n";
  s << "[TRAJ]\nCOORDINATES = XYZ\nLINEAR_UNITS = mm\nANGULAR_UNITS = degree\n"
    << "DEFAULT_LINEAR_VELOCITY = " << Num(o.max_velocity_mm_per_s) << "\n"
    << "MAX_LINEAR_VELOCITY = " << Num(o.max_velocity_mm_per_s) << "\n"
    << "DEFAULT_LINEAR_ACCELERATION = " << Num(o.max_acceleration_mm_per_s2) << "\n"
    << "MAX_LINEAR_ACCELERATION = " << Num(o.max_acceleration_mm_per_s2) << "\n\n";
  s << "[KINS]\nJOINTS = 3\nKINEMATICS = trivkins coordinates=XYZ\n\n";
  const char* axes = "XYZ";
  for (int j = 0; j < 3; ++j) {
    s << "[AXIS_" << axes[j] << "]\nMIN_LIMIT = " << Num(o.travel_min_mm[j])
      << "\nMAX_LIMIT = " << Num(o.travel_max_mm[j]) << "\nMAX_VELOCITY = " << Num(o.max_velocity_mm_per_s)
      << "\nMAX_ACCELERATION = " << Num(o.max_acceleration_mm_per_s2) << "\n\n";
  }
  for (int j = 0; j < 3; ++j) {
    // Homing without switches: the joint is declared at HOME_OFFSET where it stands (Z at the top).
    const double home = j == 2 ? o.travel_max_mm[j] : 0.0;
    s << "[JOINT_" << j << "]\nTYPE = LINEAR\nMIN_LIMIT = " << Num(o.travel_min_mm[j])
      << "\nMAX_LIMIT = " << Num(o.travel_max_mm[j]) << "\nMAX_VELOCITY = " << Num(o.max_velocity_mm_per_s)
      << "\nMAX_ACCELERATION = " << Num(o.max_acceleration_mm_per_s2) << "\nFERROR = 1\nMIN_FERROR = 0.25"
      << "\nHOME = " << Num(home) << "\nHOME_OFFSET = " << Num(home)
      << "\nHOME_SEARCH_VEL = 0\nHOME_LATCH_VEL = 0\nHOME_SEQUENCE = 0\n\n";
  }
  s << "[FORMLOOP]\nFORMAT = " << kMarker << "\nVERSION = 1\n";
  std::string joined;
  for (const std::string& f : files) joined += (joined.empty() ? "" : " ") + f;
  s << "# what a run copies into its session folder\nFILES = " << joined << "\n";
  s << "SERVO_CLOCK_INPUT = " << kLinuxCncServoClockInput << "\n";
  s << "LINK_PORTS = " << (o.link ? kLinuxCncLinkPorts : 0) << "\n";
  s << "# the touch probe's tool number (in " << kToolTable << ")\nPROBE_TOOL = " << o.probe_tool << "\n";
  if (probe) {
    s << "PROBE_SURFACE = " << probe->surface << "\nPROBE_BALL_RADIUS_MM = " << Num(probe->ball_radius_mm)
      << "\nPROBE_SHIFT_UM = " << Num(probe->pose.shift_um.x()) << " " << Num(probe->pose.shift_um.y()) << " "
      << Num(probe->pose.shift_um.z()) << "\nPROBE_ROTATION_URAD = " << Num(probe->pose.rotation_urad.x()) << " "
      << Num(probe->pose.rotation_urad.y()) << " " << Num(probe->pose.rotation_urad.z()) << "\n";
  } else {
    s << "PROBE_SURFACE =\n";
  }
  return s.str();
}

std::string Hal(const LinuxCncMachineOptions& o, const std::optional<ProbeSurface>& probe) {
  std::ostringstream s;
  s << "# " << kMarker << ": HAL for " << o.name << "\n\n";
  s << "loadrt [KINS]KINEMATICS\n"
    << "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS num_aio="
    << kLinuxCncAnalogPorts << " num_dio=" << kLinuxCncAnalogPorts << "\n"
    << "addf motion-command-handler servo-thread\naddf motion-controller servo-thread\n\n";
  s << "# joints: commanded position looped back as the feedback; pos-x/y/z are the machine positions\n";
  for (int j = 0; j < 3; ++j) {
    const std::string axis(1, "xyz"[j]);
    s << "net motor-" << axis << " joint." << j << ".motor-pos-cmd => joint." << j << ".motor-pos-fb\n";
    s << "net pos-" << axis << " <= joint." << j << ".pos-cmd\n";
  }
  s << "\n# estop and tool change loop back (no hardware)\n"
    << "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in\n"
    << "net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared\n"
    << "net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed\n\n";
  const std::string clock = (kLinuxCncServoClockInput < 10 ? "0" : "") + std::to_string(kLinuxCncServoClockInput);
  s << "# servo clock: seconds since start on motion.analog-in-" << clock << " (probing programs log it with M66 E"
    << kLinuxCncServoClockInput << " L0)\n"
    << "loadrt integ names=servo-clock\naddf servo-clock servo-thread\nsetp servo-clock.in 1\n"
    << "net servo-seconds servo-clock.out => motion.analog-in-" << clock << "\n\n";
  if (o.link) {
    s << "# the handshake's variable block (C, D, Q, A) on analog ports 0.." << kLinuxCncLinkPorts - 1
      << ": one shared variable per port;\n# the program commits each write by toggling digital output k, "
         "which it reads back on digital input k\n"
      << "loadusr -Wn formloop-link ./" << kLinkFile << " " << kLinuxCncLinkPorts << "\n";
    for (int k = 0; k < kLinuxCncLinkPorts; ++k) {
      const std::string port = (k < 10 ? "0" : "") + std::to_string(k);
      s << "net link-machine-" << k << " motion.analog-out-" << port << " => formloop-link.machine-" << k << "\n"
        << "net link-commit-" << k << " motion.digital-out-" << port << " => formloop-link.commit-" << k
        << " motion.digital-in-" << port << "\n"
        << "net link-block-" << k << " formloop-link.block-" << k << " => motion.analog-in-" << port << "\n";
    }
    s << "\n";
  }
  if (!probe) {
    s << "# no probe surface: motion.probe-input stays low\n";
    return s.str();
  }
  const ProbeSurfaceReport& r = probe->report;
  s << "# probe surface: " << r.description << "\n# placed with shift " << Num(r.pose.shift_um.x()) << " "
    << Num(r.pose.shift_um.y()) << " " << Num(r.pose.shift_um.z()) << " um and rotation "
    << Num(r.pose.rotation_urad.x()) << " " << Num(r.pose.rotation_urad.y()) << " " << Num(r.pose.rotation_urad.z())
    << " urad; ball radius " << Num(r.ball_radius_mm) << " mm; " << r.iterations << " fixed-point steps, "
    << r.components << " components; trips within " << FormatFixed(r.max_trigger_error_nm, 3)
    << " nm of the ball radius (" << kSurfaceFile << ")\n";
  s << probe->net.Hal("psurf", "servo-thread", {"pos-x", "pos-y", "pos-z"}, "probe-gap");
  s << "\n# contact when the gap is negative; live only while the spindle is off\n"
    << "loadrt comp names=probe-contact\nloadrt not names=probe-spindle-off\nloadrt and2 names=probe-live\n"
    << "addf probe-contact servo-thread\naddf probe-spindle-off servo-thread\naddf probe-live servo-thread\n"
    << "setp probe-contact.in1 0\nsetp probe-contact.hyst 0\n"
    << "net probe-gap => probe-contact.in0\n"
    << "net probe-touching probe-contact.out => probe-live.in0\n"
    << "net spindle-on spindle.0.on => probe-spindle-off.in\n"
    << "net spindle-off probe-spindle-off.out => probe-live.in1\n"
    << "net probe-tripped probe-live.out => motion.probe-input\n";
  return s.str();
}

std::string ToolTable(const LinuxCncMachineOptions& o) {
  std::string t = "; " + std::string(kMarker) + ": tool table (the simulated machine does not use tool geometry)\n";
  for (int k = 1; k <= o.tools; ++k) t += "T" + std::to_string(k) + " P" + std::to_string(k) + " Z0 D0 ;\n";
  if (o.probe_tool > o.tools) {
    const std::string n = std::to_string(o.probe_tool);
    t += "T" + n + " P" + n + " Z0 D0 ;touch probe\n";
  }
  return t;
}

// A file formloop may replace: absent, or one of its own.
Status MayWrite(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) return Status::Ok();
  auto text = ReadFile(path);
  if (text.ok() && text->find(kMarker) != std::string::npos) return Status::Ok();
  return Status::BadInput(Where{.file = path.string()}, "exists and was not written by formloop; nothing was written",
                          "choose an empty folder for the configuration");
}

}  // namespace

Status LinuxCncMachineOptions::Validate() const {
  for (int j = 0; j < 3; ++j) {
    if (!(travel_min_mm[j] < travel_max_mm[j])) {
      return Status::BadInput(Where{.field = "travel"},
                              std::string("axis ") + "XYZ"[j] + ": minimum must be below maximum");
    }
  }
  if (!(max_velocity_mm_per_s > 0 && max_velocity_mm_per_s <= 2000)) {
    return Status::BadInput(Where{.field = "max_velocity_mm_per_s"}, "must be in (0, 2000]");
  }
  if (!(max_acceleration_mm_per_s2 > 0 && max_acceleration_mm_per_s2 <= 50000)) {
    return Status::BadInput(Where{.field = "max_acceleration_mm_per_s2"}, "must be in (0, 50000]");
  }
  if (servo_period_ns < 100000 || servo_period_ns > 10000000) {
    return Status::BadInput(Where{.field = "servo_period_ns"}, "must be in 100000..10000000 (0.1 to 10 ms)");
  }
  if (tools < 1 || tools > 999) return Status::BadInput(Where{.field = "tools"}, "must be in 1..999");
  if (probe_tool < 1 || probe_tool > 9999) return Status::BadInput(Where{.field = "probe_tool"}, "must be in 1..9999");
  if (name.find_first_of("\n\r[]") != std::string::npos) {
    return Status::BadInput(Where{.field = "name"}, "must be one line without brackets");
  }
  return probe ? surface.Validate() : Status::Ok();
}

json LinuxCncConfigReport::ToJson() const {
  return {{"ini", ini.string()}, {"files", files}, {"probe_surface", probe ? probe->ToJson() : json(nullptr)}};
}

Result<LinuxCncConfigReport> WriteLinuxCncConfig(const fs::path& dir, const LinuxCncMachineOptions& options) {
  FL_RETURN_IF_ERROR(options.Validate());
  std::optional<ProbeSurface> probe;
  if (options.probe) {
    FL_ASSIGN_OR_RETURN(ProbeSurface built, BuildProbeSurface(options.surface));
    probe = std::move(built);
  }
  LinuxCncConfigReport report;
  report.files = {kLinuxCncIniName, kHalFile, kDisplayFile, kToolTable};
  if (options.link) report.files.emplace_back(kLinkFile);
  if (probe) {
    report.files.emplace_back(kSurfaceFile);
    report.probe = probe->report;
  }
  std::vector<std::pair<std::string, std::string>> contents = {
      {kLinuxCncIniName, Ini(options, report.files, report.probe)},
      {kHalFile, Hal(options, probe)},
      {kDisplayFile, internal::kLinuxCncDisplayScript},
      {kToolTable, ToolTable(options)}};
  if (options.link) contents.emplace_back(kLinkFile, internal::kLinuxCncLinkComponent);
  if (probe) {
    json surface = probe->report.ToJson();
    surface["format"] = std::string(kMarker) + ": probe surface";
    contents.emplace_back(kSurfaceFile, surface.dump(2) + "\n");
  }
  for (const auto& [name, text] : contents) FL_RETURN_IF_ERROR(MayWrite(dir / name));
  FL_RETURN_IF_ERROR(MakeDirectories(dir));
  for (const auto& [name, text] : contents) FL_RETURN_IF_ERROR(WriteFileAtomic(dir / name, text));
  std::error_code ec;
  for (const char* program : {kDisplayFile, kLinkFile}) {
    if (!fs::exists(dir / program)) continue;
    fs::permissions(dir / program, fs::perms::owner_exec | fs::perms::group_exec | fs::perms::others_exec,
                    fs::perm_options::add, ec);
    if (ec) return Status::IoError("cannot make " + (dir / program).string() + " executable: " + ec.message());
  }
  report.ini = dir / kLinuxCncIniName;
  return report;
}

std::string LinuxCncConfig::Get(const std::string& section, const std::string& key) const {
  const auto s = sections.find(section);
  if (s == sections.end()) return "";
  const auto k = s->second.find(key);
  return k == s->second.end() ? "" : k->second;
}

Result<LinuxCncConfig> ReadLinuxCncConfig(const fs::path& ini_or_dir) {
  LinuxCncConfig config;
  std::error_code ec;
  config.ini = fs::is_directory(ini_or_dir, ec) ? ini_or_dir / kLinuxCncIniName : ini_or_dir;
  config.ini = fs::absolute(config.ini, ec);
  config.dir = config.ini.parent_path();
  FL_ASSIGN_OR_RETURN(const std::string text, ReadFile(config.ini));
  std::istringstream in(text);
  std::string line, section;
  long line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#' || line[first] == ';') continue;
    const auto last = line.find_last_not_of(" \t\r");
    line = line.substr(first, last - first + 1);
    if (line.front() == '[') {
      if (line.back() != ']') {
        return Status::BadInput(Where{.file = config.ini.string(), .line = line_no}, "section header without ']'");
      }
      section = line.substr(1, line.size() - 2);
      config.sections[section];
      continue;
    }
    const auto eq = line.find('=');
    if (eq == std::string::npos) continue;
    auto trim = [](std::string s) {
      const auto a = s.find_first_not_of(" \t");
      const auto b = s.find_last_not_of(" \t");
      return a == std::string::npos ? std::string() : s.substr(a, b - a + 1);
    };
    config.sections[section][trim(line.substr(0, eq))] = trim(line.substr(eq + 1));
  }
  if (config.Get("FORMLOOP", "FORMAT") != kMarker) {
    return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] FORMAT"},
                            "is not a configuration formloop wrote; formloop runs programs only on the simulated "
                            "machines it generates",
                            "write one with `formloop machine linuxcnc config --out DIR`");
  }
  std::istringstream files(config.Get("FORMLOOP", "FILES"));
  for (std::string f; files >> f;) {
    if (f.find('/') != std::string::npos || f == "..") {
      return Status::BadInput(Where{.file = config.ini.string(), .field = "[FORMLOOP] FILES"},
                              "'" + f + "' is not a file name in the configuration folder");
    }
    config.files.push_back(f);
  }
  return config;
}

}  // namespace formloop::cnc
