#pragma once
// Probing a surface on a LinuxCNC machine, end to end: the probing plan on Q, formloop's LinuxCNC
// probing program for it (fast approach, back-off, slow measuring touch, PROBEOPEN and a LOG line with
// the point id per point: nc-gen/probe_program.h), the run on the controller (cnc/linuxcnc_run.h) and
// the LOG read back, checked against the PROBEOPEN file, into formloop's probe log
// (cnc/linuxcnc_probe_log.h).
//
// Output folder (`out`, created; it must not hold a previous run):
//   probing_plan.json   the plan (ids, points, normals)
//   probe.ngc           the program that ran
//   probe_profile.json  the probe the analysis should assume: the configuration's ball radius and a
//                       pretravel of half a servo period's travel at the measuring feed (LinuxCNC
//                       records the first period with the input set, so the centre is late by a
//                       uniform fraction of v·T; F6 and 1 ms: 0.05 µm ± 0.03 µm)
//   controller/         the run's session folder: configuration copy, controller.log, result.json,
//                       probe_results.txt (PROBEOPEN), probe_points.txt (LOGOPEN)
//   probe_log.csv       formloop's probe log (id, ball centre, approach, time), written last
// A failed run leaves the folder without probe_log.csv and returns the controller's error with the line.

#include <filesystem>

#include "cnc/linuxcnc_config.h"
#include "cnc/linuxcnc_run.h"
#include "core/status.h"
#include "metrology/probe.h"
#include "nc-gen/probe_program.h"
#include "reconstruction/bspline_surface.h"

namespace formloop::cnc {

struct LinuxCncProbingOptions {
  int nu = 3, nv = 3;           // the plan's grid in parameter space
  double inset_fraction = 0.1;  // of each span left free at the domain's edges
  // The program. Defaults: approach at F600 from 2 mm above the surface, back off 0.1 mm, measure at F6
  // (trigger error below 0.1 µm with a 1 ms servo period), search 1 mm beyond the surface. A NaN
  // safe_z_mm is 5 mm above the highest start point; the ball radius, the travel and feed limits and the
  // servo clock's input (linuxcnc_time_input -1) come from the configuration.
  nc::ProbeProgramOptions program = DefaultProgram();
  LinuxCncRunOptions run;
  static nc::ProbeProgramOptions DefaultProgram();
  Status Validate() const;
};

struct LinuxCncProbing {
  metrology::ProbingPlan plan;
  metrology::ProbeModel probe;  // what the analysis should assume
  LinuxCncRunReport run;
  metrology::ProbeLog log;
  std::filesystem::path folder;
};

Result<LinuxCncProbing> ProbeOnLinuxCnc(const LinuxCncConfig& config, const recon::BSplineSurface& q,
                                        const LinuxCncProbingOptions& options, const std::filesystem::path& out);
// The same for a plan made elsewhere (`formloop run`'s); options.nu, nv and inset_fraction are not used.
Result<LinuxCncProbing> ProbePlanOnLinuxCnc(const LinuxCncConfig& config, const metrology::ProbingPlan& plan,
                                            const LinuxCncProbingOptions& options, const std::filesystem::path& out);

// The machine limits of a formloop configuration (travel from [AXIS_*], feed from MAX_LINEAR_VELOCITY).
Result<nc::MachineLimits> LimitsOf(const LinuxCncConfig& config);

}  // namespace formloop::cnc
