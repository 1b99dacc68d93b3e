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
//
// A query far from the sheet is another matter: the rings of cells grow around p until they reach the
// nearest point, so a point D above the sheet visits about (D / cell)^3 cells and every point in them (a
// probing move's clearance, sampled every 10 µm up to safe Z above a finely sampled CAD face, took three
// minutes in tests/app/cad_parts_test.cc). Once a query's grid work passes kMaxGridWork (point_grid.cc),
// it goes to a kd-tree over the same points (nanoflann, built once, by the first such query); the tree only
// proposes candidates, each kept or dropped by the same squared norm the grid uses, so both give the same
// answer, bit for bit.

#include <Eigen/Core>
#include <memory>
#include <utility>
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

  std::size_t size() const;

 private:
  struct Points;  // the points in cell order, their input indices, and the kd-tree once it is built
  int CellCoord(double x, int axis) const;
  std::size_t CellIndex(int ix, int iy, int iz) const {
    return (static_cast<std::size_t>(iz) * dims_[1] + static_cast<std::size_t>(iy)) * dims_[0] +
           static_cast<std::size_t>(ix);
  }

  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double cell_mm_ = 1;
  int dims_[3] = {0, 0, 0};
  std::vector<int> start_;  // cell c holds the points start_[c] .. start_[c + 1] − 1 (cell order)
  // Shared by copies (the points never change after construction), so a copy keeps the tree too.
  std::shared_ptr<const Points> points_;
};

}  // namespace formloop::recon
