#pragma once
// Standard-block correction of in-machine probe points (spec/tuning-and-link.md §3; seed 000).
//
// A gauge block per corrected axis sits in the machine; each calibration point j has a reference value
// R_j certified off the machine (CMM) and, in every run, an in-machine value M_j. The in-machine error at
// j is e_j = M_j − R_j, and a part coordinate p along that axis is corrected as p' = p − ê(p), each axis
// separately, on the raw points before any fit. ê(p):
//  - NEAREST (seed 000): e_j* with j* = argmin_j |p − R_j|; on a tie the mean of the tied errors.
//  - LINEAR: linear interpolation between the two calibration points that bracket p; outside
//    [R_min, R_max] the end value, flagged EXTRAPOLATED when p is more than half the end interval beyond
//    the end point.
//  - SCALE: least-squares line e(p) = α + β·p over the axis' calibration points (needs 2 distinct R);
//    β, the effective thermal scale mismatch, is reported in µm/m.
// Axes without calibration points are left as they are.
//
// Worked example (seed 000): A1 probed at −118.000 with nearest calibration point −117.0 (e = +0.009)
// → −118.009; A2 at −142.000 (e = +0.011) → −142.011; the two-point diameter 24.000 → 24.002. The sign
// convention (e = M − R, subtracted) is reconstructed from that arithmetic (spec §3 [R]).
//
// Staleness: block values must come from the same session as the part points; when both carry times
// and they are more than max_age_s apart (30 min by default) the block is BLOCK_STALE (dimensions are
// flagged and write-back is blocked by the caller).
//
// Block file (CSV, '#' comments): header `axis,reference_mm,measured_mm` and optionally `t` (s, the same
// clock as the points' t column); axis is X, Y or Z; one row per calibration point.

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/status.h"

namespace formloop::metrology {

enum class BlockMode { kNearest, kLinear, kScale };
const char* BlockModeName(BlockMode mode);
bool ParseBlockMode(const std::string& text, BlockMode* mode);  // "NEAREST" | "LINEAR" | "SCALE"

struct CalibrationPoint {
  int axis = 0;             // 0 = X, 1 = Y, 2 = Z
  double reference_mm = 0;  // R_j (certificate)
  double measured_mm = 0;   // M_j (this run)
  std::optional<double> time_s;
};

struct StandardBlock {
  std::vector<CalibrationPoint> points;
  std::string source;  // file name, for messages
};

// Errors name the file, line and field; two rows with the same axis and reference are an error.
Result<StandardBlock> ReadStandardBlockCsv(const std::filesystem::path& path);

struct AxisCorrection {
  double error_mm = 0;        // ê(p), subtracted from p
  bool extrapolated = false;  // LINEAR beyond half an end interval
};

class BlockCorrector {
 public:
  // BadInput when an axis has no usable data for the mode (SCALE with one distinct reference).
  static Result<BlockCorrector> Build(const StandardBlock& block, BlockMode mode);

  BlockMode mode() const { return mode_; }
  bool HasAxis(int axis) const { return !axes_[axis].reference_mm.empty(); }
  AxisCorrection ErrorAt(int axis, double coordinate_mm) const;
  // β of the SCALE fit in µm/m (0 for the other modes or an axis without points).
  double ScaleMismatchUmPerM(int axis) const { return axes_[axis].beta * 1e6; }
  // p' = p − ê(p) on every calibrated axis (only where `measured` is true); *extrapolated is set when any
  // axis was extrapolated.
  Eigen::Vector3d Correct(const Eigen::Vector3d& p, const std::array<bool, 3>& measured, bool* extrapolated) const;
  nlohmann::json ToJson() const;

 private:
  struct Axis {
    std::vector<double> reference_mm;  // sorted ascending, unique
    std::vector<double> error_mm;      // mean error per reference
    double alpha = 0, beta = 0;        // SCALE
  };
  BlockMode mode_ = BlockMode::kNearest;
  Axis axes_[3];
};

struct BlockAge {
  bool checked = false;  // both the block and the points carry times
  double max_gap_s = 0;  // largest |t_block − t_point|
  bool stale = false;    // max_gap_s > max_age_s
};
BlockAge CheckBlockAge(const StandardBlock& block, const std::vector<double>& point_times_s, double max_age_s);

}  // namespace formloop::metrology
