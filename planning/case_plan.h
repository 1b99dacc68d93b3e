#pragma once
// The plan of a new part from a retrieved case (spec/case-library.md §1, §6; spec/simulation.md §4):
// the case's plan adapted to the part, the case's learned model for this machine / tool / material, and
// the choice by route:
//
//   direct   (A > 0.95)         the case's plan; pre-compensation by the learned model (when `learn`)
//   simulate (0.80 ≤ A ≤ 0.95)  the case's plan checked on the new part in the virtual machine and, when
//                               it has a predicted defect, corrected by the plan GA (planning/sim_correction.h)
//   default  (A < 0.80, or no library)  the part file's own plan, flagged for an engineer
//
// Nothing here reads or writes files: the caller writes the report (plan.json) and, on the simulate
// route, the correction (sim_correction.json).

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "kb/library.h"
#include "nc-gen/post.h"
#include "nc-gen/toolpath.h"
#include "planning/sim_correction.h"
#include "reconstruction/bspline_surface.h"
#include "simulation/model.h"

namespace formloop::planning {

// "ball r3": the tool key of learned models.
std::string ToolKey(double radius_mm);

// What a case's plan is adapted to: the part's own plan (everything the case does not say: chord
// tolerance, point spacing, leads, clearance, plunge feed, zig-zag), the magazine the planner may choose
// from and the machine's limits.
struct PartPlanBasis {
  nc::ToolpathOptions plan;
  std::vector<nc::BallEndTool> magazine;
  nc::MachineLimits limits;
};

// The magazine tool nearest to `radius_mm` (the smaller one on a tie); `own` (the part's tool) when
// nothing in the magazine is nearer.
nc::BallEndTool NearestTool(const nc::BallEndTool& own, const std::vector<nc::BallEndTool>& magazine, double radius_mm);

// The part's plan with the case's choices: tool (nearest in the magazine), scallop target, raster angle,
// feed and spindle speed (capped by the limits). `notes` lists what came from the case and what stayed
// the part's. BadInput naming the case when a field it gives has the wrong type.
Result<nc::ToolpathOptions> PlanFromCase(const kb::CaseRecord& record, const PartPlanBasis& part,
                                         nlohmann::json* notes);

// The case's learned model for machine / tool / material (simulation.effect_models[].model), if stored.
std::optional<sim::Model> LearnedModelOf(const kb::CaseRecord& record, const std::string& machine,
                                         const std::string& tool_key, const std::string& material);

// Everything the choice of plan depends on.
struct PlanRequest {
  const recon::BSplineSurface* surface = nullptr;  // Q of the new part
  PartPlanBasis part;
  int flutes = 2;
  std::string material;
  std::string machine;                   // the machine the part is cut on (key of learned models)
  double tolerance_mm = 0.010;           // α
  double coverage_factor = 2;            // k of the form error: e_rand of the correction = k σ(d_u) of the case
  double probe_inset_fraction = 0.05;    // of the 10 × 10 grid the correction predicts the form error on
  std::string route = "default";         // direct | simulate | default (retrieval::RetrievalResult::route)
  const kb::CaseRecord* best = nullptr;  // the retrieved case (none: the default plan)
  double similarity = -1;                // A of the best case
  bool learn = true;                     // pre-compensate with the case's learned model
  std::uint64_t seed = 1;                // of the simulation-correction GA
};

struct PlanChoice {
  nc::ToolpathOptions plan;
  std::optional<sim::Model> learned;  // the case's model for this machine/tool/material
  double precompensation_scale = 0;   // 0: no pre-compensation
  bool flag_engineer = false;         // the default plan, or a correction that could not remove every defect
  std::string source;                 // "case X", "case X, simulation-corrected", "default plan ..."
  nlohmann::json report = nlohmann::json::object();  // plan.json before the tool path is added
  std::optional<SimCorrectionResult> correction;     // route simulate
  // `plan`'s tool path on the request's surface when the simulation correction planned it already (its
  // SimCorrectionResult::path, moved here); null otherwise. The run cuts it instead of planning it again.
  std::shared_ptr<nc::Toolpath> path;
};

// The plan by route (see the top of this file). The case's learned model is the baseline of the
// diagnosis and, when `learn`, the pre-compensation.
Result<PlanChoice> ChoosePlan(const PlanRequest& request);

}  // namespace formloop::planning
