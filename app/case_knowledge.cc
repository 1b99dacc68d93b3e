#include "app/case_knowledge.h"

#include <algorithm>
#include <cmath>
#include <map>

#include <fmt/format.h>

#include "retrieval/starter.h"

namespace formloop::app {
namespace {

double NumberAt(const nlohmann::json& j, std::initializer_list<const char*> path, double fallback) {
  const nlohmann::json* node = &j;
  for (const char* key : path) {
    if (!node->is_object() || !node->contains(key)) return fallback;
    node = &(*node)[key];
  }
  return node->is_number() ? node->get<double>() : fallback;
}

}  // namespace

std::string ToolKey(double radius_mm) { return fmt::format("ball r{:g}", radius_mm); }

nc::BallEndTool NearestTool(const PartSpec& part, double radius_mm) {
  nc::BallEndTool best = part.toolpath.tool;
  double best_gap = std::abs(best.radius_mm - radius_mm);
  for (const auto& tool : part.tools) {
    const double gap = std::abs(tool.radius_mm - radius_mm);
    if (gap < best_gap - 1e-12 || (std::abs(gap - best_gap) <= 1e-12 && tool.radius_mm < best.radius_mm)) {
      best = tool;
      best_gap = gap;
    }
  }
  return best;
}

nc::ToolpathOptions PlanFromCase(const kb::CaseRecord& record, const PartSpec& part, nlohmann::json* notes) {
  nc::ToolpathOptions plan = part.toolpath;
  const nlohmann::json& m = record.manufacturing;
  nlohmann::json from_case = nlohmann::json::object();
  if (m.contains("tools") && m["tools"].is_array() && !m["tools"].empty()) {
    const double r = NumberAt(m["tools"][0], {"radius_mm"}, plan.tool.radius_mm);
    plan.tool = NearestTool(part, r);
    from_case["tool"] = {{"case_radius_mm", r}, {"magazine_tool", plan.tool.number},
                         {"radius_mm", plan.tool.radius_mm}};
  }
  const double scallop = NumberAt(m, {"strategy", "scallop_um"}, -1);
  if (scallop > 0) {
    plan.scallop_um = scallop;
    from_case["scallop_um"] = scallop;
  }
  const double angle = NumberAt(m, {"strategy", "raster_angle_deg"}, std::nan(""));
  if (std::isfinite(angle)) {
    plan.raster_angle_deg = angle;
    from_case["raster_angle_deg"] = angle;
  }
  const double feed = NumberAt(m, {"feeds", "feed_mm_per_min"}, -1);
  if (feed > 0) {
    plan.feed_mm_per_min = std::min(feed, part.limits.max_feed_mm_per_min);
    from_case["feed_mm_per_min"] = plan.feed_mm_per_min;
  }
  const double rpm = NumberAt(m, {"feeds", "spindle_rpm"}, -1);
  if (rpm > 0) {
    plan.spindle_rpm = std::min(rpm, part.limits.max_spindle_rpm);
    from_case["spindle_rpm"] = plan.spindle_rpm;
  }
  if (notes != nullptr) {
    *notes = {{"case", record.uid},
              {"from_case", from_case},
              {"kept_from_part", "chord tolerance, point spacing, leads, clearance, plunge feed, zig-zag"}};
  }
  return plan;
}

std::optional<sim::Model> LearnedModelOf(const kb::CaseRecord& record, const std::string& machine,
                                         const std::string& tool_key, const std::string& material) {
  const nlohmann::json models = record.simulation.value("effect_models", nlohmann::json::array());
  if (!models.is_array()) return std::nullopt;
  for (const auto& entry : models) {
    if (!entry.is_object() || entry.value("machine", "") != machine || entry.value("tool", "") != tool_key ||
        entry.value("material", "") != material || !entry.contains("model")) {
      continue;
    }
    auto model = sim::Model::FromJson(entry["model"], "case " + record.uid + " learned model");
    if (model.ok()) return std::move(model).value();
  }
  return std::nullopt;
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
  const std::string tool = ToolKey(in.plan.tool.radius_mm);
  if (in.learned) {
    nlohmann::json rows = nlohmann::json::array();
    for (const auto& e : in.learned->effects) {
      const auto& spec = e.effect->parameters();
      for (std::size_t k = 0; k < spec.size(); ++k) {
        rows.push_back({{"name", std::string(e.effect->name()) + "." + spec[k].name},
                        {"estimate", e.values[k]},
                        {"standard_error", e.std_errors.empty() ? 0.0 : e.std_errors[k]}});
      }
    }
    nlohmann::json entry = {{"machine", part.machine_name}, {"tool", tool},       {"material", part.material},
                            {"effects", rows},              {"model", in.learned->ToJson()},
                            {"provenance", in.learned_provenance}};
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
      {"tools", nlohmann::json::array({{{"type", "ball-end"}, {"number", p.tool.number}, {"radius_mm", p.tool.radius_mm},
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
