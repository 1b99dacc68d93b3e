#pragma once
// What the pipeline takes from a retrieved case and what it gives back (spec/case-library.md §1, §6):
// the case's plan adapted to the new part, the learned model for this machine/tool/material, and the
// case the finished run retains (new, or an update of the same part's case).

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "app/part.h"
#include "kb/library.h"
#include "nc-gen/toolpath.h"
#include "retrieval/features.h"
#include "simulation/model.h"

namespace formloop::app {

// "ball r3" — the tool key of learned models.
std::string ToolKey(double radius_mm);

// The magazine tool nearest to `radius_mm` (the smaller one on a tie).
nc::BallEndTool NearestTool(const PartSpec& part, double radius_mm);

// The part's plan with the case's choices: tool (nearest in the magazine), scallop target, raster angle,
// feed and spindle speed. `notes` lists what came from the case and what stayed the part's.
nc::ToolpathOptions PlanFromCase(const kb::CaseRecord& record, const PartSpec& part, nlohmann::json* notes);

// The case's learned model for machine / tool / material (simulation.effect_models[].model), if stored.
std::optional<sim::Model> LearnedModelOf(const kb::CaseRecord& record, const std::string& machine,
                                         const std::string& tool_key, const std::string& material);

// The retrieval description of a part (retrieval::PartDescription) from its part file.
retrieval::PartDescription DescriptionOf(const PartSpec& part, const nc::ToolpathOptions& plan);

struct RetainInput {
  const PartSpec* part = nullptr;
  const retrieval::PartFeatures* features = nullptr;
  nc::ToolpathOptions plan;
  nlohmann::json outcome;           // route, similarity, loops, form errors, causes
  nlohmann::json compensation_loops = nlohmann::json::array();
  std::optional<sim::Model> learned;  // the extended model of the diagnosis (or the baseline kept)
  nlohmann::json learned_provenance = nlohmann::json::object();
  const kb::CaseRecord* existing = nullptr;  // the part's own case, when it is already in the library
  // {"part": resolved part, "machine": "virtual[:PROFILE]"} when the part was cut on the virtual machine
  // (stored as part.rerun, so app/route_calibration.h can run it again); null otherwise.
  nlohmann::json rerun;
};
// The case record the run stores: uid = part name; an existing record keeps its other learned models.
Result<kb::CaseRecord> MakeRetainedCase(const RetainInput& input);

}  // namespace formloop::app
