#pragma once
// `formloop tune`: probe points → dimensions → OK/NG → offset changes → safety ladder → write plan
// (spec/tuning-and-link.md §1-6; issue 21). The library function the CLI (app/cmd_tune.cc) wraps.
//
// Steps, each recorded with its inputs in DIR/audit.jsonl:
//  1. the measurement model (tuning/measurement_model.h), the probe points (CSV: id, x, y, z and
//     optionally t in s), optionally the standard block (metrology/standard_block.h) and the current
//     offsets read from the controller at acquisition start ("formloop.current_offsets");
//  2. every dimension not IGNOREd: its points (reference coordinates with the measured axes replaced,
//     block-corrected; a measured axis more than max_point_deviation_mm from its reference is an invalid
//     measurement), its value and standard uncertainty (metrology/dimensions.h) and its judgement;
//  3. the offset changes: `wls` (tuning/offset_solve.h, our trust-region reflective solve) or `average`
//     (tuning/wear_average.h, seed 004), rounded to the controller resolution inside the bounds (§5.1);
//  4. the ladder (tuning/write_plan.h): beyond a limit → RECHECK; with --recheck-block the dimensions
//     and the solve are recomputed with the re-probed block and, still beyond, INTERVENE;
//  5. outputs in DIR (built as DIR.partial, renamed when complete; an existing DIR is replaced only with
//     --force and only when it holds an earlier tune output; never a folder holding an input):
//     report.json and report.csv (per dimension: measured value, deviation, OK/NG, uncertainty, the
//     prediction after the change), offsets.json (the write plan of /work/wt/WRITE_PLAN.md),
//     audit.jsonl and summary.txt. Same inputs → byte-identical outputs (no clock is read).
//
// Bad inputs (model, points, block, current offsets, options) are errors with the file, field and fix, and
// nothing is written. A plan that is not SAFE is written (it documents the refusal) and reported through
// TuneReport::plan.status; the CLI exits 1 for it.

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/status.h"
#include "metrology/dimensions.h"
#include "metrology/standard_block.h"
#include "tuning/measurement_model.h"
#include "tuning/offset_solve.h"
#include "tuning/wear_average.h"
#include "tuning/write_plan.h"

namespace formloop::tuning {

enum class Strategy { kWls, kAverage };
const char* StrategyName(Strategy strategy);
bool ParseStrategy(const std::string& text, Strategy* strategy);  // "wls" | "average"

struct TuneOptions {
  std::filesystem::path model;            // required
  std::filesystem::path points;           // required (CSV)
  std::filesystem::path block;            // optional standard-block CSV of this session
  std::filesystem::path recheck_block;    // optional: the block probed again after a RECHECK
  std::filesystem::path current_offsets;  // optional: without it nothing can be written (BLOCKED)
  std::filesystem::path out;              // required
  Strategy strategy = Strategy::kWls;
  bool confirm = false;                     // the operator confirms the whole set of a SAFE plan
  bool accept_alarm = false;                // average: send a value beyond the allowed maximum (logged)
  std::vector<std::string> acknowledge_ng;  // dimensions the operator accepts will stay (or become) NG
  std::string session;                      // free text; default "<part code> <points file name>"
  std::string measured_at;                  // ISO 8601 with time zone, copied to the report records
  bool force = false;                       // replace an earlier tune output in `out`
  Status Validate() const;
};

struct DimensionResult {
  const ModelDimension* dimension = nullptr;
  std::string state;    // MEASURED | NOT_MEASURED | INVALID | IGNORED
  std::string problem;  // why NOT_MEASURED / INVALID
  metrology::DimensionEvaluation evaluation;
  metrology::Judgement judgement;
  bool extrapolated = false;  // a point's block correction was extrapolated
  std::vector<int> point_ids;
  // After the rounded change (COMPENSATE and TOLERANCE_ONLY with a K row; others unchanged).
  std::optional<double> predicted_value_after;
  std::optional<bool> predicted_ok_after;
  bool not_reachable = false;
  double r_eq_mm = 0;
};

struct TuneAttempt {
  std::string block_file;  // empty: no block correction
  std::optional<metrology::BlockCorrector> corrector;
  metrology::BlockAge block_age;
  std::vector<DimensionResult> dimensions;  // model order
  OffsetProblem problem;                    // the COMPENSATE dimensions that were measured
  std::vector<int> problem_rows;            // index into dimensions for each problem row
  std::optional<OffsetSolution> wls;
  std::optional<AverageResult> average;
  RoundedOffsets rounded;
  std::vector<OffsetChange> changes;
};

struct TuneReport {
  std::shared_ptr<const MeasurementModel> model;  // what the attempts' pointers refer to
  TuneAttempt first;
  std::optional<TuneAttempt> recheck;  // when the ladder re-probed the block
  WritePlan plan;
  std::vector<nlohmann::json> audit;  // the audit lines
  int ng_count = 0;                   // NG dimensions of the measured part
  const TuneAttempt& final_attempt() const { return recheck ? *recheck : first; }
  nlohmann::json SummaryJson() const;  // what the CLI prints on stdout
};

Result<TuneReport> RunTune(const TuneOptions& options);

}  // namespace formloop::tuning
