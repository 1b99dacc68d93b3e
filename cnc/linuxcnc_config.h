#pragma once
// A LinuxCNC configuration for a simulated 3-axis mill with a touch probe, written by
// `formloop machine linuxcnc config` and run by cnc/linuxcnc_run.h.
//
// The machine (LinuxCNC 2.9, linuxcnc-uspace, no real-time kernel needed): trivial kinematics XYZ in
// mm, joints looped back (motor-pos-cmd → motor-pos-fb), homing without switches (HOME_SEARCH_VEL = 0:
// X and Y are declared at 0, Z at the top of its travel), soft limits at the travel, one velocity and
// acceleration limit for every axis, servo period 1 ms, iocontrol's estop and tool-change loop-backs.
// The DISPLAY is formloop's own program on LinuxCNC's Python module (cnc/linuxcnc_display.py).
//
// HAL, in servo-thread order after motion (motmod with num_aio = num_dio = 16 analog and digital ports
// each way):
//   - a servo clock on motion.analog-in-15 (integ of 1: seconds since the controller started), which
//     formloop's probing program logs as each touch's time (M66 E15 L0, #5399; [FORMLOOP]
//     SERVO_CLOCK_INPUT);
//   - with `link`, the handshake's variable block on analog ports 0..3 (C, D, Q, A): the link component
//     formloop_link.py (cnc/linuxcnc_link.h) joins motion.analog-out-k and motion.analog-in-k into one
//     shared variable and serves the collector; motion.digital-out-k, the program's commit of each
//     write, goes to the component and back to motion.digital-in-k;
//   - the probe surface (cnc/linuxcnc_probe_surface.h) on joint.N.pos-cmd, a comparator that is true
//     when the ball is in contact, and an and2 that passes it to motion.probe-input only while the
//     spindle is off: a touch probe does not cut, and a cutting program moving through the simulated
//     part would otherwise trip "probe tripped during non-probe move".
//
// Files in the folder (all written atomically; a file of the same name that formloop did not write is
// never replaced, see WriteLinuxCncConfig): formloop.ini, formloop.hal, formloop_display.py,
// formloop_link.py (with `link`), tool.tbl and probe_surface.json (what the probe surface is and how
// exactly the net trips: ProbeSurfaceReport). LinuxCNC writes its parameters (formloop.var) in the
// session folder of each run.

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cnc/linuxcnc_probe_surface.h"
#include "core/status.h"

namespace formloop::cnc {

struct LinuxCncMachineOptions {
  std::string name = "formloop simulated XYZ mill";
  // Soft limits, mm (the defaults of `formloop nc`'s --travel and --travel-z).
  Eigen::Vector3d travel_min_mm{-300, -300, -200};
  Eigen::Vector3d travel_max_mm{300, 300, 200};
  double max_velocity_mm_per_s = 100;        // every axis (rapids at 6000 mm/min)
  double max_acceleration_mm_per_s2 = 2000;  // every axis
  long servo_period_ns = 1000000;            // the trigger error is up to feed × this
  bool probe = true;                         // false: no probe surface, motion.probe-input stays low
  bool link = true;                          // the handshake block on analog ports 0..3 (header comment)
  ProbeSurfaceOptions surface;
  int tools = 20;  // tool table entries T1..Tn (geometry is not simulated)
  // The touch probe's tool number, in the tool table too (length 0: the probe surface acts on the joint
  // positions, so the controlled point is the stylus-ball centre): formloop's probing programs change to
  // it and activate its length offset (T.. M6, G43 H..; nc::ProbeProgramOptions::probe_tool, default 99).
  int probe_tool = 99;
  Status Validate() const;
};

struct LinuxCncConfigReport {
  std::filesystem::path ini;
  std::vector<std::string> files;           // written, in the folder
  std::optional<ProbeSurfaceReport> probe;  // none without a probe surface
  nlohmann::json ToJson() const;
};

// The name of the INI file in a configuration folder.
inline constexpr const char* kLinuxCncIniName = "formloop.ini";
// The analog ports of the configuration: the servo clock's input and the link's block (PACKED: C, D,
// Q, A from port 0, the dialect's default base of cnc/machine_program.h).
inline constexpr int kLinuxCncAnalogPorts = 16;
inline constexpr int kLinuxCncServoClockInput = 15;
inline constexpr int kLinuxCncLinkPorts = 4;

// Writes the configuration into `dir` (created if needed). A file that exists there and does not start
// with formloop's marker line is left alone and the whole call is refused (BadInput naming it), so a
// user's own configuration is never overwritten; formloop's own files are replaced.
Result<LinuxCncConfigReport> WriteLinuxCncConfig(const std::filesystem::path& dir,
                                                 const LinuxCncMachineOptions& options);

// A formloop configuration read back: the INI's sections as key → value (last value wins; LinuxCNC's
// repeated keys such as HALFILE are not used by formloop's own checks) and the folder's files.
struct LinuxCncConfig {
  std::filesystem::path dir, ini;
  std::map<std::string, std::map<std::string, std::string>> sections;
  std::vector<std::string> files;  // [FORMLOOP] FILES: what a run copies
  std::string Get(const std::string& section, const std::string& key) const;
};
// Reads `ini` (a formloop.ini or the folder holding one). BadInput when it is not one formloop wrote
// (no [FORMLOOP] section): formloop runs programs only on configurations it generated.
Result<LinuxCncConfig> ReadLinuxCncConfig(const std::filesystem::path& ini_or_dir);

}  // namespace formloop::cnc
