#pragma once
// The part description a process engineer hands to `formloop run` (PART.json), parsed into typed
// options with every default filled in. The resolved description is written back into the run
// folder, so a run can be repeated from its own folder.
//
// {
//   "name": "demo-saddle",                       // run and program names
//   "surface": {"reference": "saddle"},          // analytic reference surface (STEP input: later issue)
//   "material": "H13 tool steel",
//   "tolerance_mm": 0.010,                       // form tolerance α
//   "seed": 20261121,                            // every random draw of the run derives from it
//   "fit": {"samples_u": 50, "samples_v": 50, "tolerance_mm": 0.0001},
//   "tool": {"number": 1, "radius_mm": 3.0},
//   "toolpath": {"scallop_um": 3, "chord_tolerance_um": 1, "feed_mm_per_min": 1500, ...},
//   "machine": {"travel_min_mm": [..], "travel_max_mm": [..], "max_feed_mm_per_min": .., "effects": {..}},
//   "probing": {"grid": [20, 20], "inset_fraction": 0.05, "ball_radius_mm": 1.0, ...},
//   "analysis": {"neighbours": 8, "max_control_net": 8, "coverage_factor": 2},
//   "loops": {"max": 3, "max_offset_um": 200}
// }

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/decomposition.h"
#include "metrology/probe.h"
#include "nc-gen/compensation.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/virtual_machine.h"

namespace formloop::app {

struct PartSpec {
  std::string name = "part";
  std::string surface_reference;        // name of an analytic reference surface
  std::string material = "unspecified";
  double tolerance_mm = 0.010;
  unsigned long long seed = 1;
  int fit_samples_u = 50, fit_samples_v = 50;  // sampling of the ideal surface for the B-spline fit
  recon::GridFitOptions fit;
  int fit_check_points = 2000;          // random points where the fit is checked against the truth
  nc::ToolpathOptions toolpath;
  nc::MachineLimits limits;
  std::string dialect = "linuxcnc";     // controller dialect of the NC and probing programs (machine.dialect)
  sim::MachineEffects effects;          // what the virtual machine does that the plan does not know
  metrology::ProbeModel true_probe;     // the probe the virtual machine really has
  int probe_nu = 20, probe_nv = 20;
  double probe_inset_fraction = 0.05;
  nc::ProbeProgramOptions probe_program;
  metrology::ProbeModel probe;          // the probe model the analysis applies
  metrology::DecompositionOptions analysis;
  int max_loops = 3;
  nc::CompensationOptions compensation;

  nlohmann::json ToJson() const;  // fully resolved
};

Result<PartSpec> ParsePart(const nlohmann::json& json, const std::string& source);
Result<PartSpec> ReadPart(const std::filesystem::path& path);

}  // namespace formloop::app
