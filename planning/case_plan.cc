#include "planning/case_plan.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/json_io.h"
#include "core/log.h"
#include "metrology/probe.h"

namespace formloop::planning {
std::string ToolKey(double radius_mm) { return fmt::format("ball r{:g}", radius_mm); }

nc::BallEndTool NearestTool(const nc::BallEndTool& own, const std::vector<nc::BallEndTool>& magazine,
                            double radius_mm) {
  nc::BallEndTool best = own;
  double best_gap = std::abs(best.radius_mm - radius_mm);
  for (const auto& tool : magazine) {
    const double gap = std::abs(tool.radius_mm - radius_mm);
    if (gap < best_gap - 1e-12 || (std::abs(gap - best_gap) <= 1e-12 && tool.radius_mm < best.radius_mm)) {
      best = tool;
      best_gap = gap;
    }
  }
  return best;
}

Result<nc::ToolpathOptions> PlanFromCase(const kb::CaseRecord& record, const PartPlanBasis& part,
                                         nlohmann::json* notes) {
  nc::ToolpathOptions plan = part.plan;
  const JsonFields m(record.manufacturing, "case " + record.uid, "manufacturing.");
  nlohmann::json from_case = nlohmann::json::object();
  std::vector<JsonFields> tools;
  if (m.Has("tools")) FL_RETURN_IF_ERROR(m.ObjectArray("tools", &tools));
  if (!tools.empty()) {
    double r = plan.tool.radius_mm;
    FL_RETURN_IF_ERROR(tools.front().OptionalNumber("radius_mm", &r));
    plan.tool = NearestTool(part.plan.tool, part.magazine, r);
    from_case["tool"] = {
        {"case_radius_mm", r}, {"magazine_tool", plan.tool.number}, {"radius_mm", plan.tool.radius_mm}};
  }
  std::optional<JsonFields> strategy, feeds;
  FL_RETURN_IF_ERROR(m.Object("strategy", &strategy));
  FL_RETURN_IF_ERROR(m.Object("feeds", &feeds));
  double scallop = -1, angle = std::nan(""), feed = -1, rpm = -1;
  if (strategy) {
    FL_RETURN_IF_ERROR(strategy->OptionalNumber("scallop_um", &scallop));
    FL_RETURN_IF_ERROR(strategy->OptionalNumber("raster_angle_deg", &angle));
  }
  if (feeds) {
    FL_RETURN_IF_ERROR(feeds->OptionalNumber("feed_mm_per_min", &feed));
    FL_RETURN_IF_ERROR(feeds->OptionalNumber("spindle_rpm", &rpm));
  }
  if (scallop > 0) {
    plan.scallop_um = scallop;
    from_case["scallop_um"] = scallop;
  }
  if (std::isfinite(angle)) {
    plan.raster_angle_deg = angle;
    from_case["raster_angle_deg"] = angle;
  }
  if (feed > 0) {
    plan.feed_mm_per_min = std::min(feed, part.limits.max_feed_mm_per_min);
    from_case["feed_mm_per_min"] = plan.feed_mm_per_min;
  }
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

Result<PlanChoice> ChoosePlan(const PlanRequest& request) {
  const PlanRequest& r = request;
  PlanChoice c;
  c.plan = r.part.plan;
  if (r.route == "default" || r.best == nullptr) {
    c.source = "default plan (the part file's), flagged for an engineer";
    c.flag_engineer = true;
    c.report = {{"source", c.source}, {"route", r.route}};
    return c;
  }
  nlohmann::json notes;
  FL_ASSIGN_OR_RETURN(c.plan, PlanFromCase(*r.best, r.part, &notes));
  c.learned = LearnedModelOf(*r.best, r.machine, ToolKey(c.plan.tool.radius_mm), r.material);
  c.source = "case " + r.best->uid;
  c.precompensation_scale = c.learned && r.learn ? 1.0 : 0.0;
  c.report = {{"source", c.source},
              {"route", r.route},
              {"case_plan", notes},
              {"learned_model", c.learned ? c.learned->ToJson() : nlohmann::json(nullptr)}};
  if (r.route != "simulate") return c;

  // 0.80 ≤ A ≤ 0.95: simulate the case's plan on this part with the case's model and correct it.
  if (r.surface == nullptr) return Status::Internal("ChoosePlan: no surface for the simulation-correction step");
  SimCorrectionInput in;
  in.surface = r.surface;
  in.case_plan = c.plan;
  in.tools = r.part.magazine;
  in.flutes = r.flutes;
  if (c.learned) in.model = *c.learned;
  in.similarity = r.similarity;
  // e_rand: the random error the case's own run left (coverage factor × σ(d_u) of its last cycle), when
  // the case was retained by formloop run; else the GA's default.
  const nlohmann::json outcome = r.best->part.value("outcome", nlohmann::json::object());
  if (outcome.is_object() && outcome.contains("random_sigma_um") && outcome["random_sigma_um"].is_number()) {
    in.random_um = r.coverage_factor * outcome["random_sigma_um"].get<double>();
  }
  in.tolerance_mm = r.tolerance_mm;
  in.limits = r.part.limits;
  FL_ASSIGN_OR_RETURN(in.probing_plan, metrology::PlanProbingGrid(*r.surface, 10, 10, r.probe_inset_fraction));
  in.seed = r.seed;
  FL_ASSIGN_OR_RETURN(SimCorrectionResult corrected, RunSimulationCorrection(in));
  if (corrected.defects_before.empty()) {
    // Nothing to correct: the case's plan is kept (the GA's optimum would only trade time for error
    // the case's plan already meets), pre-compensated as on the direct route.
    log::Info("[plan] simulation-correction: the case's plan has no predicted defect on this part; kept");
    c.source += ", simulation-checked (no predicted defect)";
    c.path = std::move(corrected.path);  // the case's plan, as checked
  } else if (corrected.corrected) {
    // The GA may switch tools: the learned model belongs to the tool it was learned with.
    if (corrected.plan.tool.radius_mm != c.plan.tool.radius_mm) {
      c.learned = LearnedModelOf(*r.best, r.machine, ToolKey(corrected.plan.tool.radius_mm), r.material);
    }
    c.plan = corrected.plan;
    c.path = std::move(corrected.path);  // the corrected plan, as checked
    c.precompensation_scale = c.learned && r.learn ? corrected.precompensation_scale : 0.0;
    c.source += ", simulation-corrected";
  } else {
    log::Warn("simulation-correction could not remove every predicted defect: {}", corrected.why_not);
    c.source += ", simulation-correction failed (" + corrected.why_not + "), flagged";
    c.flag_engineer = true;
  }
  c.report["source"] = c.source;
  // What the run uses, beside the GA's candidate: the same tool and radius as plan.json and the programs.
  const char* decision = corrected.defects_before.empty()
                             ? "the case's plan, kept: it has no predicted defect on this part (nothing to correct)"
                         : corrected.corrected
                             ? "the GA's candidate: it removes every predicted defect"
                             : "the case's plan, kept and flagged for an engineer: the correction could not remove "
                               "every predicted defect (the GA's candidate is not used)";
  corrected.applied = {{"decision", decision},
                       {"tool_number", c.plan.tool.number},
                       {"tool_radius_mm", c.plan.tool.radius_mm},
                       {"scallop_um", c.plan.scallop_um},
                       {"feed_mm_per_min", c.plan.feed_mm_per_min},
                       {"spindle_rpm", c.plan.spindle_rpm},
                       {"precompensation_scale", c.precompensation_scale}};
  c.report["sim_correction"] = {{"defects_before", corrected.defects_before.size()},
                                {"defects_after", corrected.defects_after.size()},
                                {"corrected", corrected.corrected},
                                {"why_not", corrected.why_not}};
  c.correction = std::move(corrected);
  return c;
}

}  // namespace formloop::planning
