#pragma once
// Simple tool-wear compensation by averaging (spec/tuning-and-link.md §6; seed 004), the `--strategy
// average` beside the weighted solve.
//
// Each COMPENSATE dimension whose K row has exactly one offset (a tool's radius or length wear, or a work
// offset) gives a sub-compensation for that offset's cell:
//   1. band centre a = (u + l)/2, target s* = s + a (seed 004's "additional compensation" for asymmetric
//      tolerances, aiming at the middle of the band [R]);
//   2. skipped when |s* − m| < skip_band_mm (default 0.002 mm);
//   3. sub = f·(s* − m) with f = 1/K (seed 004's factor per compensation type: +1 outer, −1 inner in its
//      diameter terms; K = ±2 here for sizes made by a radius offset);
// the cell's value is the mean of its subs. |value| > max_mm (default 0.020 mm) raises ALARM: the value is
// only sent after the operator confirms (logged). Dimensions on several offsets are skipped with a reason:
// averaging cannot split one deviation between offsets (use the weighted solve).
//
// With one offset per dimension, |K| equal within a cell, equal weights, no bounds and no regularisation,
// the weighted solve of tuning/offset_solve.h with BAND_CENTRE targets gives exactly this average.

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"
#include "tuning/offset_solve.h"

namespace formloop::tuning {

struct AverageOptions {
  double skip_band_mm = 0.002;  // |s* − m| below this: no compensation from that dimension
  double max_mm = 0.020;        // allowed |value| per cell before ALARM
  Status Validate() const;
};

struct AverageDimension {
  std::string id;
  bool used = false;
  std::string reason;  // why it was skipped (empty when used)
  int offset = -1;     // the cell it fed
  double sub_mm = 0;   // its sub-compensation
};

struct AverageCell {
  int offset = -1;
  double sum_mm = 0;
  int count = 0;
  double value_mm = 0;  // sum / count
  bool alarm = false;   // |value| > max_mm
};

struct AverageResult {
  Eigen::VectorXd delta_mm;  // k: the cell values (0 for offsets without dimensions)
  std::vector<AverageDimension> dimensions;
  std::vector<AverageCell> cells;  // only cells with at least one sub
  bool alarm = false;
  nlohmann::json ToJson(const OffsetProblem& problem) const;
};

// The problem's COMPENSATE dimensions; the problem's targets are ignored (the strategy always aims at the
// band centre).
Result<AverageResult> AverageWearCompensation(const OffsetProblem& problem, const AverageOptions& options = {});

}  // namespace formloop::tuning
