#include "cnc/write_back.h"

#include <cmath>

#include "core/json_io.h"
#include "core/log.h"
#include "core/point_io.h"

namespace formloop::cnc {

namespace {

constexpr double kEps = 1e-9;  // mm: floating-point slack in the limit comparisons

Status ParseWrite(const Json& j, const std::string& source, const std::string& prefix, PlannedWrite* w) {
  if (!j.is_object())
    return Status::BadInput(Where{.file = source, .field = prefix}, "each write must be a JSON object");
  JsonFields f(j, source, prefix + ".");
  std::string kind;
  FL_RETURN_IF_ERROR(f.String("offset", &w->offset));
  FL_RETURN_IF_ERROR(f.String("kind", &kind));
  FL_RETURN_IF_ERROR(f.OptionalString("address", &w->controller_address));
  if (kind == "TOOL_RADIUS_WEAR" || kind == "TOOL_LENGTH_WEAR") {
    long long tool = 0;
    FL_RETURN_IF_ERROR(f.Integer("tool", &tool, 1, 9999));
    w->address.kind = kind == "TOOL_RADIUS_WEAR" ? OffsetKind::kToolRadiusWear : OffsetKind::kToolLengthWear;
    w->address.tool = static_cast<int>(tool);
  } else if (kind == "WORK_OFFSET") {
    std::string wcs, axis;
    FL_RETURN_IF_ERROR(f.String("wcs", &wcs));
    FL_RETURN_IF_ERROR(f.String("axis", &axis));
    const auto parsed = ParseOffsetAddress(wcs + "." + axis);
    if (!parsed.ok()) {
      return Status::BadInput(Where{.file = source, .field = prefix + ".wcs"},
                              "work offset '" + wcs + "' axis '" + axis + "' is not known",
                              "use wcs G54..G59 and axis X, Y or Z");
    }
    w->address = *parsed;
  } else {
    return Status::BadInput(Where{.file = source, .field = prefix + ".kind"}, "unknown kind '" + kind + "'",
                            "use TOOL_RADIUS_WEAR, TOOL_LENGTH_WEAR or WORK_OFFSET");
  }
  FL_RETURN_IF_ERROR(f.Number("previous_mm", &w->previous_mm));
  FL_RETURN_IF_ERROR(f.Number("delta_mm", &w->delta_mm));
  FL_RETURN_IF_ERROR(f.Number("new_mm", &w->new_mm));
  FL_RETURN_IF_ERROR(f.Number("resolution_mm", &w->resolution_mm, {.min = 0, .exclusive_min = true}));
  FL_RETURN_IF_ERROR(f.Number("baseline_mm", &w->baseline_mm));
  FL_RETURN_IF_ERROR(f.Number("limit_mm", &w->limit_mm, {.min = 0}));
  if (f.Has("step_limit_mm") && !j.at("step_limit_mm").is_null()) {
    double step = 0;
    FL_RETURN_IF_ERROR(f.Number("step_limit_mm", &step, {.min = 0}));
    w->step_limit_mm = step;
  }
  return Status::Ok();
}

// The writer's own check of one write (nothing beyond its limits is ever sent).
std::vector<std::string> LimitProblems(const PlannedWrite& w) {
  std::vector<std::string> out;
  const std::string name = w.offset + " (" + w.address.ToString() + ")";
  if (std::fabs(w.new_mm - w.baseline_mm) > w.limit_mm + kEps) {
    out.push_back(name + ": new value " + FormatExact(w.new_mm) + " mm is " +
                  FormatExact(std::fabs(w.new_mm - w.baseline_mm)) + " mm from its baseline " +
                  FormatExact(w.baseline_mm) + " mm, beyond the limit " + FormatExact(w.limit_mm) + " mm");
  }
  if (w.step_limit_mm && std::fabs(w.delta_mm) > *w.step_limit_mm + kEps) {
    out.push_back(name + ": change " + FormatExact(w.delta_mm) + " mm is beyond the step limit " +
                  FormatExact(*w.step_limit_mm) + " mm");
  }
  if (std::fabs(w.previous_mm + w.delta_mm - w.new_mm) > w.resolution_mm / 2) {
    out.push_back(name + ": new " + FormatExact(w.new_mm) + " mm is not previous " + FormatExact(w.previous_mm) +
                  " + delta " + FormatExact(w.delta_mm) + " mm");
  }
  const double steps = w.delta_mm / w.resolution_mm;
  if (std::fabs(steps - std::round(steps)) > 1e-6) {
    out.push_back(name + ": change " + FormatExact(w.delta_mm) + " mm is not a whole number of resolution steps (" +
                  FormatExact(w.resolution_mm) + " mm)");
  }
  return out;
}

}  // namespace

Result<WritePlan> ParseWritePlan(const Json& json, const std::string& source) {
  if (!json.is_object()) return Status::BadInput(Where{.file = source}, "the write plan must be a JSON object");
  JsonFields f(json, source);
  std::string format;
  long long version = 0;
  FL_RETURN_IF_ERROR(f.String("format", &format));
  if (format != "formloop.offset_write_plan") {
    return Status::BadInput(
        Where{.file = source, .field = "format"}, "format is '" + format + "'",
        "give the offset write plan written by `formloop tune` (format formloop.offset_write_plan)");
  }
  FL_RETURN_IF_ERROR(f.Integer("version", &version, 1, 1));
  WritePlan plan;
  FL_RETURN_IF_ERROR(f.OptionalString("session", &plan.session));
  FL_RETURN_IF_ERROR(f.String("status", &plan.status));
  if (plan.status != "SAFE" && plan.status != "RECHECK" && plan.status != "INTERVENE" && plan.status != "BLOCKED") {
    return Status::BadInput(Where{.file = source, .field = "status"}, "unknown status '" + plan.status + "'",
                            "SAFE, RECHECK, INTERVENE or BLOCKED");
  }
  FL_RETURN_IF_ERROR(f.Bool("confirmed", &plan.confirmed));
  for (const char* key : {"blocked_reasons", "not_reachable_acknowledged"}) {
    if (!f.Has(key)) continue;
    const Json& a = json.at(key);
    if (!a.is_array()) return Status::BadInput(Where{.file = source, .field = key}, "must be an array of strings");
    for (std::size_t k = 0; k < a.size(); ++k) {
      if (!a[k].is_string()) {
        return Status::BadInput(Where{.file = source, .field = std::string(key) + "[" + std::to_string(k) + "]"},
                                "must be a string");
      }
      (std::string(key) == "blocked_reasons" ? plan.blocked_reasons : plan.not_reachable_acknowledged).push_back(a[k]);
    }
  }
  if (!f.Has("writes") || !json.at("writes").is_array()) {
    return Status::BadInput(Where{.file = source, .field = "writes"}, "missing or not an array");
  }
  const Json& writes = json.at("writes");
  for (std::size_t k = 0; k < writes.size(); ++k) {
    PlannedWrite w;
    FL_RETURN_IF_ERROR(ParseWrite(writes[k], source, "writes[" + std::to_string(k) + "]", &w));
    for (const auto& other : plan.writes) {
      if (other.address == w.address) {
        return Status::BadInput(Where{.file = source, .field = "writes[" + std::to_string(k) + "]"},
                                "offset " + w.address.ToString() + " appears twice", "one write per offset");
      }
    }
    plan.writes.push_back(w);
  }
  return plan;
}

Result<WritePlan> ReadWritePlan(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(const Json json, ReadJsonFile(path));
  return ParseWritePlan(json, path.string());
}

nlohmann::json WriteBackReport::ToJson() const {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& i : items) {
    nlohmann::json j = {{"offset", i.offset}, {"address", i.address}, {"previous_mm", i.previous_mm},
                        {"new_mm", i.new_mm}, {"written", i.written}, {"rolled_back", i.rolled_back}};
    if (i.read_before_mm) j["read_before_mm"] = *i.read_before_mm;
    if (i.read_back_mm) j["read_back_mm"] = *i.read_back_mm;
    if (i.rolled_back_read_mm) j["rolled_back_read_mm"] = *i.rolled_back_read_mm;
    if (!i.note.empty()) j["note"] = i.note;
    list.push_back(j);
  }
  return {{"outcome", outcome}, {"reasons", reasons}, {"offsets", list}};
}

namespace {

// Reads one offset, reconnecting once if the connection is gone.
Result<double> ReadOffsetRetry(MacroTransport& t, const OffsetAddress& a) {
  auto r = t.ReadOffset(a);
  if (!r.ok() && r.status().code() == StatusCode::kIoError && t.Connect().ok()) r = t.ReadOffset(a);
  return r;
}

}  // namespace

Result<WriteBackReport> WriteBack(MacroTransport& t, const WritePlan& plan, bool operator_confirmed) {
  WriteBackReport report;
  for (const auto& w : plan.writes) {
    WriteBackItem item;
    item.offset = w.offset;
    item.address = w.address.ToString();
    item.previous_mm = w.previous_mm;
    item.new_mm = w.new_mm;
    report.items.push_back(item);
  }
  // 1. Refusals: nothing is sent.
  if (!operator_confirmed) report.reasons.push_back("the operator did not confirm (--confirm)");
  if (plan.status != "SAFE") {
    std::string r = "the plan's status is " + plan.status + ", not SAFE";
    for (const auto& b : plan.blocked_reasons) r += "; " + b;
    report.reasons.push_back(r);
  }
  if (!plan.confirmed) report.reasons.push_back("the plan was not confirmed in `formloop tune` (confirmed: false)");
  for (const auto& w : plan.writes) {
    for (auto& p : LimitProblems(w)) report.reasons.push_back(std::move(p));
  }
  if (!report.reasons.empty()) {
    report.outcome = "REFUSED";
    return report;
  }
  if (plan.writes.empty()) {
    report.outcome = "NOTHING_TO_WRITE";  // every rounded change was zero
    return report;
  }
  // 2. The offsets must still hold what the plan was computed from.
  FL_RETURN_IF_ERROR(t.Connect());
  bool changed = false;
  for (std::size_t k = 0; k < plan.writes.size(); ++k) {
    const auto& w = plan.writes[k];
    FL_ASSIGN_OR_RETURN(const double now, ReadOffsetRetry(t, w.address));
    report.items[k].read_before_mm = now;
    if (std::fabs(now - w.previous_mm) > w.resolution_mm / 2) {
      changed = true;
      report.reasons.push_back("OFFSET_CHANGED: " + w.address.ToString() + " reads " + FormatExact(now) +
                               " mm, the plan expects " + FormatExact(w.previous_mm) +
                               " mm; re-run the measurement and `formloop tune`");
    }
  }
  if (changed) {
    report.outcome = "OFFSET_CHANGED";
    return report;
  }
  // 3. Write, then read every written offset back.
  std::vector<std::size_t> touched;  // written, or possibly written (outcome unknown)
  bool failed = false;
  for (std::size_t k = 0; k < plan.writes.size() && !failed; ++k) {
    const auto& w = plan.writes[k];
    touched.push_back(k);
    const Status s = t.WriteOffset(w.address, w.new_mm);
    if (!s.ok()) {
      failed = true;
      report.items[k].note = "write failed: " + s.message();
      report.reasons.push_back("WRITE_FAILED: " + w.address.ToString() + ": " + s.message());
      if (s.code() == StatusCode::kIoError) (void)t.Connect();
    } else {
      report.items[k].written = true;
    }
  }
  bool mismatch = false;
  for (const std::size_t k : touched) {
    const auto& w = plan.writes[k];
    const auto back = ReadOffsetRetry(t, w.address);
    if (!back.ok()) {
      mismatch = true;
      report.reasons.push_back("WRITE_VERIFY_FAILED: " + w.address.ToString() +
                               " cannot be read back: " + back.status().message());
      continue;
    }
    report.items[k].read_back_mm = *back;
    if (report.items[k].written && std::fabs(*back - w.new_mm) > w.resolution_mm / 2) {
      mismatch = true;
      report.reasons.push_back("WRITE_VERIFY_FAILED: " + w.address.ToString() + " was written " +
                               FormatExact(w.new_mm) + " mm but reads back " + FormatExact(*back) + " mm");
    }
  }
  if (!failed && !mismatch) {
    report.outcome = "WRITTEN";
    return report;
  }
  // 4. Roll back everything that was (or may have been) written, and check the rollback.
  bool rollback_ok = true;
  for (const std::size_t k : touched) {
    const auto& w = plan.writes[k];
    Status s = t.WriteOffset(w.address, w.previous_mm);
    if (!s.ok() && s.code() == StatusCode::kIoError && t.Connect().ok()) s = t.WriteOffset(w.address, w.previous_mm);
    const auto back = ReadOffsetRetry(t, w.address);
    if (back.ok()) report.items[k].rolled_back_read_mm = *back;
    // What counts is the value read back: an offset whose write was refused still holds its previous value.
    report.items[k].rolled_back = back.ok() && std::fabs(*back - w.previous_mm) <= w.resolution_mm / 2;
    if (!s.ok() && report.items[k].rolled_back)
      report.items[k].note += " (its rollback write was refused; it reads the previous value)";
    if (!report.items[k].rolled_back) {
      rollback_ok = false;
      report.reasons.push_back("ROLLBACK_FAILED: " + w.address.ToString() + " could not be set back to " +
                               FormatExact(w.previous_mm) + " mm (reads " +
                               (back.ok() ? FormatExact(*back) + " mm" : back.status().message()) +
                               "): check this offset on the controller by hand before the next part");
    }
  }
  report.outcome = !rollback_ok ? "ROLLBACK_FAILED" : (failed ? "WRITE_FAILED" : "WRITE_VERIFY_FAILED");
  log::Error("link write: {}; every written offset {}", report.outcome,
             rollback_ok ? "was rolled back and verified" : "that could be was rolled back");
  return report;
}

}  // namespace formloop::cnc
