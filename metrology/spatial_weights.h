#pragma once
// Spatial weights for Moran's I (spec/metrology.md §5).
//
//   W  n × n sparse, row-major; w_ij > 0 when j is a neighbour of i; w_ii = 0.
// k-nearest-neighbour weights are asymmetric (j among i's k nearest does not make i among j's);
// Delaunay and distance-band weights are symmetric in their neighbour structure (row-standardised
// values are not).
//
// Islands (rows without neighbours) are counted and listed; what Moran's I does with them is an
// explicit IslandPolicy (refuse, drop, or keep them as zero rows with the full n), never silent.

#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/status.h"

namespace formloop::metrology {

enum class WeightStyle {
  kBinary,           // "B": w_ij = 1 for neighbours
  kRowStandardised,  // "W": each row sums to 1
};

// "B" or "W" (case-insensitive); BadInput naming `option` otherwise.
Result<WeightStyle> ParseWeightStyle(std::string_view text, const std::string& option = "--style");
const char* WeightStyleName(WeightStyle style);  // "B" / "W"

// What to do with units that have no neighbours (PySAL/spdep "islands").
enum class IslandPolicy {
  kRefuse,  // BadInput naming the islands (the default: nothing happens silently)
  kDrop,    // remove them from data and weights (repeated until no island is left, since removing a
            // unit can empty another's row); n counts the units kept
  kZero,    // keep them as zero rows and columns with the full n: PySAL's behaviour, spdep's
            // zero.policy = TRUE with adjust.n = FALSE. The Cliff–Ord moments stay exact, since they
            // hold for any W with zero diagonal (S0, S1, S2 simply receive nothing from those rows).
};
Result<IslandPolicy> ParseIslandPolicy(std::string_view text, const std::string& option = "--islands");
const char* IslandPolicyName(IslandPolicy policy);  // "refuse" / "drop" / "zero"

struct SpatialWeights {
  SpatialWeights() = default;
  SpatialWeights(const SpatialWeights&) = default;
  SpatialWeights& operator=(const SpatialWeights&) = default;
  // Eigen 3.4's SparseMatrix has no move operations: moving swaps its storage instead of copying it
  // (three copies of 10 MB for k = 8 on 1e5 points on the way out through Result otherwise).
  SpatialWeights(SpatialWeights&& other) noexcept { *this = std::move(other); }
  SpatialWeights& operator=(SpatialWeights&& other) noexcept {
    if (this != &other) {
      Eigen::SparseMatrix<double, Eigen::RowMajor> released;
      w.swap(released);
      w.swap(other.w);
      style = other.style;
      islands = other.islands;
      island_indices = std::move(other.island_indices);
    }
    return *this;
  }

  Eigen::SparseMatrix<double, Eigen::RowMajor> w;
  WeightStyle style = WeightStyle::kRowStandardised;
  int islands = 0;                  // rows without neighbours
  std::vector<int> island_indices;  // their 0-based rows, ascending
  int n() const { return static_cast<int>(w.rows()); }
  // Neighbour lists (0-based, ascending) recovered from the sparsity pattern.
  std::vector<std::vector<int>> Neighbours() const;
};

// k nearest neighbours of each point among the others, 2-D or 3-D points as columns of `points`
// (2 × n or 3 × n): the k smallest (‖p_j − p_i‖², j) in double, so ties are broken by index. A
// nanoflann kd-tree in double gives the candidates (with a radius search when equidistant points may
// reach past them); the compressed rows are written directly, points searched on both cores.
Result<SpatialWeights> KnnWeights(const Eigen::MatrixXd& points, int k, WeightStyle style);

// Delaunay neighbours of 2-D points (2 × n, e.g. (u, v)): i and j are neighbours when the Delaunay
// triangulation (CGAL Delaunay_triangulation_2, exact predicates) has the edge ij. Collinear points
// give the chain along the line. Coincident points are refused (BadInput naming both indices): the
// triangulation would merge them and leave one without neighbours.
Result<SpatialWeights> DelaunayWeights(const Eigen::MatrixXd& uv, WeightStyle style);

// Distance band: j is a neighbour of i when 0 < j ≠ i and ‖p_j − p_i‖ ≤ radius (inclusive, as
// libpysal's DistanceBand), 2-D or 3-D points as columns. nanoflann radius search, with the band
// decided in double precision. Points farther than `radius` from every other become islands.
Result<SpatialWeights> DistanceBandWeights(const Eigen::MatrixXd& points, double radius, WeightStyle style);

// Binary neighbour lists -> weights of the given style (neighbours[i] = 0-based indices; duplicates
// and self-references are ignored).
Result<SpatialWeights> WeightsFromNeighbours(const std::vector<std::vector<int>>& neighbours, WeightStyle style);

// GAL file (GeoDa/PySAL): first line n (or "0 n name id"), then per unit "id count" and a line of
// neighbour ids. `ids` gives the order of the data rows; every GAL id must be among them.
Result<SpatialWeights> ReadGal(const std::filesystem::path& path, const std::vector<std::string>& ids,
                               WeightStyle style);

// Writes the neighbour structure of `weights` as a GAL file (first line n; islands get "id 0" and
// no list line), atomically. ids: one per row, without whitespace. ReadGal reads it back exactly.
Status WriteGal(const std::filesystem::path& path, const SpatialWeights& weights, const std::vector<std::string>& ids);

// The weights an IslandPolicy leaves. kept: original rows still in use (all of them unless kDrop);
// dropped: original rows removed (kDrop only, ascending); weights: over `kept`, restyled after a drop.
struct IslandResolution {
  IslandPolicy policy = IslandPolicy::kRefuse;
  int islands = 0;           // islands in the weights as given
  std::vector<int> kept;     // 0-based original rows
  std::vector<int> dropped;  // 0-based original rows
  SpatialWeights weights;
};
// kRefuse: BadInput listing (the first few) islands with the fix. kZero: the weights unchanged.
Result<IslandResolution> ResolveIslands(const SpatialWeights& weights, IslandPolicy policy);

}  // namespace formloop::metrology
