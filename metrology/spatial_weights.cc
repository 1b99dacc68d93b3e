#include "metrology/spatial_weights.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <utility>

#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <nanoflann.hpp>

#include "core/atomic_file.h"
#include "core/parallel.h"

namespace formloop::metrology {
namespace {

std::string Lower(std::string_view text) {
  std::string out(text);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

// nanoflann's view of the columns of a 2 × n or 3 × n matrix (no copy; the search runs in double).
struct ColumnCloud {
  const Eigen::MatrixXd* points;
  std::size_t kdtree_get_point_count() const { return static_cast<std::size_t>(points->cols()); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const {
    return (*points)(static_cast<Eigen::Index>(d), static_cast<Eigen::Index>(i));
  }
  template <class Box>
  bool kdtree_get_bbox(Box& /*box*/) const {
    return false;
  }
};
template <int Dim>
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, ColumnCloud>, ColumnCloud, Dim,
                                                   std::uint32_t>;
constexpr std::size_t kLeafSize = 16;
constexpr long kChunk = 4096;  // points per parallel chunk (fixed: the same rows for any thread count)
// Grid kNN: a point's first search covers the (2·kBlock + 1)² cells around its own, each holding about
// kPointsPerCellPerNeighbour · (k + 1) points. Measured on 1e5 uniform points, k = 8: 21 candidates per
// point and a further ring for 30 % of them beat 41 candidates and 0.7 % (0.5) or a 5 × 5 block.
constexpr long kBlock = 1;
constexpr double kPointsPerCellPerNeighbour = 0.25;

// The squared distance that decides neighbours (the tree's own is only a candidate filter).
double SquaredDistance(const Eigen::MatrixXd& points, long i, long j) {
  return (points.col(j) - points.col(i)).squaredNorm();
}

// Row i of k-NN weights: the k points j ≠ i smallest in (‖p_j − p_i‖², j), ascending by index, into
// columns[i·k, (i+1)·k). The tree returns k + 5 candidates (self, k, spares for ties); when the k-th
// exact distance is not strictly below the farthest candidate, points at that distance may have been
// left out, and a radius search at it (inclusive, a hair wider) brings every one of them in.
template <int Dim>
void KnnRows(const Eigen::MatrixXd& points, int k, int* columns) {
  const ColumnCloud cloud{&points};
  const KdTree<Dim> tree(Dim, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
  const long n = points.cols();
  const std::size_t query = static_cast<std::size_t>(std::min<long>(n, k + 5));
  ParallelFor(n, kChunk, [&](long begin, long end) {
    std::vector<std::uint32_t> found(query);
    std::vector<double> tree_d2(query);
    std::vector<std::pair<double, int>> candidates;
    std::vector<std::pair<std::uint32_t, double>> within;
    double q[Dim];
    for (long i = begin; i < end; ++i) {
      for (int d = 0; d < Dim; ++d) q[d] = points(d, i);
      const std::size_t m = tree.knnSearch(q, query, found.data(), tree_d2.data());
      candidates.clear();
      double farthest = 0;
      for (std::size_t s = 0; s < m; ++s) {
        farthest = std::max(farthest, tree_d2[s]);
        if (found[s] != static_cast<std::uint32_t>(i)) {
          candidates.emplace_back(SquaredDistance(points, i, found[s]), static_cast<int>(found[s]));
        }
      }
      std::sort(candidates.begin(), candidates.end());
      const double kth = candidates[static_cast<std::size_t>(k - 1)].first;
      if (static_cast<long>(m) < n && !(kth < farthest * (1 - 1e-12))) {
        const double radius = std::max(kth * (1 + 1e-9), std::numeric_limits<double>::denorm_min());
        tree.radiusSearch(q, radius, within, nanoflann::SearchParams(32, 0, false));
        candidates.clear();
        for (const auto& [j, unused] : within) {
          if (j != static_cast<std::uint32_t>(i)) {
            candidates.emplace_back(SquaredDistance(points, i, j), static_cast<int>(j));
          }
        }
        std::sort(candidates.begin(), candidates.end());
      }
      int* row = columns + i * k;
      for (int m2 = 0; m2 < k; ++m2) row[m2] = candidates[static_cast<std::size_t>(m2)].second;
      std::sort(row, row + k);
    }
  });
}

// The same rows for 2-D points from a uniform grid of square cells (about `per_cell` points each), the
// points counting-sorted by cell and searched in that order (neighbouring queries share cache lines).
// The candidates of the 3 × 3 cells around the point's cell are measured in one pass and the k smallest
// (d², j) kept; rings farther out are searched only while the k-th is not strictly closer than anything
// outside the cells searched can be (less a margin for the rounding of the cell assignment), and only
// their cells that can hold a closer point. False when the points are too clustered for a grid (the
// caller then uses the kd-tree): every answer is the same exact set either way.
bool KnnRowsGrid(const Eigen::MatrixXd& points, int k, int* columns) {
  const long n = points.cols();
  double x0 = points(0, 0), y0 = points(1, 0), x1 = x0, y1 = y0;
  for (long i = 1; i < n; ++i) {
    x0 = std::min(x0, points(0, i));
    x1 = std::max(x1, points(0, i));
    y0 = std::min(y0, points(1, i));
    y1 = std::max(y1, points(1, i));
  }
  const double wx = x1 - x0, wy = y1 - y0;
  const double per_cell = std::max(1.0, kPointsPerCellPerNeighbour * (k + 1));
  const double h = std::sqrt(wx * wy * per_cell / static_cast<double>(n));
  if (!(h > 0) || !std::isfinite(h)) return false;  // collinear or coincident points
  const long gx = std::min<long>(static_cast<long>(wx / h) + 1, 1L << 15);
  const long gy = std::min<long>(static_cast<long>(wy / h) + 1, 1L << 15);
  if (gx * gy > 4 * n + 16) return false;
  auto cell_of = [&](double value, double origin, long count) {
    return std::clamp(static_cast<long>((value - origin) / h), 0L, count - 1);
  };
  // Counting sort of the points by cell (stable: ascending index within a cell).
  std::vector<int> start(static_cast<std::size_t>(gx * gy + 1), 0);
  std::vector<int> cell(static_cast<std::size_t>(n));
  for (long i = 0; i < n; ++i) {
    cell[static_cast<std::size_t>(i)] =
        static_cast<int>(cell_of(points(1, i), y0, gy) * gx + cell_of(points(0, i), x0, gx));
    ++start[static_cast<std::size_t>(cell[static_cast<std::size_t>(i)]) + 1];
  }
  int fullest = 0;
  for (std::size_t c = 1; c < start.size(); ++c) {
    fullest = std::max(fullest, start[c]);
    start[c] += start[c - 1];
  }
  if (fullest > 16 * per_cell + 64) return false;
  std::vector<double> xs(static_cast<std::size_t>(n)), ys(static_cast<std::size_t>(n));
  std::vector<int> ids(static_cast<std::size_t>(n));
  {
    std::vector<int> next(start.begin(), start.end() - 1);
    for (long i = 0; i < n; ++i) {
      const auto at = static_cast<std::size_t>(next[static_cast<std::size_t>(cell[static_cast<std::size_t>(i)])]++);
      xs[at] = points(0, i);
      ys[at] = points(1, i);
      ids[at] = static_cast<int>(i);
    }
  }
  const double margin = 1e-9 * h;
  const auto uk = static_cast<std::size_t>(k);
  // Queries in cell order; each row depends on its point only, so the chunks may run in any order.
  ParallelFor(n, kChunk, [&](long begin, long end) {
    std::vector<double> block_d2((2 * kBlock + 1) * (2 * kBlock + 1) * static_cast<std::size_t>(fullest));
    std::vector<int> block_j(block_d2.size());
    std::vector<double> best_d2(uk);
    std::vector<int> best_j(uk);
    for (long q = begin; q < end; ++q) {
      const int i = ids[static_cast<std::size_t>(q)];
      const double px = xs[static_cast<std::size_t>(q)], py = ys[static_cast<std::size_t>(q)];
      const long cx = cell[static_cast<std::size_t>(i)] % gx, cy = cell[static_cast<std::size_t>(i)] / gx;
      // The k best (d², j) found so far, unordered; (worst_d2, worst_j) at best_*[worst] is the largest
      // of them once k are in. Rejecting a candidate is one comparison, taking one a branch-free rescan.
      std::size_t found = 0, worst = 0;
      double worst_d2 = 0;
      int worst_j = 0;
      auto offer = [&](double d2, int j) {
        if (found < uk) {
          best_d2[found] = d2;
          best_j[found] = j;
          if (++found < uk) return;
        } else {
          if (d2 > worst_d2 || (d2 == worst_d2 && j > worst_j)) return;
          best_d2[worst] = d2;
          best_j[worst] = j;
        }
        worst = 0;
        worst_d2 = best_d2[0];
        worst_j = best_j[0];
        for (std::size_t t = 1; t < uk; ++t) {
          const double d = best_d2[t];
          const int jt = best_j[t];
          const bool larger = (d > worst_d2) | ((d == worst_d2) & (jt > worst_j));
          worst = larger ? t : worst;
          worst_d2 = larger ? d : worst_d2;
          worst_j = larger ? jt : worst_j;
        }
      };
      // The block: one contiguous run of the sorted points per cell row, measured first, then offered.
      std::size_t m = 0;
      const long bx0 = std::max(cx - kBlock, 0L), bx1 = std::min(cx + kBlock, gx - 1);
      for (long iy = std::max(cy - kBlock, 0L); iy <= std::min(cy + kBlock, gy - 1); ++iy) {
        const auto from = static_cast<std::size_t>(start[static_cast<std::size_t>(iy * gx + bx0)]);
        const auto to = static_cast<std::size_t>(start[static_cast<std::size_t>(iy * gx + bx1 + 1)]);
        for (std::size_t s = from; s < to; ++s, ++m) {
          const double dx = xs[s] - px, dy = ys[s] - py;
          block_d2[m] = dx * dx + dy * dy;
          block_j[m] = ids[s];
        }
      }
      for (std::size_t t = 0; t < m; ++t) {
        if (block_j[t] != i) offer(block_d2[t], block_j[t]);
      }
      // Further rings while a point outside the searched square could still be among the k.
      for (long r = kBlock + 1;; ++r) {
        const long lx = cx - r + 1, hx = cx + r - 1, ly = cy - r + 1, hy = cy + r - 1;  // searched so far
        if (lx <= 0 && ly <= 0 && hx >= gx - 1 && hy >= gy - 1) break;                  // every cell searched
        if (found == uk) {
          double reach = std::numeric_limits<double>::infinity();
          if (lx > 0) reach = std::min(reach, px - (x0 + static_cast<double>(lx) * h));
          if (hx < gx - 1) reach = std::min(reach, x0 + static_cast<double>(hx + 1) * h - px);
          if (ly > 0) reach = std::min(reach, py - (y0 + static_cast<double>(ly) * h));
          if (hy < gy - 1) reach = std::min(reach, y0 + static_cast<double>(hy + 1) * h - py);
          reach -= margin;
          if (reach > 0 && worst_d2 < reach * reach) break;
        }
        // One cell of the ring, skipped when it cannot hold a point closer than the k-th.
        auto visit = [&](long ix, long iy) {
          if (found == uk) {
            const double cell_x = x0 + static_cast<double>(ix) * h, cell_y = y0 + static_cast<double>(iy) * h;
            const double gap_x = std::max({cell_x - px, px - (cell_x + h), 0.0});
            const double gap_y = std::max({cell_y - py, py - (cell_y + h), 0.0});
            const double ex = std::max(gap_x - margin, 0.0), ey = std::max(gap_y - margin, 0.0);
            if (ex * ex + ey * ey > worst_d2) return;
          }
          const auto c = static_cast<std::size_t>(iy * gx + ix);
          for (auto s = static_cast<std::size_t>(start[c]); s < static_cast<std::size_t>(start[c + 1]); ++s) {
            const double dx = xs[s] - px, dy = ys[s] - py;
            offer(dx * dx + dy * dy, ids[s]);
          }
        };
        const long rx0 = std::max(cx - r, 0L), rx1 = std::min(cx + r, gx - 1);
        for (long ix = rx0; ix <= rx1; ++ix) {
          if (cy - r >= 0) visit(ix, cy - r);
          if (cy + r < gy) visit(ix, cy + r);
        }
        for (long iy = std::max(cy - r + 1, 0L); iy <= std::min(cy + r - 1, gy - 1); ++iy) {
          if (cx - r >= 0) visit(cx - r, iy);
          if (cx + r < gx) visit(cx + r, iy);
        }
      }
      // Sorted here, then stored: the row is far from the last one written (queries go in cell order).
      std::sort(best_j.begin(), best_j.end());
      std::copy(best_j.begin(), best_j.end(), columns + static_cast<long>(i) * k);
    }
  });
  return true;
}

// Rows of distance-band neighbours: j ≠ i with ‖p_j − p_i‖² ≤ radius² decided in double; the tree's
// search is a hair wider (its strict "<" and its own summation order must not lose a point on the band).
template <int Dim>
void BandRows(const Eigen::MatrixXd& points, double radius, std::vector<std::vector<int>>* neighbours) {
  const ColumnCloud cloud{&points};
  const KdTree<Dim> tree(Dim, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(kLeafSize));
  const double r2 = radius * radius;
  const double search = std::max(r2 * (1 + 1e-9), std::numeric_limits<double>::denorm_min());
  ParallelFor(points.cols(), kChunk, [&](long begin, long end) {
    std::vector<std::pair<std::uint32_t, double>> within;
    double q[Dim];
    for (long i = begin; i < end; ++i) {
      for (int d = 0; d < Dim; ++d) q[d] = points(d, i);
      tree.radiusSearch(q, search, within, nanoflann::SearchParams(32, 0, false));
      auto& row = (*neighbours)[static_cast<std::size_t>(i)];
      for (const auto& [j, unused] : within) {
        if (j != static_cast<std::uint32_t>(i) && SquaredDistance(points, i, j) <= r2) {
          row.push_back(static_cast<int>(j));
        }
      }
    }
  });
}

Status CheckPoints(const Eigen::MatrixXd& points, const char* what, bool two_d_only) {
  if (two_d_only ? points.rows() != 2 : (points.rows() != 2 && points.rows() != 3)) {
    return Status::Internal(std::string(what) + ": points must be " + (two_d_only ? "2 × n" : "2 × n or 3 × n"));
  }
  if (!points.allFinite()) {
    return Status::BadInput(std::string(what) + ": a coordinate is NaN or infinite. Fix: remove that point");
  }
  return Status::Ok();
}

}  // namespace

Result<WeightStyle> ParseWeightStyle(std::string_view text, const std::string& option) {
  const std::string t = Lower(text);
  if (t == "b") return WeightStyle::kBinary;
  if (t == "w" || t == "r") return WeightStyle::kRowStandardised;
  return Status::BadInput(Where{.field = option}, "unknown weight style '" + std::string(text) + "'",
                          "use B (binary) or W (row-standardised)");
}

const char* WeightStyleName(WeightStyle style) { return style == WeightStyle::kBinary ? "B" : "W"; }

Result<IslandPolicy> ParseIslandPolicy(std::string_view text, const std::string& option) {
  const std::string t = Lower(text);
  if (t == "refuse") return IslandPolicy::kRefuse;
  if (t == "drop") return IslandPolicy::kDrop;
  if (t == "zero") return IslandPolicy::kZero;
  return Status::BadInput(Where{.field = option}, "unknown island policy '" + std::string(text) + "'",
                          "use refuse, drop or zero");
}

const char* IslandPolicyName(IslandPolicy policy) {
  switch (policy) {
    case IslandPolicy::kRefuse:
      return "refuse";
    case IslandPolicy::kDrop:
      return "drop";
    case IslandPolicy::kZero:
      return "zero";
  }
  return "?";
}

std::vector<std::vector<int>> SpatialWeights::Neighbours() const {
  std::vector<std::vector<int>> out(static_cast<std::size_t>(w.rows()));
  for (int i = 0; i < w.outerSize(); ++i) {
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(w, i); it; ++it) {
      if (it.value() != 0) out[static_cast<std::size_t>(i)].push_back(static_cast<int>(it.col()));
    }
  }
  return out;
}

Result<SpatialWeights> WeightsFromNeighbours(const std::vector<std::vector<int>>& neighbours, WeightStyle style) {
  const int n = static_cast<int>(neighbours.size());
  SpatialWeights result;
  result.style = style;
  // Compressed row storage filled directly: rows in order, each sorted and de-duplicated.
  std::vector<int> outer(static_cast<std::size_t>(n) + 1, 0);
  std::vector<int> inner;
  std::vector<double> values;
  std::vector<int> row;
  for (int i = 0; i < n; ++i) {
    row = neighbours[static_cast<std::size_t>(i)];
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
    row.erase(std::remove(row.begin(), row.end(), i), row.end());
    if (row.empty()) {
      ++result.islands;
      result.island_indices.push_back(i);
    }
    const double value = style == WeightStyle::kBinary ? 1.0 : 1.0 / static_cast<double>(row.size());
    for (int j : row) {
      if (j < 0 || j >= n) return Status::Internal("neighbour index " + std::to_string(j) + " out of range");
      inner.push_back(j);
      values.push_back(value);
    }
    outer[static_cast<std::size_t>(i) + 1] = static_cast<int>(inner.size());
  }
  result.w = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor>>(
      n, n, static_cast<Eigen::Index>(inner.size()), outer.data(), inner.data(), values.data());
  return result;
}

Result<SpatialWeights> KnnWeights(const Eigen::MatrixXd& points, int k, WeightStyle style) {
  const int n = static_cast<int>(points.cols());
  if (k < 1) return Status::BadInput(Where{.field = "k"}, "needs at least one neighbour", "use k >= 1 (default 8)");
  if (n <= k) {
    return Status::BadInput(Where{.field = "k"},
                            std::to_string(n) + " points cannot each have " + std::to_string(k) + " neighbours",
                            "use fewer neighbours or more points");
  }
  FL_RETURN_IF_ERROR(CheckPoints(points, "k-NN weights", false));
  if (static_cast<double>(n) * k > std::numeric_limits<int>::max()) {
    return Status::BadInput(
        Where{.field = "k"},
        std::to_string(n) + " points × " + std::to_string(k) + " neighbours exceed the sparse matrix's 2^31 entries",
        "use fewer neighbours or thin the points");
  }
  // Every row has exactly k entries: the compressed rows are written in place, no triplets, no copy.
  SpatialWeights result;
  result.style = style;
  result.w.resize(n, n);
  result.w.resizeNonZeros(static_cast<Eigen::Index>(n) * k);
  int* columns = result.w.innerIndexPtr();
  if (points.rows() == 2) {
    if (!KnnRowsGrid(points, k, columns)) KnnRows<2>(points, k, columns);
  } else {
    KnnRows<3>(points, k, columns);
  }
  for (int i = 0; i <= n; ++i) result.w.outerIndexPtr()[i] = i * k;
  const double value = style == WeightStyle::kBinary ? 1.0 : 1.0 / static_cast<double>(k);
  std::fill(result.w.valuePtr(), result.w.valuePtr() + result.w.nonZeros(), value);
  return result;
}

namespace {
bool ParseCount(const std::string& text, int* count) {
  if (text.empty() || text.size() > 9) return false;
  for (char c : text) {
    if (c < '0' || c > '9') return false;
  }
  *count = std::stoi(text);
  return true;
}
}  // namespace

Result<SpatialWeights> ReadGal(const std::filesystem::path& path, const std::vector<std::string>& ids,
                               WeightStyle style) {
  std::ifstream in(path);
  const std::string file = path.string();
  if (!in) return Status::NotFound("GAL file '" + file + "' cannot be opened. Check the path");
  std::map<std::string, int> index;
  for (std::size_t i = 0; i < ids.size(); ++i) {
    if (!index.emplace(ids[i], static_cast<int>(i)).second) {
      return Status::BadInput("GAL weights '" + file + "': the data's id '" + ids[i] + "' appears in rows " +
                              std::to_string(index[ids[i]] + 1) + " and " + std::to_string(i + 1) +
                              ". Fix: give every data row its own id (the id column must be unique)");
    }
  }
  std::string line;
  long line_no = 0;
  auto next_line = [&](std::vector<std::string>* tokens) {
    while (std::getline(in, line)) {
      ++line_no;
      std::istringstream ss(line);
      tokens->clear();
      std::string t;
      while (ss >> t) tokens->push_back(t);
      if (!tokens->empty()) return true;
    }
    return false;
  };
  std::vector<std::string> tokens;
  if (!next_line(&tokens)) return Status::BadInput(Where{.file = file}, "the file is empty", "write a GAL file");
  const std::string count_text = tokens.size() >= 2 ? tokens[1] : tokens[0];
  long n = 0;
  try {
    n = std::stol(count_text);
  } catch (...) {
    return Status::BadInput(Where{.file = file, .line = line_no}, "first line does not give the number of units");
  }
  if (n != static_cast<long>(ids.size())) {
    return Status::BadInput(Where{.file = file, .line = line_no},
                            "GAL has " + std::to_string(n) + " units, the data " + std::to_string(ids.size()),
                            "pair data and weights from the same source");
  }
  std::vector<std::vector<int>> neighbours(ids.size());
  std::vector<bool> seen(ids.size(), false);
  for (long unit = 0; unit < n; ++unit) {
    if (!next_line(&tokens) || tokens.size() != 2) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "expected 'id count'", "check the GAL file");
    }
    auto it = index.find(tokens[0]);
    if (it == index.end()) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "id '" + tokens[0] + "' is not in the data",
                              "pair data and weights from the same source (check the id column)");
    }
    if (seen[static_cast<std::size_t>(it->second)]) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "id '" + tokens[0] + "' is listed twice",
                              "give each unit one 'id count' line");
    }
    seen[static_cast<std::size_t>(it->second)] = true;
    int count = 0;
    if (!ParseCount(tokens[1], &count)) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "'" + tokens[1] + "' is not a neighbour count",
                              "write 'id count' with a whole number count");
    }
    std::vector<std::string> list;
    if (count > 0 && !next_line(&list)) {
      return Status::BadInput(Where{.file = file, .line = line_no}, "neighbour list missing");
    }
    if (static_cast<int>(list.size()) != count) {
      return Status::BadInput(
          Where{.file = file, .line = line_no},
          "expected " + std::to_string(count) + " neighbour ids, found " + std::to_string(list.size()));
    }
    for (const auto& id : list) {
      auto jt = index.find(id);
      if (jt == index.end()) {
        return Status::BadInput(Where{.file = file, .line = line_no}, "neighbour id '" + id + "' is not in the data",
                                "pair data and weights from the same source (check the id column)");
      }
      neighbours[static_cast<std::size_t>(it->second)].push_back(jt->second);
    }
  }
  return WeightsFromNeighbours(neighbours, style);
}

Result<SpatialWeights> DelaunayWeights(const Eigen::MatrixXd& uv, WeightStyle style) {
  using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
  using VertexBase = CGAL::Triangulation_vertex_base_with_info_2<int, Kernel>;
  using Tds = CGAL::Triangulation_data_structure_2<VertexBase>;
  using Delaunay = CGAL::Delaunay_triangulation_2<Kernel, Tds>;
  FL_RETURN_IF_ERROR(CheckPoints(uv, "Delaunay weights", true));
  const int n = static_cast<int>(uv.cols());
  if (n < 2) return Status::BadInput("Delaunay weights need at least 2 points, got " + std::to_string(n));
  // Coincident points would be merged by the triangulation: refuse them by name.
  std::vector<int> order(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) order[static_cast<std::size_t>(i)] = i;
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return uv(0, a) != uv(0, b) ? uv(0, a) < uv(0, b) : (uv(1, a) != uv(1, b) ? uv(1, a) < uv(1, b) : a < b);
  });
  for (std::size_t m = 1; m < order.size(); ++m) {
    const int a = order[m - 1], b = order[m];
    if (uv(0, a) == uv(0, b) && uv(1, a) == uv(1, b)) {
      return Status::BadInput("Delaunay weights: points " + std::to_string(a) + " and " + std::to_string(b) +
                              " (0-based rows) coincide. Fix: merge or remove duplicate points, or use k-NN weights");
    }
  }
  std::vector<std::pair<Kernel::Point_2, int>> sites;
  sites.reserve(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) sites.emplace_back(Kernel::Point_2(uv(0, i), uv(1, i)), i);
  std::vector<std::vector<int>> neighbours(static_cast<std::size_t>(n));
  try {
    Delaunay dt;
    dt.insert(sites.begin(), sites.end());
    if (static_cast<int>(dt.number_of_vertices()) != n) {
      return Status::Internal("Delaunay weights: the triangulation kept " + std::to_string(dt.number_of_vertices()) +
                              " of " + std::to_string(n) + " distinct points");
    }
    for (auto e = dt.finite_edges_begin(); e != dt.finite_edges_end(); ++e) {
      const auto face = e->first;
      const int a = face->vertex(Delaunay::cw(e->second))->info();
      const int b = face->vertex(Delaunay::ccw(e->second))->info();
      neighbours[static_cast<std::size_t>(a)].push_back(b);
      neighbours[static_cast<std::size_t>(b)].push_back(a);
    }
  } catch (const std::exception& e) {
    return Status::Internal(std::string("Delaunay weights: CGAL failed: ") + e.what());
  }
  return WeightsFromNeighbours(neighbours, style);
}

Result<SpatialWeights> DistanceBandWeights(const Eigen::MatrixXd& points, double radius, WeightStyle style) {
  FL_RETURN_IF_ERROR(CheckPoints(points, "distance-band weights", false));
  if (!(radius > 0) || !std::isfinite(radius)) {
    return Status::BadInput(Where{.field = "band"}, "the band distance must be positive and finite",
                            "give the neighbourhood radius in the points' units, e.g. 2.5");
  }
  const int n = static_cast<int>(points.cols());
  if (n < 2) return Status::BadInput("distance-band weights need at least 2 points, got " + std::to_string(n));
  std::vector<std::vector<int>> neighbours(static_cast<std::size_t>(n));
  if (points.rows() == 2) {
    BandRows<2>(points, radius, &neighbours);
  } else {
    BandRows<3>(points, radius, &neighbours);
  }
  return WeightsFromNeighbours(neighbours, style);
}

Status WriteGal(const std::filesystem::path& path, const SpatialWeights& weights, const std::vector<std::string>& ids) {
  const int n = weights.n();
  if (static_cast<int>(ids.size()) != n) {
    return Status::Internal("WriteGal: " + std::to_string(ids.size()) + " ids for " + std::to_string(n) + " units");
  }
  for (const auto& id : ids) {
    if (id.empty() || id.find_first_of(" \t\r\n") != std::string::npos) {
      return Status::BadInput(Where{.file = path.string()}, "id '" + id + "' is empty or contains whitespace",
                              "use ids without spaces (GAL separates them by whitespace)");
    }
  }
  const auto neighbours = weights.Neighbours();
  std::ostringstream out;
  out << n << "\n";
  for (int i = 0; i < n; ++i) {
    const auto& row = neighbours[static_cast<std::size_t>(i)];
    out << ids[static_cast<std::size_t>(i)] << " " << row.size() << "\n";
    if (row.empty()) continue;
    for (std::size_t m = 0; m < row.size(); ++m) {
      out << (m ? " " : "") << ids[static_cast<std::size_t>(row[m])];
    }
    out << "\n";
  }
  return WriteFileAtomic(path, out.str());
}

Result<IslandResolution> ResolveIslands(const SpatialWeights& weights, IslandPolicy policy) {
  IslandResolution r;
  r.policy = policy;
  r.islands = weights.islands;
  const int n = weights.n();
  r.kept.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) r.kept[static_cast<std::size_t>(i)] = i;
  if (weights.islands == 0 || policy == IslandPolicy::kZero) {
    r.weights = weights;
    return r;
  }
  if (policy == IslandPolicy::kRefuse) {
    std::string list;
    for (std::size_t m = 0; m < weights.island_indices.size() && m < 10; ++m) {
      list += (m ? ", " : "") + std::to_string(weights.island_indices[m]);
    }
    if (weights.island_indices.size() > 10) list += ", ...";
    return Status::BadInput("Moran's I: " + std::to_string(weights.islands) +
                            " point(s) have no neighbours (islands; 0-based rows " + list +
                            "). Fix: choose an island policy (drop, or zero rows keeping n), or widen the "
                            "neighbourhood (more neighbours, a larger band)");
  }
  // kDrop: remove islands, restyle, and repeat while removal leaves new ones.
  std::vector<std::vector<int>> neighbours = weights.Neighbours();
  SpatialWeights current = weights;
  while (current.islands > 0) {
    const int m = current.n();
    std::vector<int> new_index(static_cast<std::size_t>(m), -1);
    std::vector<int> kept;
    for (int i = 0, next = 0; i < m; ++i) {
      if (neighbours[static_cast<std::size_t>(i)].empty()) {
        r.dropped.push_back(r.kept[static_cast<std::size_t>(i)]);
      } else {
        new_index[static_cast<std::size_t>(i)] = next++;
        kept.push_back(r.kept[static_cast<std::size_t>(i)]);
      }
    }
    std::vector<std::vector<int>> reduced;
    for (int i = 0; i < m; ++i) {
      if (new_index[static_cast<std::size_t>(i)] < 0) continue;
      std::vector<int> row;
      for (int j : neighbours[static_cast<std::size_t>(i)]) {
        if (new_index[static_cast<std::size_t>(j)] >= 0) row.push_back(new_index[static_cast<std::size_t>(j)]);
      }
      reduced.push_back(std::move(row));
    }
    r.kept = std::move(kept);
    neighbours = std::move(reduced);
    FL_ASSIGN_OR_RETURN(current, WeightsFromNeighbours(neighbours, weights.style));
  }
  std::sort(r.dropped.begin(), r.dropped.end());
  r.weights = std::move(current);
  return r;
}

}  // namespace formloop::metrology
