#pragma once
// Spatial weights for Moran's I (spec/metrology.md §5).
//
//   W  n × n sparse, row-major; w_ij > 0 when j is a neighbour of i; w_ii = 0.
// k-nearest-neighbour weights are asymmetric (j among i's k nearest does not make i among j's).
// Islands (rows without neighbours) are counted; Moran's I refuses weights with islands unless the
// caller drops them, so they never distort n silently.

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/status.h"

namespace formloop::metrology {

enum class WeightStyle {
  kBinary,           // "B": w_ij = 1 for neighbours
  kRowStandardised,  // "W": each row sums to 1
};

struct SpatialWeights {
  Eigen::SparseMatrix<double, Eigen::RowMajor> w;
  WeightStyle style = WeightStyle::kRowStandardised;
  int islands = 0;
  int n() const { return static_cast<int>(w.rows()); }
};

// k nearest neighbours of each point among the others (ties broken by index), 2-D or 3-D points
// as columns of `points` (2 × n or 3 × n). Uses PCL's kd-tree (FLANN).
Result<SpatialWeights> KnnWeights(const Eigen::MatrixXd& points, int k, WeightStyle style);

// Binary neighbour lists -> weights of the given style (neighbours[i] = 0-based indices).
Result<SpatialWeights> WeightsFromNeighbours(const std::vector<std::vector<int>>& neighbours, WeightStyle style);

// GAL file (GeoDa/PySAL): first line n (or "0 n name id"), then per unit "id count" and a line of
// neighbour ids. `ids` gives the order of the data rows; every GAL id must be among them.
Result<SpatialWeights> ReadGal(const std::filesystem::path& path, const std::vector<std::string>& ids,
                               WeightStyle style);

}  // namespace formloop::metrology
