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
#include "simulation/part_record.h"
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
// retrieved one, whose learned model the run's diagnosis starts from) when it has them, else the most
// recently updated such case (ties by uid). Empty: none; *from_case names the case.
Result<std::vector<sim::PlannedProposal>> StoredSeparatingExperiments(kb::Library& library, const std::string& machine,
                                                                      const std::string& tool,
                                                                      const std::string& material,
                                                                      const std::string& preferred,
                                                                      std::string* from_case);

// The earlier cases a part's first diagnosis pools with it (RunOptions::pool_cases; simulation/part_record.h):
// the part records the library holds for this machine/tool/material (schema v3), the newest case first,
// the part's own case left out, at most `limit`. `report` says which cases were pooled and, for every
// other case with a learned model of this key, why not: no part record (stored before case library v3,
// or by a run that did not cut the part) or beyond the limit. A record within the limit that this
// formloop cannot read is an error naming the library, the case and the field (never skipped quietly).
struct PooledCases {
  std::vector<std::string> uids;
  std::vector<sim::PartRecord> records;
  nlohmann::json report;  // {"limit": N, "cases": [uid, ...], "not_pooled": [{"case": uid, "why": ...}, ...]}
  // Per pooled case, what the run folder's inputs/pooled_cases.json records of it (the run repeats only
  // with the same records): {"case", "updated_at", "points", "record_sha256"}.
  nlohmann::json inputs = nlohmann::json::array();
};
Result<PooledCases> FindPooledCases(kb::Library& library, const std::string& machine, const std::string& tool,
                                    const std::string& material, const std::string& own_uid, int limit);
// What a pooled run would trip on (`kb check`): every part record of the library read as FindPooledCases
// reads it; one line per record it cannot read, naming the case, its machine/tool/material and the field.
Result<std::vector<std::string>> PartRecordProblems(kb::Library& library);

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
  // The part's record for later pooled diagnoses (none: the part was not cut by formloop's program).
  const sim::PartRecord* part_record = nullptr;
  // {"part": resolved part, "machine": "virtual[:PROFILE]"} when the part was cut on the virtual machine
  // (stored as part.rerun, so app/route_calibration.h can run it again); null otherwise.
  nlohmann::json rerun;
};
// The case record the run stores: uid = part name; an existing record keeps its other learned models.
Result<kb::CaseRecord> MakeRetainedCase(const RetainInput& input);
// The part record row the run stores beside it (kb::Library::SetPartRecord), keyed like the learned model.
std::optional<kb::PartRecordRow> MakePartRecordRow(const RetainInput& input);

}  // namespace formloop::app
