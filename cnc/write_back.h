#pragma once
// Confirmed offset write-back (spec/tuning-and-link.md §5.3–5.5): the write plan `formloop tune`
// produces (format: /work/wt/WRITE_PLAN.md, "formloop.offset_write_plan" version 1) is read, checked
// again on the writer's side, and written through a MacroTransport.
//
//   refuse, nothing sent   unless the plan's status is SAFE, it is confirmed, and the operator passed
//                          --confirm; and unless every write passes its limits again here:
//                          |new − baseline| ≤ limit, |delta| ≤ step_limit (when given), new =
//                          previous + delta (within resolution/2), delta a whole number of resolution
//                          steps. The limit cannot be overridden from here.
//   NOTHING_TO_WRITE       a SAFE, confirmed plan without writes (every rounded change was zero)
//   OFFSET_CHANGED         just before writing, every offset is read; |o_now − previous| >
//                          resolution/2 on any of them aborts before anything is written.
//   write, read back       each new value is written, then every written offset is read back;
//   WRITE_VERIFY_FAILED    a difference > resolution/2 on any of them (or a write that failed or whose
//                          outcome is unknown) rolls every offset written so far back to its previous
//                          value, and the rollback is read back too (ROLLBACK_FAILED says which offsets
//                          need a person when even that fails).
// This file holds its own small reader of the plan (the tuning layer writes it; cnc/ sits below it).

#include <filesystem>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "cnc/transport.h"
#include "core/status.h"

namespace formloop::cnc {

struct PlannedWrite {
  std::string offset;              // the model's offset id ("T3_radius_wear")
  OffsetAddress address;           // from kind, tool, wcs, axis
  std::string controller_address;  // free text from the model, reported only
  double previous_mm = 0, delta_mm = 0, new_mm = 0;
  double resolution_mm = 0.001;
  double baseline_mm = 0;
  double limit_mm = 0.1;
  std::optional<double> step_limit_mm;
};

struct WritePlan {
  std::string session;
  std::string status;  // SAFE | RECHECK | INTERVENE | BLOCKED
  std::vector<std::string> blocked_reasons;
  bool confirmed = false;
  std::vector<std::string> not_reachable_acknowledged;
  std::vector<PlannedWrite> writes;
};

// Reads and checks the plan; errors name the file and the field ("writes[2].limit_mm"). Fields the
// format does not know are ignored (tuning may add some).
Result<WritePlan> ReadWritePlan(const std::filesystem::path& path);
Result<WritePlan> ParseWritePlan(const nlohmann::json& json, const std::string& source);

struct WriteBackItem {
  std::string offset;
  std::string address;
  double previous_mm = 0, new_mm = 0;
  std::optional<double> read_before_mm, read_back_mm, rolled_back_read_mm;
  bool written = false, rolled_back = false;
  std::string note;
};

struct WriteBackReport {
  // WRITTEN, NOTHING_TO_WRITE, REFUSED, OFFSET_CHANGED, WRITE_VERIFY_FAILED, WRITE_FAILED, ROLLBACK_FAILED
  std::string outcome;
  std::vector<std::string> reasons;
  std::vector<WriteBackItem> items;
  bool ok() const { return outcome == "WRITTEN" || outcome == "NOTHING_TO_WRITE"; }
  nlohmann::json ToJson() const;
};

// Runs the write-back. A refusal, OFFSET_CHANGED and a verified rollback are reports, not errors; a
// non-ok Status only when the controller cannot be reached before anything was written.
Result<WriteBackReport> WriteBack(MacroTransport& transport, const WritePlan& plan, bool operator_confirmed);

}  // namespace formloop::cnc
