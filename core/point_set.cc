#include "core/point_set.h"

#include <cmath>
#include <set>

namespace formloop {

void PointSet::SetScalar(const std::string& name, std::vector<double> values) {
  if (auto* existing = FindScalar(name)) {
    *existing = std::move(values);
    return;
  }
  scalars.push_back({name, std::move(values)});
}

const std::vector<double>* PointSet::FindScalar(const std::string& name) const {
  for (const auto& column : scalars) {
    if (column.name == name) return &column.values;
  }
  return nullptr;
}

std::vector<double>* PointSet::FindScalar(const std::string& name) {
  for (auto& column : scalars) {
    if (column.name == name) return &column.values;
  }
  return nullptr;
}

bool IsReservedColumn(const std::string& name) {
  for (const char* reserved : kReservedColumns) {
    if (name == reserved) return true;
  }
  return false;
}

Status PointSet::Validate(const std::string& source) const {
  const std::size_t n = points.size();
  auto size_error = [&](const std::string& what, std::size_t got) {
    return Status::Internal(source + ": " + what + " has " + std::to_string(got) + " entries for " + std::to_string(n) +
                            " points");
  };
  if (!normals.empty() && normals.size() != n) return size_error("normals", normals.size());
  if (!ids.empty() && ids.size() != n) return size_error("ids", ids.size());
  if (!times_s.empty() && times_s.size() != n) return size_error("times", times_s.size());
  std::set<std::string> names;
  for (const auto& column : scalars) {
    if (column.name.empty()) return Status::Internal(source + ": a scalar column has no name");
    if (IsReservedColumn(column.name)) {
      return Status::Internal(source + ": scalar column '" + column.name + "' uses a reserved name");
    }
    if (!names.insert(column.name).second) {
      return Status::Internal(source + ": scalar column '" + column.name + "' appears twice");
    }
    if (column.values.size() != n) return size_error("scalar '" + column.name + "'", column.values.size());
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!points[i].allFinite()) {
      return Status::BadInput(source + ": point " + std::to_string(i) + " has a non-finite coordinate");
    }
    if (!normals.empty() && !normals[i].allFinite()) {
      return Status::BadInput(source + ": normal " + std::to_string(i) + " is not finite");
    }
    if (!times_s.empty() && !std::isfinite(times_s[i])) {
      return Status::BadInput(source + ": time " + std::to_string(i) + " is not finite");
    }
  }
  for (const auto& column : scalars) {
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(column.values[i])) {
        return Status::BadInput(source + ": scalar '" + column.name + "' of point " + std::to_string(i) +
                                " is not finite");
      }
    }
  }
  return Status::Ok();
}

}  // namespace formloop
