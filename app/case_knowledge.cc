#include "app/case_knowledge.h"

#include <algorithm>
#include <vector>

#include "core/file_hash.h"
#include "planning/case_plan.h"
#include "retrieval/starter.h"

namespace formloop::app {

Result<sim::PlausibleRanges> PlausibleRangesFor(kb::Library* library, const std::filesystem::path& data_dir) {
  if (library != nullptr) {
    FL_ASSIGN_OR_RETURN(const kb::RuleSet rules, library->GetRules());
    if (const kb::Rule* rule = rules.Find(sim::kPlausibleRangesRule)) {
      return sim::PlausibleRanges::FromJson(rule->choice, "case library rule set v" + std::to_string(rules.version));
    }
  }
  return sim::ReadPlausibleRanges((data_dir / "starter" / "rules.json").string());
}

nlohmann::json LearnedModelEntry(const sim::Model& model, const std::string& machine, const std::string& tool,
                                 const std::string& material, const nlohmann::json& provenance) {
  nlohmann::json rows = nlohmann::json::array();
  std::vector<std::string> aliased_parameters;
  for (const auto& g : model.alias_groups) {
    for (const auto& m : g.members) aliased_parameters.push_back(m);
  }
  for (const auto& e : model.effects) {
    if (!e.alias_group.empty()) continue;
    const auto& spec = e.effect->parameters();
    for (std::size_t k = 0; k < spec.size(); ++k) {
      const std::string parameter = std::string(e.effect->name()) + "(" + spec[k].name + ")";
      if (std::find(aliased_parameters.begin(), aliased_parameters.end(), parameter) != aliased_parameters.end()) {
        continue;
      }
      rows.push_back({{"name", std::string(e.effect->name()) + "." + spec[k].name},
                      {"estimate", e.values[k]},
                      {"standard_error", e.std_errors.empty() ? 0.0 : e.std_errors[k]}});
    }
  }
  nlohmann::json groups = nlohmann::json::array();
  for (const auto& g : model.alias_groups) groups.push_back({{"id", g.id}, {"members", g.members}});
  return {{"machine", machine},      {"tool", tool},           {"material", material},
          {"effects", rows},         {"alias_groups", groups}, {"model", model.ToJson()},
          {"provenance", provenance}};
}

Result<std::vector<sim::PlannedProposal>> StoredSeparatingExperiments(kb::Library& library, const std::string& machine,
                                                                      const std::string& tool,
                                                                      const std::string& material,
                                                                      const std::string& preferred,
                                                                      std::string* from_case) {
  FL_ASSIGN_OR_RETURN(std::vector<kb::CaseRecord> cases, library.ListCases());
  std::stable_sort(cases.begin(), cases.end(), [&](const kb::CaseRecord& a, const kb::CaseRecord& b) {
    if ((a.uid == preferred) != (b.uid == preferred)) return a.uid == preferred;
    // Else the newest: its diagnosis saw the most of the machine (a pooled one, all the parts before it).
    if (a.updated_at != b.updated_at) return a.updated_at > b.updated_at;
    return a.uid < b.uid;
  });
  for (const kb::CaseRecord& c : cases) {
    const nlohmann::json models = c.simulation.value("effect_models", nlohmann::json::array());
    if (!models.is_array()) continue;
    for (const nlohmann::json& m : models) {
      if (!m.is_object() || m.value("machine", "") != machine || m.value("tool", "") != tool ||
          m.value("material", "") != material || !m.contains("separating_experiments") ||
          !m["separating_experiments"].is_array() || m["separating_experiments"].empty()) {
        continue;
      }
      std::vector<sim::PlannedProposal> out;
      const nlohmann::json& list = m["separating_experiments"];
      for (std::size_t i = 0; i < list.size(); ++i) {
        FL_ASSIGN_OR_RETURN(sim::PlannedProposal p,
                            sim::PlannedProposal::FromJson(
                                list[i], "case library, case " + c.uid,
                                "simulation.effect_models[].separating_experiments[" + std::to_string(i) + "]."));
        out.push_back(std::move(p));
      }
      *from_case = c.uid;
      return out;
    }
  }
  return std::vector<sim::PlannedProposal>{};
}

Result<PooledCases> FindPooledCases(kb::Library& library, const std::string& machine, const std::string& tool,
                                    const std::string& material, const std::string& own_uid, int limit) {
  PooledCases out;
  nlohmann::json not_pooled = nlohmann::json::array();
  std::vector<std::string> with_record;
  FL_ASSIGN_OR_RETURN(const std::vector<kb::PartRecordRow> rows, library.PartRecords(machine, tool, material));
  for (const kb::PartRecordRow& row : rows) {
    if (row.case_uid == own_uid) continue;
    with_record.push_back(row.case_uid);
    if (static_cast<int>(out.uids.size()) >= limit) {
      not_pooled.push_back(
          {{"case", row.case_uid}, {"why", "beyond the limit of " + std::to_string(limit) + " cases (newest first)"}});
      continue;
    }
    auto record = sim::PartRecord::FromJson(row.record, "part record of case " + row.case_uid);
    if (!record.ok()) {
      // A record the library holds but this formloop cannot read is the library's fault, not the part's:
      // refuse rather than diagnose without it and leave the user to wonder why.
      return Status::BadInput(
          Where{.file = library.db()->name(), .field = "case_part_records (case " + row.case_uid + ")"},
          "the part record of case " + row.case_uid + " (" + machine + " / " + tool + " / " + material +
              ") cannot be pooled: " + std::string(record.status().message()),
          "run that part again (its run replaces the record), remove the case (formloop kb remove), or run with "
          "--pool-cases 0");
    }
    out.uids.push_back(row.case_uid);
    out.records.push_back(std::move(record).value());
    out.inputs.push_back({{"case", row.case_uid},
                          {"updated_at", row.case_updated_at},
                          {"points", out.records.back().points()},
                          {"record_sha256", Sha256Hex(row.record.dump())}});
  }
  // Cases with a learned model of this key but no record.
  FL_ASSIGN_OR_RETURN(const std::vector<kb::CaseRecord> cases, library.ListCases());
  for (const kb::CaseRecord& c : cases) {
    if (c.uid == own_uid || std::find(with_record.begin(), with_record.end(), c.uid) != with_record.end()) continue;
    const nlohmann::json models = c.simulation.value("effect_models", nlohmann::json::array());
    bool same_key = false;
    for (const nlohmann::json& m : models.is_array() ? models : nlohmann::json::array()) {
      same_key = same_key || (m.is_object() && m.value("machine", "") == machine && m.value("tool", "") == tool &&
                              m.value("material", "") == material);
    }
    if (same_key) {
      not_pooled.push_back({{"case", c.uid},
                            {"why",
                             "no part record (stored before case library v3, or by a run that did not cut the part "
                             "with formloop's program): run the part again to pool it"}});
    }
  }
  out.report = {{"limit", limit}, {"cases", out.uids}, {"not_pooled", not_pooled}};
  return out;
}

Result<std::vector<std::string>> PartRecordProblems(kb::Library& library) {
  FL_ASSIGN_OR_RETURN(const std::vector<kb::PartRecordRow> rows, library.AllPartRecords());
  std::vector<std::string> problems;
  for (const kb::PartRecordRow& row : rows) {
    const auto record =
        sim::PartRecord::FromJson(row.record, "part record of case " + row.case_uid + " (" + row.machine + " / " +
                                                  row.tool + " / " + row.material + ")");
    if (!record.ok()) problems.push_back(std::string(record.status().message()));
  }
  return problems;
}

retrieval::PartDescription DescriptionOf(const PartSpec& part, const nc::ToolpathOptions& plan) {
  retrieval::PartDescription d;
  d.family_tag = part.name;
  d.shape_family = part.ShapeConcept();
  d.material = part.material;
  d.form_tolerance_mm = part.tolerance_mm;
  d.ra_um = part.finish_ra_um;
  d.batch_size = part.batch_size;
  d.machine_class = part.machine_class;
  d.tool_radius_mm = plan.tool.radius_mm;
  d.strategy = plan.zigzag ? "raster zig-zag" : "raster one-way";
  d.raster_angle_deg = plan.raster_angle_deg;
  return d;
}

std::optional<kb::PartRecordRow> MakePartRecordRow(const RetainInput& in) {
  if (in.part_record == nullptr) return std::nullopt;
  kb::PartRecordRow row;
  row.case_uid = in.part->name;
  row.machine = in.part->machine_name;
  row.tool = planning::ToolKey(in.plan.tool.radius_mm);
  row.material = in.part->material;
  row.record = in.part_record->ToJson();
  return row;
}

Result<kb::CaseRecord> MakeRetainedCase(const RetainInput& in) {
  const PartSpec& part = *in.part;
  kb::CaseRecord record;
  if (in.existing != nullptr) record = *in.existing;
  record.uid = part.name;
  record.name = part.name + " (" + part.SurfaceName() + ", " + part.material + ")";
  record.family = part.ShapeConcept();
  // The part as it was asked for (its own tool), like the descriptor and concepts it is found by; the
  // tool the plan used is in manufacturing.tools.
  record.part = retrieval::PartDescriptionToJson(DescriptionOf(part, part.toolpath));
  record.part["surface"] = part.ToJson()["surface"];
  record.part["outcome"] = in.outcome;
  if (!in.rerun.is_null()) record.part["rerun"] = in.rerun;
  const auto& d = in.features->descriptors;
  record.descriptor = std::vector<double>(d.data(), d.data() + d.size());
  record.concepts = in.features->Concepts();
  const std::string tool = planning::ToolKey(in.plan.tool.radius_mm);
  if (in.learned) {
    nlohmann::json entry =
        LearnedModelEntry(*in.learned, part.machine_name, tool, part.material, in.learned_provenance);
    if (!in.separating_experiments.empty()) entry["separating_experiments"] = in.separating_experiments;
    nlohmann::json models = record.simulation.value("effect_models", nlohmann::json::array());
    if (!models.is_array()) models = nlohmann::json::array();
    bool replaced = false;
    for (auto& m : models) {
      if (m.value("machine", "") == part.machine_name && m.value("tool", "") == tool &&
          m.value("material", "") == part.material) {
        m = entry;
        replaced = true;
      }
    }
    if (!replaced) models.push_back(entry);
    record.simulation["effect_models"] = models;
  }
  const auto& p = in.plan;
  record.manufacturing = {
      {"machine", part.machine_name},
      {"tools", nlohmann::json::array({{{"type", "ball-end"},
                                        {"number", p.tool.number},
                                        {"radius_mm", p.tool.radius_mm},
                                        {"flutes", part.flutes}}})},
      {"strategy",
       {{"pattern", p.zigzag ? "raster zig-zag" : "raster one-way"},
        {"raster_angle_deg", p.raster_angle_deg},
        {"scallop_um", p.scallop_um}}},
      {"feeds", {{"feed_mm_per_min", p.feed_mm_per_min}, {"spindle_rpm", p.spindle_rpm}}},
      {"compensation", {{"method", "mirror-systematic"}, {"loops", in.compensation_loops}}},
      {"probing", {{"grid", {part.probe_nu, part.probe_nv}}, {"inset_fraction", part.probe_inset_fraction}}},
      {"reconstruction", {{"algorithm", "B-spline"}, {"fit", part.ToJson()["fit"]}}}};
  // The library validates exactly as `kb add` does.
  return kb::CaseRecord::FromJson(record.ToJson(), Where{.file = "retained case " + record.uid});
}

}  // namespace formloop::app
