#pragma once
// The part description a process engineer hands to `formloop run` (PART.json), parsed into typed
// options with every default filled in. The resolved description is written back into the run
// folder, so a run can be repeated from its own folder.
//
// {
//   "name": "demo-saddle",                       // run and program names
//   "surface": {"reference": "saddle"},          // analytic reference surface, or a parametric kind:
//              {"kind": "gaussian_pocket", "params": {"size_mm": 80, ...}, "samples": 41}  (retrieval/starter.h)
//              {"cad": "part.step", "faces": [3, 4] | "face_names": ["top"]}  or  {"points": "scan.ply"}
//              (files relative to the part file; app/surface_source.h)
//   "shape_family": "bowl", "finish_ra_um": 0.8, "batch_size": 1,   // retrieval description (optional)
//   "material": "H13",                           // a leaf or alias of data/taxonomies/material.txt
//   "tolerance_mm": 0.010,                       // form tolerance α
//   "seed": 20261121,                            // every random draw of the run derives from it
//   "fit": {"samples_u": 50, "samples_v": 50, "tolerance_mm": 0.0001},
//   "tool": {"number": 1, "radius_mm": 3.0, "flutes": 2},
//   "tools": [{"number": 2, "radius_mm": 1.5}, ...],   // magazine for the simulation-correction step
//   "toolpath": {"scallop_um": 3, "chord_tolerance_um": 1, "feed_mm_per_min": 1500, ...},
//   "machine": {"name": "vm-1", "class": "3-axis", "travel_min_mm": [..], "travel_max_mm": [..], "max_feed_mm_per_min":
//   ..,
//               "effects": {"format": "formloop-model", "version": 1, "effects": [..]}},   // simulation/model.h
//   "probing": {"grid": [20, 20], "inset_fraction": 0.05, "edge_margin_mm": 2, "ball_radius_mm": 1.0, ...,
//               "profile": "probe.json"},        // a probe profile from `formloop calibrate sphere` (or inline)
//   "analysis": {"neighbours": 8, "max_control_net": 8, "coverage_factor": 2},
//   "loops": {"max": 3, "max_offset_um": 200},
//   "separating_experiment": "library"           // optional (issue 20): apply the separating experiment the
//                                                // case library holds for this machine/tool/material and
//                                                // store this part's proposals there; or a diagnosis.json of
//                                                // `formloop diagnose` (its proposals' "next_part"), or
//                                                // {"proposals": [next_part, ...]} inline
//   "direct_measurements": "readings.json"       // optional (issue 20): readings taken beside the probe log
//                                                // (tool setter, reference sphere, datum; the format of
//                                                // `formloop diagnose --direct`, relative to the part file),
//                                                // or the list inline; the first-cycle diagnosis uses them
// }

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/surface_source.h"
#include "core/status.h"
#include "metrology/decomposition.h"
#include "metrology/probe.h"
#include "nc-gen/compensation.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_program.h"
#include "nc-gen/toolpath.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/diagnose.h"
#include "simulation/model.h"
#include "simulation/proposal_plan.h"
#include "simulation/virtual_machine.h"

namespace formloop::app {

struct PartSpec {
  std::string name = "part";
  std::string surface_reference;  // name of an analytic reference surface, or ...
  std::string surface_kind;       // ... a parametric kind (reconstruction/surface_family.h) with its parameters
  std::map<std::string, double> surface_params;
  int surface_samples = 41;                 // grid samples per direction of a parametric kind's fit
  std::optional<SurfaceFile> surface_file;  // ... or CAD faces or a scan (app/surface_source.h)
  // Retrieval description (retrieval::PartDescription): the shape concept defaults from the surface.
  std::string shape_family;
  double finish_ra_um = 0.8;
  int batch_size = 1;
  std::string machine_class = "3-axis";
  std::string machine_name = "virtual-3axis";  // key of learned models in the case library
  int flutes = 2;                              // of the ball-end tools (feed per tooth)
  std::vector<nc::BallEndTool> tools;          // the magazine the planner may choose from (default: the part's tool)
  std::string material = "unspecified";
  double tolerance_mm = 0.010;
  unsigned long long seed = 1;
  int fit_samples_u = 50, fit_samples_v = 50;  // sampling of the ideal surface for the B-spline fit
  recon::GridFitOptions fit;
  int fit_check_points = 2000;  // random points where the fit is checked against the truth
  nc::ToolpathOptions toolpath;
  nc::MachineLimits limits;
  std::string dialect = "linuxcnc";  // controller dialect of the NC and probing programs (machine.dialect)
  // machine.effects: what the virtual machine does that the plan does not know, as the effect catalogue's
  // model JSON (simulation/model.h); absent: `--machine virtual` takes the machine's profile. The old
  // fields (tool_radius_error_um, deflection_um, thermal_amplitude_um, thermal_tau_s, surface_noise_um,
  // probe_noise_um) are still read, turned into the model, with a deprecation note in the log.
  std::optional<sim::Model> effects;
  metrology::ProbeModel true_probe;  // the probe the virtual machine really has
  int probe_nu = 20, probe_nv = 20;
  double probe_inset_fraction = 0.05;
  double probe_edge_margin_mm = metrology::kProbeEdgeMarginMm;  // from a trimmed face's edge (metrology/probe.h)
  // probing.profile / machine.probe.profile: the probe models came from probe profiles (lobing included);
  // the resolved part then carries them inline.
  bool probe_profile_given = false, true_probe_profile_given = false;
  nc::ProbeProgramOptions probe_program;
  metrology::ProbeModel probe;  // the probe model the analysis applies
  metrology::DecompositionOptions analysis;
  int max_loops = 3;
  nc::CompensationOptions compensation;
  // separating_experiment (simulation/proposal_plan.h): "" none; "library": the proposals the case library
  // holds for this machine/tool/material (found by the run), and this part's own proposals stored there;
  // "given": `proposals` (read from a file of `formloop diagnose` or inline).
  std::string separating_experiment;
  std::vector<sim::PlannedProposal> proposals;
  // direct_measurements (simulation/diagnose.h): readings of this part's machine, tool, probe and set-up
  // taken beside the probe log — a tool setter, a reference sphere, the fixture's datum — as the separating
  // experiment asks for them; rows of the part's first-cycle diagnosis (as `formloop diagnose --direct`).
  std::vector<sim::DirectMeasurement> direct;

  nlohmann::json ToJson() const;     // fully resolved
  std::string SurfaceName() const;   // the reference name, "<kind>(p=v, ...)", "cad:FILE[faces]" or "scan:FILE"
  std::string ShapeConcept() const;  // shape_family, else the shape taxonomy leaf of the surface
};

Result<PartSpec> ParsePart(const nlohmann::json& json, const std::string& source);
Result<PartSpec> ReadPart(const std::filesystem::path& path);

// The work of running `part` with the tool-path options `plan` (core/work_estimate.h): cutter locations
// and probe points, memory, time on the machine over part.max_loops cycles and the run folder's size,
// from the part's surface (nc-gen/raster_estimate.h). Refuses above the stated limits (unless --yes),
// naming `source` and the field that drives the estimate. `q`: the fitted surface when there is one.
Status CheckPartWork(const PartSpec& part, const nc::ToolpathOptions& plan, const std::string& source,
                     const recon::BSplineSurface* q = nullptr);

}  // namespace formloop::app
