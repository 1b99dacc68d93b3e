#pragma once
// The machine side of the handshake as a program a shop loads (spec/tuning-and-link.md §7.4 M0–M5),
// written for Fanuc (custom macro B), LinuxCNC (O-codes, numbered parameters, HAL analog I/O) and
// Sinumerik 840D (R parameters). The program probes every point of a plan and hands each one to the
// collector through the variable block (cnc/handshake.h):
//
//   start   alarm request A > 0 → alarm DIMENSION NG (an earlier part is waiting for the operator)
//   M0      Q = Q + 1
//   M1      wait (dwell t_dwell per look) until C = (1,0,1,0); after T_arm alarm COLLECTOR OFFLINE
//   per point: rapid above, down to the clearance point, probing move to the search end (G31 / G38.2 /
//           MEAS=1), then the send subprogram:
//   M2      v_a = ROUND[(measured_a − reference_a)·10000], |v_a| ≥ 1000 → −2048 (OVERFLOW);
//           PACKED: D = F(v_x)·2^24 + F(v_y)·2^12 + F(v_z) with F(v) = v + 4096 for v < 0; SPLIT: v as is;
//           write the data, then C = (1,1,2,i)  (data first, control last: rule R2)
//   M3      wait until HD = 0 (HD = FIX[C/16384] − 2·FIX[C/32768]); after T_ack alarm COLLECTOR TIMEOUT;
//           PT = 4095 → alarm ABORTED; ST ≠ 1 or PT ≠ i → alarm HANDSHAKE ERROR
//   M4      C = (1,1,3,N)
//   M5      wait until C = 0; a timeout only gives the message MEASUREMENT NOT CONFIRMED
// A probe that never triggers is an alarm (Fanuc: the skip position equals the programmed end;
// Sinumerik: $AC_MEA[1] = 0; LinuxCNC: G38.2 raises its own error).
//
// Where the block lives:
//   Fanuc     common variables #900.. (retained #500–#999), scratch #150–#166
//   Sinumerik R90.. (R0–R99 exist by default), scratch R70–R86
//   LinuxCNC  HAL analog ports: the program writes C, D, Q with M68 E<port> Q<value> (motion.analog-out-NN,
//             immediate) and reads C and A with M66 E<port> L0 (motion.analog-in-NN into #5399). Port k is
//             block address base+k (C = E0, D = E1, Q = E2, A = E3 for PACKED; SPLIT needs num_aio ≥ 6).
//             Each write is committed by toggling digital output <port> (M66 P<port> L0 reads its level
//             back through digital input <port>, then M64 or M65 P<port> flips it; num_dio as num_aio),
//             so every write is an event on HAL, a value equal to the last one included. On the
//             controller each port pair is joined by a small HAL component (cnc/linuxcnc_link.h) that
//             keeps the last value written by either side, so C behaves as one shared variable; the
//             emulator implements exactly that view. HAL floats are doubles, so D travels exact.
//             Scratch parameters #1150–#1166.
// The reference of a point is the stylus-ball centre at nominal contact (surface point + R·normal),
// written with 4 decimals (0.1 µm, the unit of v); ReferenceOf() gives the collector the same values.

#include <array>
#include <string>
#include <vector>

#include "cnc/handshake.h"
#include "cnc/journal.h"
#include "cnc/macro_code.h"
#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/probe_program.h"

namespace formloop::cnc {

struct MachineProgramOptions {
  Dialect dialect = Dialect::kFanuc;
  Layout layout = Layout::kPacked;
  int base = -1;                 // block base; −1 = the dialect's default (Fanuc #900, Sinumerik R90, LinuxCNC E0)
  double dwell_s = 0.020;        // t_dwell (spec R4)
  double arm_timeout_s = 60;     // T_arm
  double ack_timeout_s = 10;     // T_ack
  double finish_timeout_s = 10;  // how long M5 waits for C = 0
  // Probe geometry, feed, safe Z, machine limits and the title (probe.post.title); coordinates are
  // written with probe.post.decimals (Fanuc IS-B: at most 3).
  nc::ProbeProgramOptions probe;
  int program_number = 1000;  // Fanuc: main O1000, send subprogram O1001
  // LinuxCNC: the controller's own record of every probe trip, (PROBEOPEN probe.results_file) around
  // the points, to check what the collector received against (cnc/linuxcnc_link.h).
  bool log_trips = false;
  Status Validate() const;
  int ResolvedBase() const;
  BlockLayout Block() const { return BlockLayout{layout, ResolvedBase()}; }
};

// One point's positions (stylus-ball centre, mm, part frame).
struct ProbePath {
  std::array<double, 3> above{};      // at safe Z over the clearance point
  std::array<double, 3> clearance{};  // clearance_mm outside the surface along the normal
  std::array<double, 3> end{};        // search_mm inside the nominal surface (where the probe move ends)
  std::array<double, 3> reference{};  // nominal centre at contact, rounded to 0.1 µm
};
ProbePath ProbePathOf(const metrology::ProbePoint& point, const nc::ProbeProgramOptions& probe);
// The reference of a point as the program writes it (= ProbePathOf(..).reference).
std::array<double, 3> ReferenceOf(const metrology::ProbePoint& point, double ball_radius_mm);

struct MachineProgram {
  std::vector<MacroFile> files;  // Fanuc, LinuxCNC: one file; Sinumerik: FL_MEASURE.MPF + FL_SEND.SPF
  BlockLayout block;
  int points = 0;
};

// Checks the plan (1..2000 points with ids 1..N in order, every position within the machine limits,
// the probe feed within the feed limit) and writes the program. Nothing is returned on a refusal.
Result<MachineProgram> WriteMachineProgram(const metrology::ProbingPlan& plan, const MachineProgramOptions& options);

// The points of a collected session as a probe log: centre = ReferenceOf(point) + v·kValueUnitMm, the
// approach from `approaches` (plan order) or −n when it is empty, the collector's time. Points with an
// axis out of range (OVERFLOW, RANGE_ERROR) are left out and listed in *skipped; an id that is not in
// the plan is an error.
Result<metrology::ProbeLog> ProbeLogOfSession(const Session& session, const metrology::ProbingPlan& plan,
                                              const std::vector<Eigen::Vector3d>& approaches, double ball_radius_mm,
                                              std::vector<int>* skipped);

// The file name a dialect's main program is written to ("measure.nc", "measure.ngc", "FL_MEASURE.MPF").
std::string MainProgramFileName(Dialect dialect);

}  // namespace formloop::cnc
