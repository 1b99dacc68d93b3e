#include "metrology/standard_block.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "core/atomic_file.h"
#include "core/csv.h"
#include "core/point_io.h"

namespace formloop::metrology {
namespace {

const char* kAxisNames[] = {"X", "Y", "Z"};

}  // namespace

const char* BlockModeName(BlockMode mode) {
  switch (mode) {
    case BlockMode::kNearest:
      return "NEAREST";
    case BlockMode::kLinear:
      return "LINEAR";
    case BlockMode::kScale:
      return "SCALE";
  }
  return "?";
}

bool ParseBlockMode(const std::string& text, BlockMode* mode) {
  for (BlockMode m : {BlockMode::kNearest, BlockMode::kLinear, BlockMode::kScale}) {
    if (text == BlockModeName(m)) {
      *mode = m;
      return true;
    }
  }
  return false;
}

Result<StandardBlock> ReadStandardBlockCsv(const std::filesystem::path& path) {
  FL_ASSIGN_OR_RETURN(std::string text, ReadFile(path));
  if (text.rfind("\xEF\xBB\xBF", 0) == 0) text.erase(0, 3);  // UTF-8 byte-order mark (spreadsheets write one)
  StandardBlock block;
  block.source = path.string();
  FL_ASSIGN_OR_RETURN(const CsvTable table, ParseCsvTable(text, block.source, /*require_rows=*/false));
  const std::string fix = "write the header axis,reference_mm,measured_mm[,t] and one row per calibration point";
  if (table.header_line == 0 || table.rows.empty()) {
    return Status::BadInput(Where{.file = block.source}, "no calibration points", fix);
  }
  for (const std::string& name : table.header) {
    if (name != "axis" && name != "reference_mm" && name != "measured_mm" && name != "t") {
      return Status::BadInput(Where{.file = block.source, .line = table.header_line, .field = name}, "unknown column",
                              "the block file has columns axis,reference_mm,measured_mm and optionally t");
    }
  }
  FL_ASSIGN_OR_RETURN(const int col_axis, table.Column("axis", "axis"));
  FL_ASSIGN_OR_RETURN(const int col_ref, table.Column("reference_mm", "reference_mm"));
  FL_ASSIGN_OR_RETURN(const int col_meas, table.Column("measured_mm", "measured_mm"));
  const int col_t = table.Find("t");
  std::map<std::pair<int, double>, long> seen;
  for (std::size_t row = 0; row < table.rows.size(); ++row) {
    const long line_no = table.lines[row];
    CalibrationPoint p;
    const std::string& axis = table.rows[row][col_axis];
    if (axis == "X" || axis == "x")
      p.axis = 0;
    else if (axis == "Y" || axis == "y")
      p.axis = 1;
    else if (axis == "Z" || axis == "z")
      p.axis = 2;
    else {
      return Status::BadInput(Where{.file = block.source, .line = line_no, .field = "axis"},
                              "value '" + axis + "' is not an axis", "write X, Y or Z");
    }
    FL_RETURN_IF_ERROR(table.Number(row, col_ref, &p.reference_mm));
    FL_RETURN_IF_ERROR(table.Number(row, col_meas, &p.measured_mm));
    if (col_t >= 0 && !table.rows[row][col_t].empty()) {
      double t = 0;
      FL_RETURN_IF_ERROR(table.Number(row, col_t, &t));
      p.time_s = t;
    }
    const auto key = std::make_pair(p.axis, p.reference_mm);
    if (auto it = seen.find(key); it != seen.end()) {
      return Status::BadInput(Where{.file = block.source, .line = line_no, .field = "reference_mm"},
                              "calibration point " + std::string(kAxisNames[p.axis]) + " " + table.rows[row][col_ref] +
                                  " is already given on line " + std::to_string(it->second),
                              "list each calibration point once");
    }
    seen[key] = line_no;
    block.points.push_back(p);
  }
  return block;
}

Result<BlockCorrector> BlockCorrector::Build(const StandardBlock& block, BlockMode mode) {
  BlockCorrector corrector;
  corrector.mode_ = mode;
  std::map<double, std::vector<double>> per_axis[3];
  for (const auto& p : block.points) per_axis[p.axis][p.reference_mm].push_back(p.measured_mm - p.reference_mm);
  for (int axis = 0; axis < 3; ++axis) {
    Axis& a = corrector.axes_[axis];
    for (const auto& [ref, errors] : per_axis[axis]) {
      double sum = 0;
      for (double e : errors) sum += e;
      a.reference_mm.push_back(ref);
      a.error_mm.push_back(sum / static_cast<double>(errors.size()));
    }
    if (mode == BlockMode::kScale && !a.reference_mm.empty()) {
      const int n = static_cast<int>(a.reference_mm.size());
      if (n < 2) {
        return Status::BadInput(Where{.file = block.source, .field = kAxisNames[axis]},
                                "SCALE mode needs at least 2 calibration points on each corrected axis, axis " +
                                    std::string(kAxisNames[axis]) + " has 1",
                                "add a calibration point or use NEAREST/LINEAR");
      }
      double mean_r = 0, mean_e = 0;
      for (int i = 0; i < n; ++i) {
        mean_r += a.reference_mm[i];
        mean_e += a.error_mm[i];
      }
      mean_r /= n;
      mean_e /= n;
      double sxx = 0, sxy = 0;
      for (int i = 0; i < n; ++i) {
        sxx += (a.reference_mm[i] - mean_r) * (a.reference_mm[i] - mean_r);
        sxy += (a.reference_mm[i] - mean_r) * (a.error_mm[i] - mean_e);
      }
      a.beta = sxy / sxx;
      a.alpha = mean_e - a.beta * mean_r;
    }
  }
  return corrector;
}

AxisCorrection BlockCorrector::ErrorAt(int axis, double p) const {
  const Axis& a = axes_[axis];
  AxisCorrection out;
  const int n = static_cast<int>(a.reference_mm.size());
  if (n == 0) return out;
  switch (mode_) {
    case BlockMode::kNearest: {
      double best = 1e300;
      for (int i = 0; i < n; ++i) best = std::min(best, std::abs(p - a.reference_mm[i]));
      double sum = 0;
      int count = 0;
      for (int i = 0; i < n; ++i) {
        // A tie within rounding of the distances counts as a tie.
        if (std::abs(p - a.reference_mm[i]) <= best + 1e-12 * std::max(1.0, std::abs(p))) {
          sum += a.error_mm[i];
          ++count;
        }
      }
      out.error_mm = sum / count;
      return out;
    }
    case BlockMode::kLinear: {
      if (n == 1) {
        out.error_mm = a.error_mm[0];
        return out;
      }
      if (p <= a.reference_mm.front()) {
        out.error_mm = a.error_mm.front();
        out.extrapolated = a.reference_mm.front() - p > 0.5 * (a.reference_mm[1] - a.reference_mm[0]);
        return out;
      }
      if (p >= a.reference_mm.back()) {
        out.error_mm = a.error_mm.back();
        out.extrapolated = p - a.reference_mm.back() > 0.5 * (a.reference_mm[n - 1] - a.reference_mm[n - 2]);
        return out;
      }
      const auto it = std::upper_bound(a.reference_mm.begin(), a.reference_mm.end(), p);
      const int hi = static_cast<int>(it - a.reference_mm.begin());
      const int lo = hi - 1;
      const double w = (p - a.reference_mm[lo]) / (a.reference_mm[hi] - a.reference_mm[lo]);
      out.error_mm = a.error_mm[lo] + w * (a.error_mm[hi] - a.error_mm[lo]);
      return out;
    }
    case BlockMode::kScale:
      out.error_mm = a.alpha + a.beta * p;
      return out;
  }
  return out;
}

Eigen::Vector3d BlockCorrector::Correct(const Eigen::Vector3d& p, const std::array<bool, 3>& measured,
                                        bool* extrapolated) const {
  Eigen::Vector3d out = p;
  for (int axis = 0; axis < 3; ++axis) {
    if (!measured[axis] || !HasAxis(axis)) continue;
    const AxisCorrection c = ErrorAt(axis, p(axis));
    out(axis) = p(axis) - c.error_mm;
    if (extrapolated && c.extrapolated) *extrapolated = true;
  }
  return out;
}

nlohmann::json BlockCorrector::ToJson() const {
  nlohmann::json axes = nlohmann::json::object();
  for (int axis = 0; axis < 3; ++axis) {
    const Axis& a = axes_[axis];
    if (a.reference_mm.empty()) continue;
    nlohmann::json points = nlohmann::json::array();
    for (std::size_t i = 0; i < a.reference_mm.size(); ++i) {
      points.push_back({{"reference_mm", a.reference_mm[i]}, {"error_mm", a.error_mm[i]}});
    }
    nlohmann::json j = {{"points", points}};
    if (mode_ == BlockMode::kScale) {
      j["alpha_mm"] = a.alpha;
      j["scale_mismatch_um_per_m"] = a.beta * 1e6;
    }
    axes[kAxisNames[axis]] = j;
  }
  return {{"mode", BlockModeName(mode_)}, {"axes", axes}};
}

BlockAge CheckBlockAge(const StandardBlock& block, const std::vector<double>& point_times_s, double max_age_s) {
  BlockAge age;
  std::vector<double> block_times;
  for (const auto& p : block.points) {
    if (p.time_s) block_times.push_back(*p.time_s);
  }
  if (block_times.empty() || point_times_s.empty()) return age;
  age.checked = true;
  const auto [pmin, pmax] = std::minmax_element(point_times_s.begin(), point_times_s.end());
  const auto [bmin, bmax] = std::minmax_element(block_times.begin(), block_times.end());
  age.max_gap_s = std::max(std::abs(*pmax - *bmin), std::abs(*bmax - *pmin));
  age.stale = age.max_gap_s > max_age_s;
  return age;
}

}  // namespace formloop::metrology
