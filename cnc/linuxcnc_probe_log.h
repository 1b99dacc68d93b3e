#pragma once
// What formloop's LinuxCNC probing program leaves behind, read into formloop's probe log.
//
// The program (nc-gen/probe_program.h, "linuxcnc" with a linuxcnc_log_file) writes through LinuxCNC's
// (LOG,...) one line per point after its measuring touch,
//
//   formloop probe log 1: point id x y z tripped ax ay az [t_s]      (first line)
//   point 12 10.000000 10.000000 6.506083 1.000000 -0.099751 0.049876 -0.993763 12.345000
//
// (LinuxCNC prints parameters with six decimals: 1 nm), and LinuxCNC's own (PROBEOPEN) file receives
// every G38 trip as "x y z a b c u v w". Both are in the work coordinate system of the program (checked
// with a G54 offset: #5061..#5063 and the PROBEOPEN line agree). ReadLinuxCncProbeLog takes the ids,
// centres, approach directions and times from the LOG file and checks them against the PROBEOPEN file:
// it must hold `touches` lines per point, and each point's last one must equal the logged centre within
// 1e-6 mm. A point whose probe did not trip, a repeated id, a non-unit approach, a count that does not
// add up or a disagreement is an error naming the file and line.

#include <filesystem>

#include "core/status.h"
#include "metrology/probe.h"

namespace formloop::cnc {

// `probe_file` may be empty (no cross-check). `touches`: G38 trips per point (2 with a slow second touch).
Result<metrology::ProbeLog> ReadLinuxCncProbeLog(const std::filesystem::path& log_file,
                                                 const std::filesystem::path& probe_file, int touches);

}  // namespace formloop::cnc
