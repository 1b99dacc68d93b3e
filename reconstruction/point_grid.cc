// Uniform 3-D cell grid with exact nearest and radius queries (point_grid.h).

#include "reconstruction/point_grid.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>

#include <nanoflann.hpp>

namespace formloop::recon {
namespace {

// Dense storage bound: at most this many cells a point (plus a floor for small sets); a larger
// bounding box gets larger cells.
constexpr double kMaxCellsPerPoint = 8;
constexpr double kMinCellBudget = 4096;
// The grid's work on one query, counted as runs of cells plus points looked at (WithinRadius: expected at
// the mean density), beyond which the kd-tree takes over: Nearest after the ring that passes it,
// WithinRadius before it starts. A query near the sheet does a few dozen. bench/projection_bench.cc's far
// points (10,000, 3 to 30 mm off the surface), 2026-11-28: with a 512 × 512 start grid (cells about
// 0.2 mm) 3,600–4,300 ms by the grid alone, 1,000–1,300 ms with the tree past 256 or 512, 1,300–1,700 past
// 4,096; with the automatic one (cells about 2 mm, 1,300 samples) 136–139 ms alone, 145–177 with the tree
// at any of these bounds (its queries cost a few µs more there).
constexpr long kMaxGridWork = 512;
constexpr std::size_t kLeafSize = 16;

// nanoflann's view of the points in cell order (no copy; the search runs in double).
struct Cloud {
  const std::vector<Eigen::Vector3d>* points;
  std::size_t kdtree_get_point_count() const { return points->size(); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const { return (*points)[i](static_cast<Eigen::Index>(d)); }
  template <class Box>
  bool kdtree_get_bbox(Box& /*box*/) const {
    return false;
  }
};
using KdTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Cloud>, Cloud, 3, std::uint32_t>;

}  // namespace

struct PointGrid::Points {
  std::vector<Eigen::Vector3d> sorted;  // the points in cell order
  std::vector<int> index;               // their indices in the input
  Cloud cloud{&sorted};                 // the tree keeps a reference to its adaptor: it lives here, beside the tree
  mutable std::once_flag tree_built;
  mutable std::unique_ptr<KdTree> tree;  // over `sorted`, built by the first query that needs it

  const KdTree& Tree() const {
    std::call_once(tree_built, [this] {
      tree = std::make_unique<KdTree>(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
    });
    return *tree;
  }
  // Every point with squared distance <= r2 from p by our own squared norm, as (d², slot in cell order):
  // the tree's ball is a hair wider, so no point the norm keeps is lost to the tree's own rounding.
  void Within(const Eigen::Vector3d& p, double r2, std::vector<std::pair<double, int>>* out) const {
    std::vector<std::pair<std::uint32_t, double>> matches;
    const double wide = std::max(r2 * (1 + 1e-9), std::numeric_limits<double>::denorm_min());
    Tree().radiusSearch(p.data(), wide, matches, nanoflann::SearchParams(32, 0, false));
    out->clear();
    for (const auto& [slot, unused] : matches) {
      const double d2 = (sorted[slot] - p).squaredNorm();
      if (d2 <= r2) out->emplace_back(d2, static_cast<int>(slot));
    }
  }
};

std::size_t PointGrid::size() const { return points_ == nullptr ? 0 : points_->index.size(); }

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
  auto sorted = std::make_shared<Points>();
  sorted->sorted.resize(points.size());
  sorted->index.resize(points.size());
  for (std::size_t k = 0; k < points.size(); ++k) {  // input order within a cell
    const int slot = fill[cell_of[k]]++;
    sorted->sorted[static_cast<std::size_t>(slot)] = points[k];
    sorted->index[static_cast<std::size_t>(slot)] = static_cast<int>(k);
  }
  points_ = std::move(sorted);
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
  if (size() == 0) return best;
  const std::vector<Eigen::Vector3d>& sorted = points_->sorted;
  const std::vector<int>& index = points_->index;
  const int cx = CellCoord(p.x(), 0), cy = CellCoord(p.y(), 1), cz = CellCoord(p.z(), 2);
  const int max_ring = std::max({cx, dims_[0] - 1 - cx, cy, dims_[1] - 1 - cy, cz, dims_[2] - 1 - cz});
  // Rings of cells at Chebyshev distance k from p's (clamped) cell: every point not yet seen is at
  // least k cells away along some axis, so farther than k · cell from p.
  // Points s_begin .. s_end − 1 (cell order): distances, the best so far, the seen list.
  long work = 0;
  auto visit = [&](int s_begin, int s_end) {
    work += 1 + (s_end - s_begin);
    for (int s = s_begin; s < s_end; ++s) {
      const double d2 = (sorted[static_cast<std::size_t>(s)] - p).squaredNorm();
      const int id = index[static_cast<std::size_t>(s)];
      if (seen != nullptr) seen->emplace_back(d2, id);
      if (d2 < best_d2 || (d2 == best_d2 && id < best)) {
        best_d2 = d2;
        best = id;
      }
    }
  };
  bool done = false;
  for (int k = 0; k <= max_ring && work <= kMaxGridWork; ++k) {
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
    if (best >= 0 && std::sqrt(best_d2) <= complete) {
      done = true;
      break;
    }
    done = k == max_ring;  // every cell searched
  }
  if (!done) {
    // Far from every point: the tree's nearest gives the distance; every point at it (ties) by our norm.
    std::uint32_t slot = 0;
    double tree_d2 = 0;
    points_->Tree().knnSearch(p.data(), 1, &slot, &tree_d2);
    std::vector<std::pair<double, int>> ties;
    points_->Within(p, std::max(tree_d2, (sorted[slot] - p).squaredNorm()), &ties);
    for (const auto& [d2, s] : ties) {
      const int id = index[static_cast<std::size_t>(s)];
      if (d2 < best_d2 || (d2 == best_d2 && id < best)) {
        best_d2 = d2;
        best = id;
      }
    }
  }
  if (distance_mm != nullptr) *distance_mm = std::sqrt(best_d2);
  return best;
}

void PointGrid::WithinRadius(const Eigen::Vector3d& p, double radius_mm,
                             std::vector<std::pair<double, int>>* out) const {
  out->clear();
  if (size() == 0 || !(radius_mm >= 0)) return;
  const std::vector<Eigen::Vector3d>& sorted = points_->sorted;
  const std::vector<int>& index = points_->index;
  const int x0 = CellCoord(p.x() - radius_mm, 0), x1 = CellCoord(p.x() + radius_mm, 0);
  const int y0 = CellCoord(p.y() - radius_mm, 1), y1 = CellCoord(p.y() + radius_mm, 1);
  const int z0 = CellCoord(p.z() - radius_mm, 2), z1 = CellCoord(p.z() + radius_mm, 2);
  const double r2 = radius_mm * radius_mm;
  // Rows (each one run of points) plus the points expected in the box's cells at the mean density.
  const double rows = static_cast<double>(y1 - y0 + 1) * (z1 - z0 + 1);
  const double per_cell = static_cast<double>(size()) / (start_.size() - 1);
  if (rows * (1 + (x1 - x0 + 1) * per_cell) > kMaxGridWork) {
    points_->Within(p, r2, out);
    for (auto& [d, s] : *out) {
      d = std::sqrt(d);
      s = index[static_cast<std::size_t>(s)];
    }
    std::sort(out->begin(), out->end());
    return;
  }
  for (int iz = z0; iz <= z1; ++iz) {
    for (int iy = y0; iy <= y1; ++iy) {
      const std::size_t c0 = CellIndex(x0, iy, iz), c1 = CellIndex(x1, iy, iz);
      // Cells x0 .. x1 of a row are consecutive: one run of points.
      for (int s = start_[c0]; s < start_[c1 + 1]; ++s) {
        const double d2 = (sorted[static_cast<std::size_t>(s)] - p).squaredNorm();
        if (d2 <= r2) out->emplace_back(std::sqrt(d2), index[static_cast<std::size_t>(s)]);
      }
    }
  }
  std::sort(out->begin(), out->end());
}

}  // namespace formloop::recon
