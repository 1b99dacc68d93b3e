#pragma once
// A set of 3-D points (mm) with optional per-point attributes.
//
//   points   #P positions, mm, in the frame the producer states (usually the machine or part frame)
//   normals  empty or #P unit vectors
//   ids      empty or #P integer ids (probe point id, CC point id ...)
//   times_s  empty or #P times, s
//   scalars  named columns, each #P values, in insertion order (e.g. "deviation_um")
//
// Invariant: every non-empty attribute has exactly #P entries; Validate() checks it and that all
// values are finite.

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/status.h"

namespace formloop {

struct ScalarColumn {
  std::string name;
  std::vector<double> values;
};

struct PointSet {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3d> normals;
  std::vector<std::int64_t> ids;
  std::vector<double> times_s;
  std::vector<ScalarColumn> scalars;

  std::size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool has_normals() const { return !normals.empty(); }
  bool has_ids() const { return !ids.empty(); }
  bool has_times() const { return !times_s.empty(); }

  // Adds or replaces a named scalar column. values.size() must equal size() (checked by Validate()).
  void SetScalar(const std::string& name, std::vector<double> values);
  // nullptr when no column has that name.
  const std::vector<double>* FindScalar(const std::string& name) const;
  std::vector<double>* FindScalar(const std::string& name);

  // Checks sizes, finiteness, unique non-empty scalar names that do not clash with the reserved
  // names (x y z nx ny nz id t). `source` names the data in the message (a file or a stage).
  Status Validate(const std::string& source) const;
};

// Column names with a fixed meaning in every point file format.
inline constexpr const char* kReservedColumns[] = {"x", "y", "z", "nx", "ny", "nz", "id", "t"};
bool IsReservedColumn(const std::string& name);

}  // namespace formloop
