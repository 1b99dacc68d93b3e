#pragma once
// The stages of `formloop run` (app/pipeline.h), each a function with a typed result, in the order
// RunStages calls them. Each writes its own files into the run folder through RunFolderWriter and
// nothing else; the decisions behind them live in the layers below (retrieval/, planning/, nc-gen/,
// simulation/, metrology/). Internal to the app: the tests drive the pipeline through RunPart.

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "app/case_knowledge.h"
#include "app/part.h"
#include "app/pipeline.h"
#include "app/run_folder.h"
#include "core/status.h"
#include "kb/library.h"
#include "metrology/decomposition.h"
#include "metrology/probe.h"
#include "nc-gen/compensation.h"
#include "nc-gen/post.h"
#include "nc-gen/probe_reach.h"
#include "nc-gen/toolpath.h"
#include "planning/case_plan.h"
#include "reconstruction/bspline_surface.h"
#include "reconstruction/surface_family.h"
#include "retrieval/features.h"
#include "simulation/diagnose.h"
#include "simulation/model.h"
#include "simulation/proposal_plan.h"

namespace formloop::app::stages {

// formloop's version as programs and summary.json name it: core/version.h (CMake's project version).
extern const char* const kVersion;

// The machine a part is cut on: a virtual machine with its true effects, a real one's probe logs, or a
// LinuxCNC controller running formloop's probing program on its simulated part (cnc/linuxcnc_probing.h).
struct Machine {
  bool virtual_machine = true;
  std::string name;
  sim::Model model;                         // the profile's true effects (virtual)
  metrology::ProbeModel probe;              // the probe the machine really has (virtual)
  std::vector<std::string> measured;        // copies of the measured logs in inputs/measured (real machine)
  std::vector<std::string> measured_given;  // the logs as the user named them (for errors the user can fix)
  // LinuxCNC: its formloop.ini. One cycle: the simulated part is the configuration's probe surface, which
  // a compensated program cannot change, so the cutting program is not run and there is no second cycle.
  std::string linuxcnc;
};

// 1. Inputs: the machine resolved, the resolved part (machine_name = the machine really used) and the
// options written to inputs/; the seeds of the stages forked from the part's seed.
struct Inputs {
  PartSpec part;
  Machine machine;
  std::uint64_t fit_seed = 0, machine_seed = 0, plan_seed = 0, analysis_seed = 0;
};
Result<Inputs> ResolveInputs(const PartSpec& given, const RunOptions& options, const std::filesystem::path& data_dir,
                             const RunFolderWriter& folder);

// The part's surface family as recon::BuildFamilySurface takes it (the run's surface stage, retrieve's part files).
recon::FamilySurfaceOptions FamilySurfaceOptionsOf(const PartSpec& part, std::uint64_t seed, int check_points);

// 2. The ideal surface Q: a reference surface or a parametric kind fitted as a B-spline, checked against
// its defining function at random points not used in the fit, or CAD faces or a scan
// (app/surface_source.h) (surface/).
struct Surface {
  recon::BSplineSurface q;
  recon::FitReport report;
  nlohmann::json description;
  double fit_check_max_mm = 0;  // largest known distance from the given surface (NaN: unknown, a scan)
};
Result<Surface> BuildSurface(const PartSpec& part, std::uint64_t seed, const RunFolderWriter& folder);

// 3. Retrieval from the case library and the route (retrieval.json).
struct Retrieved {
  std::optional<retrieval::PartFeatures> features;
  std::optional<kb::CaseRecord> best;
  std::optional<kb::CaseRecord> own;  // the part's own case (same uid), for an update
  std::string route = "default";
  double similarity = -1;
  nlohmann::json report = nlohmann::json::object();
};
Result<Retrieved> Retrieve(const PartSpec& part, const recon::BSplineSurface& q, const RunOptions& options,
                           const std::filesystem::path& data_dir, const RunFolderWriter& folder);

// 4. The plan by route (planning::ChoosePlan; sim_correction.json on the simulate route).
Result<planning::PlanChoice> ChoosePlan(const Inputs& in, const Retrieved& retrieved, const recon::BSplineSurface& q,
                                        bool learn, const RunFolderWriter& folder);

// 4b. The separating experiment the part asks for (part.separating_experiment; simulation/proposal_plan.h):
// the proposals given in the part file, or those the case library holds for this machine/tool/material.
struct Experiment {
  std::vector<sim::PlannedProposal> proposals;  // empty: none to apply
  std::string source;                           // "part file", "case library, case X", "none in the case library"
  bool asked = false;                           // the part asks for one (and, "library", to store its own)
};
Result<Experiment> FindSeparatingExperiment(const PartSpec& part, const RunOptions& options,
                                            const std::string& retrieved_uid, const nc::ToolpathOptions& plan);

// A program as written into the run folder, with its moves as read back from its text (the text itself is
// not kept: a million-point program is ~30 MB).
struct Program {
  std::filesystem::path path;  // relative to the run folder
  std::vector<nc::ProgramMove> moves;
};

// 5. Tool path, the nominal program, the probing plan and the probing program (toolpath/). `planned`: the
// plan's tool path when the plan stage planned it already (PlanChoice::path; taken over, not copied), used
// when its options are the plan's; else (null) the path is planned here.
struct Programs {
  nc::Toolpath nominal;
  nc::PostOptions post;
  std::string extension;  // of the dialect's programs
  Program program;
  metrology::ProbingPlan probing_plan;
  // Per plan point, its approach when the separating experiment added tilted points (else empty: −n).
  std::vector<Eigen::Vector3d> probe_approaches;
  // Q for the probing programs' check that the probe keeps clear of the part (nc-gen/probe_program.h).
  std::optional<recon::FootPointProjector> part_surface;
  // The grid's points left out because the probe cannot reach them clear of the part (not in probing_plan).
  std::vector<nc::UnreachableProbePoint> unreachable;
};
// With an experiment's proposals, their tilted re-probe points are appended to the probing plan and
// carried by the probing program (toolpath/separating_experiment.json says what was applied). Points the
// probe cannot reach clear of the part are then left out of the plan (toolpath/probing_left_out.json).
Result<Programs> WritePrograms(const PartSpec& part, const recon::BSplineSurface& q, const nc::ToolpathOptions& plan,
                               std::shared_ptr<nc::Toolpath> planned, const Experiment& experiment,
                               const RunFolderWriter& folder);

// The sum of the fields compensated so far (mm): the pre-compensation and one term per loop.
struct CompensatedField {
  std::vector<std::function<double(double, double)>> terms;
  double operator()(double u, double v) const;
};

// 6. Pre-compensation by the case's learned model when the plan asks for it; the program the first
// cycle cuts; plan.json.
struct FirstCut {
  CompensatedField field;
  std::optional<Program> program;  // the pre-compensated program (none: the first cycle cuts the nominal one)
  double precompensation_scale = 0;
};
Result<FirstCut> Precompensate(const PartSpec& part, const recon::BSplineSurface& q, const planning::PlanChoice& choice,
                               const Programs& programs, const std::string& case_uid, std::uint64_t seed,
                               const RunFolderWriter& folder);

// 7a. One cycle's machining: the virtual machine cuts `program` and probes, or LinuxCNC runs formloop's
// probing program on the plan (loop-K/linuxcnc/), or the cycle's measured log is taken (loop-K/probe_log.csv,
// machine.json). Returns the log as read back, as a real machine's would be.
struct Machined {
  metrology::ProbeLog log;
  std::vector<sim::CutterLocation> cutter_locations;  // of the program cut
  // False when the program was not cut (LinuxCNC: the part is its probe surface); the diagnosis then
  // screens only the effects that need no tool path (sim::DiagnosePlanOnly).
  bool cut = true;
};
Result<Machined> MachineCycle(const Inputs& in, const Program& program, double tool_radius_mm,
                              const metrology::ProbingPlan& plan, const std::vector<Eigen::Vector3d>& approaches,
                              const std::optional<recon::FootPointProjector>& part_surface,
                              const std::vector<nc::UnreachableProbePoint>& left_out, int loop,
                              const RunFolderWriter& folder);

// 7b. The cycle's analysis (deviations.csv|.ply, analysis.json) and its compensation decision.
struct Analysed {
  LoopSummary summary;
  std::vector<std::int64_t> flagged_ids;            // points beyond the search distance or past Q's edge, left out
  std::optional<metrology::FieldModel> systematic;  // when the cycle is to be compensated
};
Result<Analysed> AnalyseCycle(const PartSpec& part, const recon::BSplineSurface& q, const metrology::ProbingPlan& plan,
                              const metrology::ProbeLog& log, int loop, bool another_loop_allowed, std::uint64_t seed,
                              const RunFolderWriter& folder);

// 7c. Loop 0: what the simulation (the case's model) gets wrong on this part, and the extended model
// (loop-0/diagnosis/); effects are named only within `plausible` (app/case_knowledge.h PlausibleRangesFor).
// The points the analysis flagged (`excluded_ids`) are left out of the diagnosis too. With `proposals`
// (the part asks for a separating experiment) and alias groups on a part that was cut, the experiment
// that would separate each group on the next part (sim::ProposeExperiments, the path re-planned by
// nc-gen) is proposed, written to loop-0/diagnosis/proposals.json and returned for the case library.
// Pooling (issue 20): with earlier cases of the same machine/tool/material (RunOptions::pool_cases,
// FindPooledCases) the diagnosis is sim::DiagnosePooledResiduals over this part (label: its name, first,
// so the learned model keeps its set-up) and theirs (labels: their uids), every part fitted from no
// effects (a learned model of fewer parts would leave the same misfit of its alias-group carriers on
// every part; a pre-compensated cut's offsets are in its own simulated cut: simulation/part_record.h);
// diagnosis.json's "pooled" says which cases were pooled and why others were not. Proposals are then
// made on the part's own diagnosis (the experiment for the next part of this machine). A part that was
// cut gets its own record in `pooling->record`, for the library.
struct FirstCyclePooling {
  const PooledCases* earlier = nullptr;   // null or empty: the part alone
  std::optional<sim::PartRecord> record;  // out
};
Result<sim::Diagnosis> DiagnoseFirstCycle(const PartSpec& part, const recon::BSplineSurface& q,
                                          const Machined& machined, const std::vector<std::int64_t>& excluded_ids,
                                          double tool_radius_mm, const metrology::ProbingPlan& plan,
                                          const planning::PlanChoice& choice, const std::string& case_uid,
                                          const sim::PlausibleRanges& plausible, const RunFolderWriter& folder,
                                          std::vector<sim::PlannedProposal>* proposals = nullptr,
                                          FirstCyclePooling* pooling = nullptr);

// 7d. The mirror-compensated program of the next cycle from the sum of the fields so far
// (loop-K/program_compensated.*, compensation_side.bin, compensation.json).
Result<Program> CompensateCycle(const PartSpec& part, const Programs& programs, const CompensatedField& field, int loop,
                                const RunFolderWriter& folder);

// 8. The case the library will hold (retain.json); committed by RunPart after everything else is written.
// With it, the part's record for later pooled diagnoses (FirstCyclePooling::record), when there is one.
struct Retained {
  kb::CaseRecord record;
  std::optional<kb::PartRecordRow> part_record;
};
Result<std::optional<Retained>> PrepareRetain(const PartSpec& part, const RunOptions& options,
                                              const Retrieved& retrieved, const nc::ToolpathOptions& plan,
                                              const std::optional<sim::Diagnosis>& diagnosis, RunSummary* summary,
                                              const RunFolderWriter& folder,
                                              const std::vector<sim::PlannedProposal>& proposals = {},
                                              const sim::PartRecord* part_record = nullptr);

// One transaction for the case, then the GHSOM insertion (a failure there leaves it stale, not wrong).
Status CommitRetained(const std::string& kb_path, const Retained& retained);

// A cycle as summary.json gives it.
nlohmann::json LoopJson(const LoopSummary& loop);

}  // namespace formloop::app::stages
