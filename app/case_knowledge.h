#pragma once
// What the pipeline gives the case library (spec/case-library.md §1, §6): the part's retrieval
// description and the case the finished run retains (new, or an update of the same part's case). What it
// takes from a retrieved case (the plan, the learned model) is planning/case_plan.h.

#include <filesystem>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "app/part.h"
#include "kb/library.h"
#include "nc-gen/toolpath.h"
#include "retrieval/features.h"
#include "simulation/model.h"
#include "simulation/plausible_ranges.h"
#include "simulation/proposal_plan.h"

namespace formloop::app {

// The plausible parameter ranges a diagnosis names effects within (sim::PlausibleRanges, rule
// "diagnose.plausible_ranges"): the library's active rule when it has one, else data_dir/starter/rules.json.
Result<sim::PlausibleRanges> PlausibleRangesFor(kb::Library* library, const std::filesystem::path& data_dir);

// The learned-model entry of a case (simulation.effect_models[]): the model, and as {name, estimate,
// standard_error} rows only the parameters of its named effects — an alias group's members carry a
// combined prediction, not estimates, and are listed under "alias_groups" instead.
nlohmann::json LearnedModelEntry(const sim::Model& model, const std::string& machine, const std::string& tool,
                                 const std::string& material, const nlohmann::json& provenance);

// The separating experiments (simulation/proposal_plan.h) the case library holds for a machine/tool/material:
// the "separating_experiments" of a case's learned-model entry with that key — the case `preferred` (the
// retrieved one) when it has them, else the first such case by uid. Empty: none; *from_case names the case.
Result<std::vector<sim::PlannedProposal>> StoredSeparatingExperiments(kb::Library& library, const std::string& machine,
                                                                      const std::string& tool,
                                                                      const std::string& material,
                                                                      const std::string& preferred,
                                                                      std::string* from_case);

// The retrieval description of a part (retrieval::PartDescription) from its part file.
retrieval::PartDescription DescriptionOf(const PartSpec& part, const nc::ToolpathOptions& plan);

struct RetainInput {
  const PartSpec* part = nullptr;
  const retrieval::PartFeatures* features = nullptr;
  nc::ToolpathOptions plan;
  nlohmann::json outcome;  // route, similarity, loops, form errors, causes
  nlohmann::json compensation_loops = nlohmann::json::array();
  std::optional<sim::Model> learned;  // the extended model of the diagnosis (or the baseline kept)
  nlohmann::json learned_provenance = nlohmann::json::object();
  // This part's proposals for the next part (PlannedProposal::ToJson each), kept with the learned model.
  nlohmann::json separating_experiments = nlohmann::json::array();
  const kb::CaseRecord* existing = nullptr;  // the part's own case, when it is already in the library
  // {"part": resolved part, "machine": "virtual[:PROFILE]"} when the part was cut on the virtual machine
  // (stored as part.rerun, so app/route_calibration.h can run it again); null otherwise.
  nlohmann::json rerun;
};
// The case record the run stores: uid = part name; an existing record keeps its other learned models.
Result<kb::CaseRecord> MakeRetainedCase(const RetainInput& input);

}  // namespace formloop::app
