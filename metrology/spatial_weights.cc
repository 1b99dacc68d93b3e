#include "metrology/spatial_weights.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>
#include <utility>

#include <CGAL/Delaunay_triangulation_2.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_vertex_base_with_info_2.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/point_types.h>

#include "core/atomic_file.h"

namespace formloop::metrology {
namespace {

std::string Lower(std::string_view text) {
  std::string out(text);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

// Centred float cloud for PCL (FLANN works in float; centring keeps the rounding relative to the extent).
pcl::PointCloud<pcl::PointXYZ>::Ptr CentredCloud(const Eigen::MatrixXd& points) {
  const int n = static_cast<int>(points.cols());
  const Eigen::VectorXd centre = points.rowwise().mean();
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  cloud->resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const Eigen::VectorXd p = points.col(i) - centre;
    (*cloud)[static_cast<std::size_t>(i)] = pcl::PointXYZ(static_cast<float>(p[0]), static_cast<float>(p[1]),
                                                          points.rows() == 3 ? static_cast<float>(p[2]) : 0.f);
  }
  return cloud;
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
  std::vector<Eigen::Triplet<double>> triplets;
  SpatialWeights result;
  result.style = style;
  for (int i = 0; i < n; ++i) {
    std::vector<int> row = neighbours[static_cast<std::size_t>(i)];
    std::sort(row.begin(), row.end());
    row.erase(std::unique(row.begin(), row.end()), row.end());
    row.erase(std::remove(row.begin(), row.end(), i), row.end());
    if (row.empty()) {
      ++result.islands;
      result.island_indices.push_back(i);
      continue;
    }
    const double value = style == WeightStyle::kBinary ? 1.0 : 1.0 / static_cast<double>(row.size());
    for (int j : row) {
      if (j < 0 || j >= n) return Status::Internal("neighbour index " + std::to_string(j) + " out of range");
      triplets.emplace_back(i, j, value);
    }
  }
  result.w.resize(n, n);
  result.w.setFromTriplets(triplets.begin(), triplets.end());
  result.w.makeCompressed();
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
  const auto cloud = CentredCloud(points);
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setSortedResults(true);
  tree.setInputCloud(cloud);
  std::vector<std::vector<int>> neighbours(static_cast<std::size_t>(n));
  const int query = std::min(n, k + 4);  // a few spare for self and ties
  pcl::Indices found;
  std::vector<float> unused;
  for (int i = 0; i < n; ++i) {
    tree.nearestKSearch(static_cast<pcl::index_t>(i), query, found, unused);
    // Exact double distances, ties broken by index: deterministic whatever FLANN returned first.
    std::vector<std::pair<double, int>> candidates;
    for (const auto j : found) {
      if (j == i) continue;
      candidates.emplace_back((points.col(j) - points.col(i)).squaredNorm(), static_cast<int>(j));
    }
    std::sort(candidates.begin(), candidates.end());
    for (int m = 0; m < k && m < static_cast<int>(candidates.size()); ++m) {
      neighbours[static_cast<std::size_t>(i)].push_back(candidates[static_cast<std::size_t>(m)].second);
    }
  }
  return WeightsFromNeighbours(neighbours, style);
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
  const auto cloud = CentredCloud(points);
  // Search a little wider in float, then decide the band exactly in double.
  const double extent = (points.rowwise().maxCoeff() - points.rowwise().minCoeff()).norm();
  const float search = static_cast<float>(radius * (1.0 + 1e-6) + 1e-6 * extent);
  pcl::KdTreeFLANN<pcl::PointXYZ> tree;
  tree.setInputCloud(cloud);
  std::vector<std::vector<int>> neighbours(static_cast<std::size_t>(n));
  const double r2 = radius * radius;
  pcl::Indices found;
  std::vector<float> unused;
  for (int i = 0; i < n; ++i) {
    tree.radiusSearch(static_cast<pcl::index_t>(i), search, found, unused);
    auto& row = neighbours[static_cast<std::size_t>(i)];
    for (const auto j : found) {
      if (j != i && (points.col(j) - points.col(i)).squaredNorm() <= r2) row.push_back(static_cast<int>(j));
    }
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
