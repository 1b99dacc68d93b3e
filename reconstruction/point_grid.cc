// Uniform 3-D cell grid with exact nearest and radius queries (point_grid.h).

#include "reconstruction/point_grid.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace formloop::recon {
namespace {

// Dense storage bound: at most this many cells a point (plus a floor for small sets); a larger
// bounding box gets larger cells.
constexpr double kMaxCellsPerPoint = 8;
constexpr double kMinCellBudget = 4096;

}  // namespace

PointGrid::PointGrid(const std::vector<Eigen::Vector3d>& points, double cell_mm) {
  if (points.empty()) return;
  Eigen::Vector3d lo = points.front(), hi = points.front();
  for (const Eigen::Vector3d& q : points) {
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  const Eigen::Vector3d extent = hi - lo;
  cell_mm_ = cell_mm > 0 && std::isfinite(cell_mm) ? cell_mm : std::max(1e-9, extent.maxCoeff());
  const double budget = std::max(kMinCellBudget, kMaxCellsPerPoint * static_cast<double>(points.size()));
  for (;;) {
    double cells = 1;
    for (int a = 0; a < 3; ++a) cells *= std::floor(extent(a) / cell_mm_) + 1;
    if (cells <= budget) break;
    cell_mm_ *= std::max(1.01, std::cbrt(cells / budget));
  }
  origin_ = lo;
  for (int a = 0; a < 3; ++a) dims_[a] = static_cast<int>(std::floor(extent(a) / cell_mm_)) + 1;
  const std::size_t n_cells = static_cast<std::size_t>(dims_[0]) * dims_[1] * dims_[2];
  std::vector<std::size_t> cell_of(points.size());
  start_.assign(n_cells + 1, 0);
  for (std::size_t k = 0; k < points.size(); ++k) {
    const Eigen::Vector3d& q = points[k];
    cell_of[k] = CellIndex(CellCoord(q.x(), 0), CellCoord(q.y(), 1), CellCoord(q.z(), 2));
    ++start_[cell_of[k] + 1];
  }
  for (std::size_t c = 0; c < n_cells; ++c) start_[c + 1] += start_[c];
  std::vector<int> fill(start_.begin(), start_.end() - 1);
  sorted_.resize(points.size());
  index_.resize(points.size());
  for (std::size_t k = 0; k < points.size(); ++k) {  // input order within a cell
    const int slot = fill[cell_of[k]]++;
    sorted_[static_cast<std::size_t>(slot)] = points[k];
    index_[static_cast<std::size_t>(slot)] = static_cast<int>(k);
  }
}

int PointGrid::CellCoord(double x, int axis) const {
  const double c = std::floor((x - origin_(axis)) / cell_mm_);
  if (!(c > 0)) return 0;  // also NaN
  return c >= dims_[axis] - 1 ? dims_[axis] - 1 : static_cast<int>(c);
}

int PointGrid::Nearest(const Eigen::Vector3d& p, double* distance_mm, std::vector<std::pair<double, int>>* seen,
                       double* complete_mm) const {
  int best = -1;
  double best_d2 = std::numeric_limits<double>::infinity();
  if (seen != nullptr) seen->clear();
  if (complete_mm != nullptr) *complete_mm = 0;
  if (index_.empty()) return best;
  const int cx = CellCoord(p.x(), 0), cy = CellCoord(p.y(), 1), cz = CellCoord(p.z(), 2);
  const int max_ring = std::max({cx, dims_[0] - 1 - cx, cy, dims_[1] - 1 - cy, cz, dims_[2] - 1 - cz});
  // Rings of cells at Chebyshev distance k from p's (clamped) cell: every point not yet seen is at
  // least k cells away along some axis, so farther than k · cell from p.
  // Points s_begin .. s_end − 1 (cell order): distances, the best so far, the seen list.
  auto visit = [&](int s_begin, int s_end) {
    for (int s = s_begin; s < s_end; ++s) {
      const double d2 = (sorted_[static_cast<std::size_t>(s)] - p).squaredNorm();
      const int id = index_[static_cast<std::size_t>(s)];
      if (seen != nullptr) seen->emplace_back(d2, id);
      if (d2 < best_d2 || (d2 == best_d2 && id < best)) {
        best_d2 = d2;
        best = id;
      }
    }
  };
  for (int k = 0; k <= max_ring; ++k) {
    const int x0 = std::max(0, cx - k), x1 = std::min(dims_[0] - 1, cx + k);
    for (int iz = std::max(0, cz - k); iz <= std::min(dims_[2] - 1, cz + k); ++iz) {
      for (int iy = std::max(0, cy - k); iy <= std::min(dims_[1] - 1, cy + k); ++iy) {
        if (std::abs(iz - cz) < k && std::abs(iy - cy) < k) {
          // A row through the inside of the ring: only its two end cells.
          if (cx - k >= 0) visit(start_[CellIndex(cx - k, iy, iz)], start_[CellIndex(cx - k, iy, iz) + 1]);
          if (cx + k < dims_[0]) visit(start_[CellIndex(cx + k, iy, iz)], start_[CellIndex(cx + k, iy, iz) + 1]);
        } else {
          // A row on the ring's surface: its cells x0 .. x1 are consecutive, one run of points.
          visit(start_[CellIndex(x0, iy, iz)], start_[CellIndex(x1, iy, iz) + 1]);
        }
      }
    }
    // Distance from p to the nearest face of the cube of cells searched that has cells beyond it.
    double complete = std::numeric_limits<double>::infinity();
    const int c[3] = {cx, cy, cz};
    for (int a = 0; a < 3; ++a) {
      if (c[a] - k > 0) complete = std::min(complete, p(a) - (origin_(a) + (c[a] - k) * cell_mm_));
      if (c[a] + k < dims_[a] - 1) complete = std::min(complete, origin_(a) + (c[a] + k + 1) * cell_mm_ - p(a));
    }
    complete = std::max(complete, k * cell_mm_);
    if (complete_mm != nullptr) *complete_mm = complete;
    if (best >= 0 && std::sqrt(best_d2) <= complete) break;
  }
  if (distance_mm != nullptr) *distance_mm = std::sqrt(best_d2);
  return best;
}

void PointGrid::WithinRadius(const Eigen::Vector3d& p, double radius_mm,
                             std::vector<std::pair<double, int>>* out) const {
  out->clear();
  if (index_.empty() || !(radius_mm >= 0)) return;
  const int x0 = CellCoord(p.x() - radius_mm, 0), x1 = CellCoord(p.x() + radius_mm, 0);
  const int y0 = CellCoord(p.y() - radius_mm, 1), y1 = CellCoord(p.y() + radius_mm, 1);
  const int z0 = CellCoord(p.z() - radius_mm, 2), z1 = CellCoord(p.z() + radius_mm, 2);
  const double r2 = radius_mm * radius_mm;
  for (int iz = z0; iz <= z1; ++iz) {
    for (int iy = y0; iy <= y1; ++iy) {
      const std::size_t c0 = CellIndex(x0, iy, iz), c1 = CellIndex(x1, iy, iz);
      // Cells x0 .. x1 of a row are consecutive: one run of points.
      for (int s = start_[c0]; s < start_[c1 + 1]; ++s) {
        const double d2 = (sorted_[static_cast<std::size_t>(s)] - p).squaredNorm();
        if (d2 <= r2) out->emplace_back(std::sqrt(d2), index_[static_cast<std::size_t>(s)]);
      }
    }
  }
  std::sort(out->begin(), out->end());
}

}  // namespace formloop::recon
