#pragma once
// A uniform 3-D cell grid over a fixed set of points (the foot-point projector's start samples,
// foot_point.h) with exact nearest-point and within-radius queries in double precision.
//
// The samples of a surface lie on a 2-D sheet, so with cells about twice the sample spacing a query
// near the surface visits a few dozen cells holding a handful of samples each: a fixed amount of
// work with no tree descent, which for the projector's queries (the nearest sample, then all samples
// within d + δ of the point) is several times faster than a kd-tree (measured in
// bench/projection_bench.cc: the "ours" rows before and after, 2026-11). Cells are stored densely
// (counting sort of the points by cell, then the points' coordinates in cell order); the cell is
// enlarged when the points' bounding box would need more than kMaxCellsPerPoint cells a point.

#include <Eigen/Core>
#include <vector>

namespace formloop::recon {

class PointGrid {
 public:
  PointGrid() = default;
  // cell_mm > 0: the intended cell edge (see above).
  PointGrid(const std::vector<Eigen::Vector3d>& points, double cell_mm);

  // Index of the point nearest to p (ties: the lower index) and its distance; −1 if there are none.
  // With seen != nullptr, also every point the search looked at as (squared distance, index), unordered,
  // and *complete_mm: seen holds every point within that distance of p (the search's cube of cells).
  int Nearest(const Eigen::Vector3d& p, double* distance_mm, std::vector<std::pair<double, int>>* seen = nullptr,
              double* complete_mm = nullptr) const;
  // Every point with |p − point| ≤ radius_mm as (distance, index), nearest first (ties: lower index).
  void WithinRadius(const Eigen::Vector3d& p, double radius_mm, std::vector<std::pair<double, int>>* out) const;

  std::size_t size() const { return index_.size(); }

 private:
  int CellCoord(double x, int axis) const;
  std::size_t CellIndex(int ix, int iy, int iz) const {
    return (static_cast<std::size_t>(iz) * dims_[1] + static_cast<std::size_t>(iy)) * dims_[0] +
           static_cast<std::size_t>(ix);
  }

  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double cell_mm_ = 1;
  int dims_[3] = {0, 0, 0};
  std::vector<int> start_;               // cell c holds the points start_[c] .. start_[c + 1] − 1 (cell order)
  std::vector<Eigen::Vector3d> sorted_;  // the points in cell order
  std::vector<int> index_;               // their indices in the input
};

}  // namespace formloop::recon
