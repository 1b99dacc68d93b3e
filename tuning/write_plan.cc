#include "tuning/write_plan.h"

#include <cmath>

#include "core/json_io.h"

namespace formloop::tuning {
namespace {

constexpr double kLimitSlackMm = 1e-12;

// Drops binary noise below a picometre so 0.085 + 0.010 prints as 0.095.
double Clean(double mm) { return std::round(mm * 1e9) / 1e9; }

std::string Mm(double v) { return Json(Clean(v)).dump() + " mm"; }

}  // namespace

const char* PlanStatusName(PlanStatus status) {
  switch (status) {
    case PlanStatus::kSafe:
      return "SAFE";
    case PlanStatus::kRecheck:
      return "RECHECK";
    case PlanStatus::kIntervene:
      return "INTERVENE";
    case PlanStatus::kBlocked:
      return "BLOCKED";
  }
  return "?";
}

std::vector<OffsetChange> CheckOffsetLimits(const MeasurementModel& model, const Eigen::VectorXd& delta_continuous_mm,
                                            const Eigen::VectorXd& delta_rounded_mm,
                                            const std::vector<std::string>& rules,
                                            const std::map<std::string, double>& previous_mm) {
  std::vector<OffsetChange> out;
  for (std::size_t j = 0; j < model.offsets.size(); ++j) {
    const ModelOffset& o = model.offsets[j];
    OffsetChange c;
    c.offset = &o;
    c.delta_continuous_mm = delta_continuous_mm(j);
    c.delta_mm = Clean(delta_rounded_mm(j));
    c.rule = j < rules.size() ? rules[j] : "";
    if (auto it = previous_mm.find(o.id); it != previous_mm.end()) {
      c.previous_mm = it->second;
      c.new_mm = Clean(it->second + c.delta_mm);
      c.checked = true;
      const double distance = std::abs(c.new_mm - o.baseline_mm);
      if (distance > o.limit_mm + kLimitSlackMm) {
        c.within_limits = false;
        c.violation = "offset " + o.id + ": new value " + Mm(c.new_mm) + " (previous " + Mm(it->second) + " + change " +
                      Mm(c.delta_mm) + ") is " + Mm(distance) + " from its baseline " + Mm(o.baseline_mm) +
                      ", beyond its limit " + Mm(o.limit_mm);
      } else if (o.step_limit_mm && std::abs(c.delta_mm) > *o.step_limit_mm + kLimitSlackMm) {
        c.within_limits = false;
        c.violation =
            "offset " + o.id + ": change " + Mm(c.delta_mm) + " is beyond its step limit " + Mm(*o.step_limit_mm);
      }
    }
    out.push_back(c);
  }
  return out;
}

bool AllWithinLimits(const std::vector<OffsetChange>& changes) {
  for (const auto& c : changes) {
    if (!c.within_limits) return false;
  }
  return true;
}

nlohmann::json WritePlan::ToJson() const {
  auto entry = [](const OffsetChange& c) {
    const ModelOffset& o = *c.offset;
    Json w = {{"offset", o.id}, {"kind", OffsetKindName(o.kind)}};
    if (o.kind == OffsetKind::kWorkOffset) {
      w["wcs"] = o.wcs;
      w["axis"] = o.axis;
    } else {
      w["tool"] = o.tool;
    }
    w["address"] = o.address;
    w["previous_mm"] = c.previous_mm ? Json(*c.previous_mm) : Json(nullptr);
    w["delta_mm"] = c.delta_mm;
    w["new_mm"] = c.previous_mm ? Json(c.new_mm) : Json(nullptr);
    w["resolution_mm"] = o.resolution_mm;
    w["baseline_mm"] = o.baseline_mm;
    w["limit_mm"] = o.limit_mm;
    w["step_limit_mm"] = o.step_limit_mm ? Json(*o.step_limit_mm) : Json(nullptr);
    return w;
  };
  Json writes = Json::array(), proposed = Json::array();
  for (const auto& c : changes) {
    if (c.delta_mm == 0) continue;
    Json p = entry(c);
    p["delta_continuous_mm"] = c.delta_continuous_mm;
    p["rule"] = c.rule;
    p["limits_checked"] = c.checked;
    p["within_limits"] = c.within_limits;
    if (!c.violation.empty()) p["violation"] = c.violation;
    proposed.push_back(p);
    if (status == PlanStatus::kSafe) {
      Json w = entry(c);
      w["rule"] = c.rule;  // an extra field (WRITE_PLAN.md: readers ignore it)
      writes.push_back(w);
    }
  }
  return {{"format", "formloop.offset_write_plan"},
          {"version", 1},
          {"session", session},
          {"status", PlanStatusName(status)},
          {"blocked_reasons", blocked_reasons},
          {"confirmed", confirmed},
          {"not_reachable_acknowledged", not_reachable_acknowledged},
          {"writes", writes},
          {"strategy", strategy},
          {"proposed", proposed}};
}

Result<std::map<std::string, double>> ReadCurrentOffsets(const std::filesystem::path& path,
                                                         const MeasurementModel& model) {
  FL_ASSIGN_OR_RETURN(const Json json, ReadJsonFile(path));
  const std::string source = path.string();
  JsonFields f(json, source);
  FL_RETURN_IF_ERROR(f.CheckKnown({"format", "version", "read_at", "machine", "values_mm"}));
  std::string format;
  FL_RETURN_IF_ERROR(f.String("format", &format));
  if (format != "formloop.current_offsets") {
    return Status::BadInput(Where{.file = source, .field = "format"},
                            "value '" + format + "' is not a current-offsets file",
                            "write \"format\": \"formloop.current_offsets\"");
  }
  long long version = 0;
  FL_RETURN_IF_ERROR(f.Integer("version", &version, 1, 1));
  if (!f.Has("values_mm") || !json["values_mm"].is_object()) {
    return Status::BadInput(Where{.file = source, .field = "values_mm"}, "missing or not an object",
                            "give {\"<offset id>\": <value in mm>, ...} as read from the controller");
  }
  std::map<std::string, double> out;
  const JsonFields values(json["values_mm"], source, "values_mm.");
  for (const auto& item : json["values_mm"].items()) {
    const std::string& key = item.key();
    if (model.OffsetIndex(key) < 0) {
      return Status::BadInput(Where{.file = source, .field = "values_mm." + key},
                              "offset '" + key + "' is not in the model", "remove it or fix the id");
    }
    FL_RETURN_IF_ERROR(values.Number(key, &out[key]));
  }
  for (const auto& o : model.offsets) {
    if (!out.count(o.id)) {
      return Status::BadInput(Where{.file = source, .field = "values_mm"}, "offset '" + o.id + "' has no current value",
                              "read every offset of the model from the controller at acquisition start");
    }
  }
  return out;
}

}  // namespace formloop::tuning
