#pragma once
// From the rounded offset changes to the write plan: the safety ladder of spec/tuning-and-link.md §5.2-5.5
// (seed 000 claims 14-15) and the file /work/wt/WRITE_PLAN.md defines between `formloop tune` and
// `formloop link write` (format "formloop.offset_write_plan", version 1).
//
// Ladder. new_j = previous_j + δq_j. An offset is within its limits when |new_j − baseline_j| ≤ L_j and,
// when given, |δq_j| ≤ step_limit_j (1e-12 mm slack for binary rounding). Otherwise:
//  (i) nothing is written (the offending offsets never appear in `writes`);
//  (ii) RECHECK: the standard block is probed again and the dimensions and the solve are recomputed with
//       the new block errors;
//  (iii) still beyond → INTERVENE: an alarm/feed hold is asked for, each offending offset is listed with
//       its value and limit, and manual action is needed. Limits are not overridable here.
// Other reasons block the write (BLOCKED): current offsets unknown, solver MAX_ITER, a stale block, a
// COMPENSATE dimension not measured or invalid, dimensions that will stay NG (NOT_REACHABLE or NG after
// rounding), or TOLERANCE_ONLY dimensions OK now that the change makes NG (through their K rows), without
// an acknowledgement naming them, an averaging ALARM without the operator's
// acceptance. The status is INTERVENE > RECHECK > BLOCKED > SAFE; blocked_reasons lists every reason.
// `writes` holds the non-zero rounded changes only when the status is SAFE (otherwise []); `proposed`
// (an extra field the reader ignores) always lists every non-zero change with its limit check.
// `confirmed` is true only for a SAFE plan the operator confirmed.

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "tuning/measurement_model.h"

namespace formloop::tuning {

enum class PlanStatus { kSafe, kRecheck, kIntervene, kBlocked };
const char* PlanStatusName(PlanStatus status);

struct OffsetChange {
  const ModelOffset* offset = nullptr;
  std::optional<double> previous_mm;  // o_prev read at acquisition start (unknown without --offsets)
  double delta_continuous_mm = 0;     // δ before rounding
  double delta_mm = 0;                // δq
  std::string rule;                   // how δq came about
  double new_mm = 0;                  // previous + δq (when previous is known)
  bool checked = false;               // previous known, limits evaluated
  bool within_limits = true;
  std::string violation;  // names the offset, the value and the limit
};

// Evaluates the limits of every change (previous values by offset id; missing → unchecked).
std::vector<OffsetChange> CheckOffsetLimits(const MeasurementModel& model, const Eigen::VectorXd& delta_continuous_mm,
                                            const Eigen::VectorXd& delta_rounded_mm,
                                            const std::vector<std::string>& rules,
                                            const std::map<std::string, double>& previous_mm);
bool AllWithinLimits(const std::vector<OffsetChange>& changes);

struct WritePlan {
  std::string session;
  PlanStatus status = PlanStatus::kBlocked;
  std::vector<std::string> blocked_reasons;
  bool confirmed = false;
  std::vector<std::string> not_reachable_acknowledged;
  std::vector<OffsetChange> changes;  // every offset (zero changes included; the JSON keeps non-zero ones)
  std::string strategy;
  nlohmann::json ToJson() const;  // the WRITE_PLAN.md document
};

// Reads "formloop.current_offsets" ({"format": "formloop.current_offsets", "version": 1, "read_at": "...",
// "values_mm": {"T3_radius_wear": 0.085, ...}}); every offset of the model must be present.
Result<std::map<std::string, double>> ReadCurrentOffsets(const std::filesystem::path& path,
                                                         const MeasurementModel& model);

}  // namespace formloop::tuning
