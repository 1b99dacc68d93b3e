#include "tuning/wear_average.h"

#include <cmath>
#include <map>

namespace formloop::tuning {

Status AverageOptions::Validate() const {
  if (!(skip_band_mm >= 0)) {
    return Status::BadInput(Where{.field = "average.skip_band_mm"}, "must be >= 0", "use the default 0.002");
  }
  if (!(max_mm > 0)) return Status::BadInput(Where{.field = "average.max_mm"}, "must be > 0", "use the default 0.020");
  return Status::Ok();
}

Result<AverageResult> AverageWearCompensation(const OffsetProblem& p, const AverageOptions& options) {
  FL_RETURN_IF_ERROR(p.Validate());
  FL_RETURN_IF_ERROR(options.Validate());
  const int n = static_cast<int>(p.dimension_ids.size());
  const int k = static_cast<int>(p.offset_ids.size());
  const Eigen::SparseMatrix<double, Eigen::RowMajor> rows(p.k);
  AverageResult out;
  out.delta_mm = Eigen::VectorXd::Zero(k);
  std::map<int, AverageCell> cells;
  for (int i = 0; i < n; ++i) {
    AverageDimension d;
    d.id = p.dimension_ids[i];
    int offset = -1, nonzeros = 0;
    double coefficient = 0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(rows, i); it; ++it) {
      if (it.value() == 0) continue;
      ++nonzeros;
      offset = static_cast<int>(it.col());
      coefficient = it.value();
    }
    const double a = 0.5 * (p.tol_upper_mm(i) + p.tol_lower_mm(i));
    const double gap = a - p.deviation_mm(i);  // s* − m
    if (nonzeros != 1) {
      d.reason = "depends on " + std::to_string(nonzeros) +
                 " offsets; averaging needs exactly one (the weighted solve splits it)";
    } else if (std::abs(gap) < options.skip_band_mm) {
      d.reason = "|s* - m| = " + std::to_string(std::abs(gap)) + " mm is below the skip band " +
                 std::to_string(options.skip_band_mm) + " mm";
      d.offset = offset;
    } else {
      d.used = true;
      d.offset = offset;
      d.sub_mm = gap / coefficient;
      AverageCell& cell = cells[offset];
      cell.offset = offset;
      cell.sum_mm += d.sub_mm;
      ++cell.count;
    }
    out.dimensions.push_back(d);
  }
  for (auto& [j, cell] : cells) {
    cell.value_mm = cell.sum_mm / cell.count;
    cell.alarm = std::abs(cell.value_mm) > options.max_mm;
    out.alarm = out.alarm || cell.alarm;
    out.delta_mm(j) = cell.value_mm;
    out.cells.push_back(cell);
  }
  return out;
}

nlohmann::json AverageResult::ToJson(const OffsetProblem& p) const {
  nlohmann::json dims = nlohmann::json::array(), cs = nlohmann::json::array();
  for (const auto& d : dimensions) {
    nlohmann::json j = {{"id", d.id}, {"used", d.used}};
    if (d.offset >= 0) j["offset"] = p.offset_ids[d.offset];
    if (d.used) j["sub_mm"] = d.sub_mm;
    if (!d.reason.empty()) j["skipped"] = d.reason;
    dims.push_back(j);
  }
  for (const auto& c : cells) {
    cs.push_back({{"offset", p.offset_ids[c.offset]}, {"subs", c.count}, {"value_mm", c.value_mm}, {"alarm", c.alarm}});
  }
  return {{"dimensions", dims}, {"cells", cs}, {"alarm", alarm}};
}

}  // namespace formloop::tuning
